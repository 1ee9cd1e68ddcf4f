"""The rows of a time interval by bisection (sorted times) against the scan of the whole stream."""

from __future__ import annotations

import numpy as np

from station.analysis.motion.windows import _rows_between


def test_bisection_gives_the_scans_rows(rng):
    n = int(rng.integers(50, 2000))
    t = np.cumsum(rng.choice([0.0, 1e-3, 2e-3, 0.5], size=n, p=[0.05, 0.8, 0.1, 0.05]))  # repeats and gaps
    ok = rng.random(n) > 0.1
    for _ in range(200):  # loop over random intervals, some empty, some past either end, on sample times
        lo, hi = np.sort(rng.uniform(t[0] - 1.0, t[-1] + 1.0, 2))
        if rng.random() < 0.3:
            lo, hi = t[rng.integers(n)], t[rng.integers(n)]
        scan = np.flatnonzero((t >= lo) & (t <= hi) & ok)
        assert np.array_equal(_rows_between(t, lo, hi, ok, True), scan)
        assert np.array_equal(_rows_between(t, lo, hi, ok, False), scan)
