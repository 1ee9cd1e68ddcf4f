"""The motion diagnosis's held-out test: signed ranks of the blocks' mean-square reductions.

A creep lowers a few early blocks of an approach by far more than the rest; the test must see that on the
lab's 20 or so held-out blocks, and must pass noise alone no more often than its alpha.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from station.analysis.motion.diagnose import signed_rank_z

ALPHA = 0.01


def test_a_few_large_gains_among_small_ones_pass(rng):
    # two held-out approaches of 10 blocks of 0.1 s: the creep's gain falls by e every 2-4 blocks (tau 0.12-0.2 s,
    # squared) from a random size; every block also carries the mean square's scatter (0.2 % of the first gain)
    for _ in range(50):
        big = rng.uniform(1e-4, 4e-3)
        gain = np.concatenate([big * np.exp(-np.arange(10) / rng.uniform(2.0, 4.0)) for _ in range(2)])
        d = gain + rng.normal(0.0, 0.002 * big, gain.size)
        z, n = signed_rank_z(d)
        assert n == 20
        assert z > stats.norm.isf(ALPHA), (z, d)


def test_noise_alone_passes_at_alpha(rng):
    # reductions symmetric about 0 (a candidate no better than the current model): the pass rate is alpha's;
    # over 1000 draws of 20 blocks the count of passes is binomial (mean 10): more than 30 has P < 1e-7
    passes = sum(signed_rank_z(rng.standard_t(3, 20) * rng.uniform(1e-6, 1e-3))[0] > stats.norm.isf(ALPHA)
                 for _ in range(1000))
    assert passes <= 30, passes
    # and a candidate that is worse fails
    z, _ = signed_rank_z(-np.abs(rng.normal(1e-4, 1e-5, 20)))
    assert z < 0.0


def test_too_few_blocks_state_nothing():
    z, n = signed_rank_z([1e-3, np.nan, 0.0, 2e-3])
    assert n == 2 and np.isnan(z)
