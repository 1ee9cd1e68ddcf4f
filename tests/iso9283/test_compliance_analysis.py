"""The static compliance analysis (ISO 9283 clause 10) on synthetic loadings: slope, its U, hysteresis, refusals."""

from __future__ import annotations

import numpy as np
import pytest

from station.analysis.iso9283.compliance import (DIRECTIONS, direction_compliance, load_levels_N, load_prompt,
                                                 parse_load_prompt)
from station.errors import ConfigError, DataError, InsufficientDataError


def _loading(rng, direction, slope, sigma_mm, hysteresis_mm=0.0, steps=10):
    F = load_levels_N(float(rng.uniform(200.0, 3000.0)), steps)
    up = np.arange(F.size) <= int(np.argmax(F))
    u = np.asarray(DIRECTIONS[direction])
    along = slope * F + np.where(up, 0.0, hysteresis_mm * np.sin(np.pi * F / F.max()))
    side = rng.normal(size=3)
    side -= (side @ u) * u  # displacement across the load does not count
    P = rng.uniform(-500, 500, 3) + np.outer(along, u) + np.outer(F * slope * 0.3, side)
    P += rng.normal(0.0, sigma_mm, P.shape)
    return F, P, up


def test_the_slope_is_found_within_its_U_and_U_is_not_too_wide(rng):
    """Over many drawn loadings the true slope falls within U about 95 % of the time (k = 2; the gauge term
    off) and within 2 U practically always."""
    inside, n = 0, 200
    for _ in range(n):
        d = str(rng.choice(list(DIRECTIONS)))
        slope = float(rng.uniform(1e-5, 5e-4))
        F, P, up = _loading(rng, d, slope, sigma_mm=float(rng.uniform(0.002, 0.02)))
        r = direction_compliance(d, F, P, up, u_F_rel=0.0)
        inside += abs(r.compliance_mm_per_N - slope) <= r.U_mm_per_N
        assert abs(r.compliance_mm_per_N - slope) <= 2.5 * r.U_mm_per_N
    assert 0.88 * n <= inside <= n  # binomial(200, 0.95): below 176 one time in 1000 or so


def test_the_gauge_term_and_hysteresis(rng):
    F, P, up = _loading(rng, "+z", 2e-4, sigma_mm=1e-6, hysteresis_mm=0.05)
    r = direction_compliance("+z", F, P, up, u_F_rel=0.01)
    assert r.U_mm_per_N >= 2 * 0.01 * r.compliance_mm_per_N * 0.999
    assert r.hysteresis_mm == pytest.approx(0.05, rel=0.05)
    assert r.loading[0] and not r.loading[-1] and len(r.displacement_mm) == F.size
    flat = direction_compliance("+z", *_loading(rng, "+z", 2e-4, sigma_mm=1e-6)[:3])
    assert flat.hysteresis_mm < 1e-4


def test_bad_input_is_refused_naming_it(rng):
    F, P, up = _loading(rng, "-x", 1e-4, 0.001)
    with pytest.raises(ConfigError, match="direction 'x'"):
        direction_compliance("x", F, P, up)
    with pytest.raises(DataError, match="positions"):
        direction_compliance("-x", F, P[:-1], up)
    with pytest.raises(InsufficientDataError, match="span"):
        direction_compliance("-x", np.full(F.size, 100.0), P, up)
    with pytest.raises(InsufficientDataError, match="need 4"):
        direction_compliance("-x", F[:3], P[:3], up[:3])
    bad = P.copy()
    bad[2, 1] = np.nan
    with pytest.raises(DataError, match="not finite"):
        direction_compliance("-x", F, bad, up)
    with pytest.raises(ConfigError, match="rated_load_N"):
        load_levels_N(-5.0)
    with pytest.raises(ConfigError, match="steps"):
        load_levels_N(100.0, 1)


def test_the_load_prompt_reads_back():
    for d in DIRECTIONS:
        for load in (0.0, 203.9, 2059.4):
            assert parse_load_prompt(load_prompt(d, load)) == (d, float(f"{load:.0f}"))
    assert parse_load_prompt("Clear the robot cell") is None
