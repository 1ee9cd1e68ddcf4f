"""Fixtures for the ISO 9283 analysis tests.

Every test that hides an effect in data draws it at random each run from the
``rng`` fixture of tests/seeding.py (a failing test prints the seed and the
command that replays it).  Thresholds come from the noise model and n.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest
from scipy import stats

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def bench_module():
    """bench/bench_iso9283.py (holds the direct per-window transcription of the seed)."""
    spec = importlib.util.spec_from_file_location("bench_iso9283", ROOT / "bench" / "bench_iso9283.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def rp_population(sigma: float) -> float:
    """RP = E[l] + 3 sd(l) for isotropic Gaussian scatter sigma per axis (l ~ sigma chi_3)."""
    m, v = stats.chi(3).stats(moments="mv")
    return sigma * (float(m) + 3.0 * math.sqrt(float(v)))


def rp_estimate_sd(sigma: float, n: int) -> float:
    """Standard deviation of the RP estimate (eq. (2)) from n attained poses.

    Delta method on l_bar + 3 S_l with the moments of sigma chi_3 (large-n
    approximation; the tests use 5 of these as their threshold).
    """
    d = stats.chi(3)
    mu = d.mean()
    mom = [d.expect(lambda x, k=k: (x - mu) ** k) for k in (2, 3, 4)]
    m2, m3, m4 = (sigma**2 * mom[0], sigma**3 * mom[1], sigma**4 * mom[2])
    s = math.sqrt(m2)
    var_lbar = m2 / n
    var_S = (m4 - m2**2) / (4 * m2 * n)
    cov = m3 / (2 * s * n)
    return math.sqrt(var_lbar + 9 * var_S + 6 * cov)


def chi3_q(p_exceed: float = 1e-6) -> float:
    """Norm bound (in sigma) for a 3-D isotropic Gaussian vector, exceeded with probability p_exceed."""
    return float(stats.chi(3).isf(p_exceed))
