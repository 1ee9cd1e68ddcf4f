"""Whether the geometry folds can judge at all (issue 43: one-joint sweeps whose held-out interior poses lie near
home, where the nominal model already predicts to the noise): :func:`folds_see_geometry` on drawn errors."""

from __future__ import annotations

import math

import numpy as np

from station.analysis.diagnose.geometry_cv import FoldErrors, folds_see_geometry

ALPHA = 0.05


def _folds(rng, n_held: int, sigma: float, bias_mm: float, dof: int):
    """Held-out poses whose nominal model misses by ``bias_mm`` (3-D, a random direction) plus noise of
    ``sigma`` per coordinate; ``s^2`` estimated from ``dof`` residual coordinates of the same noise."""
    d = rng.normal(size=(n_held, 3))
    d *= bias_mm / np.linalg.norm(d, axis=1, keepdims=True)
    e = d + rng.normal(scale=sigma, size=(n_held, 3))
    s2 = float(np.sum(rng.normal(scale=sigma, size=dof) ** 2)) / dof
    sq = np.sum(e ** 2, axis=1)
    return FoldErrors(np.arange(n_held), sq, sq, 0), s2


def test_folds_at_the_noise_are_blind_at_the_stated_rate(rng):
    """With the nominal model right on the held-out poses, the folds 'see' geometry at about alpha."""
    draws = 2000
    n_held, dof = int(rng.integers(6, 15)), int(rng.integers(30, 80))
    sigma = float(rng.uniform(0.05, 0.3))
    seen = sum(folds_see_geometry(*_folds(rng, n_held, sigma, 0.0, dof), dof, ALPHA).seen for _ in range(draws))
    se = math.sqrt(ALPHA * (1 - ALPHA) / draws)
    assert abs(seen / draws - ALPHA) < 4 * se, (seen, draws, n_held, dof)


def test_a_table_error_of_a_few_noise_sigmas_is_seen(rng):
    """A nominal model missing every held-out pose by 1.5-3x the per-pose noise (sqrt(3) sigma) is seen almost
    always, whatever the noise's size; a miss of half the noise seldom (the statistic's expectation is then about
    1.1, the 95 % quantile of F(18+, 30+) above 1.5: seen on about 8 % of draws; 300 test seeds, at most 36 of
    200)."""
    n_held, dof = int(rng.integers(6, 15)), int(rng.integers(30, 80))
    sigma = float(rng.uniform(0.05, 0.3))
    k = float(rng.uniform(1.5, 3.0)) * math.sqrt(3.0)
    big = [folds_see_geometry(*_folds(rng, n_held, sigma, k * sigma, dof), dof, ALPHA).seen for _ in range(200)]
    small = [folds_see_geometry(*_folds(rng, n_held, sigma, 0.5 * sigma, dof), dof, ALPHA).seen for _ in range(200)]
    assert sum(big) >= 190 and sum(small) <= 50, (sum(big), sum(small), n_held, dof, k)


def test_no_folds_or_no_noise_estimate_is_not_blind():
    """Without held-out poses or a residual variance the folds neither see nor are blind (the caller keeps its
    cross-validation's answer): the statistic is undefined."""
    z = np.zeros(0)
    sig = folds_see_geometry(FoldErrors(np.zeros(0, dtype=np.int64), z, z, 0), 0.01, 40.0, ALPHA)
    assert math.isnan(sig.statistic) and not sig.seen
    sq = np.ones(5)
    assert math.isnan(folds_see_geometry(FoldErrors(np.arange(5), sq, sq, 0), float("nan"), 40.0, ALPHA).statistic)
