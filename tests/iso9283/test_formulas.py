"""The seed's formulas (1), (2), (7)-(10) on hand-checked and random data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from station.analysis.iso9283.characteristics import (
    distance_accuracy,
    minimum_posing_time,
    multidirectional_accuracy,
    overshoot_settling_stops,
    position_accuracy,
    position_repeatability,
)
from station.errors import DataError, InsufficientDataError

from .conftest import rp_estimate_sd, rp_population


def test_ap_rp_hand_example():
    a = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 2, 0], [0, -2, 0]])
    acc = position_accuracy(a + [0, 0, 3], [0, 0, 0], rows=[10, 20, 30, 40])
    assert acc.AP_mm == pytest.approx(3.0) and acc.APz_mm == pytest.approx(3.0)
    assert acc.n == 4 and acc.rows.tolist() == [10, 20, 30, 40]
    rep = position_repeatability(a)
    # l = 1, 1, 2, 2; l_bar = 1.5; S_l = sqrt(4 * 0.25 / 3)
    assert rep.l_bar_mm == pytest.approx(1.5)
    assert rep.S_l_mm == pytest.approx(math.sqrt(1 / 3))
    assert rep.RP_mm == pytest.approx(1.5 + 3 * math.sqrt(1 / 3))


def test_rp_of_gaussian_scatter(rng):
    sigma = rng.uniform(0.01, 1.0)
    n = 3000
    a = rng.normal(0, sigma, (n, 3)) + rng.uniform(-1000, 1000, 3)
    rp = position_repeatability(a).RP_mm
    assert abs(rp - rp_population(sigma)) < 5 * rp_estimate_sd(sigma, n)


def test_formula_input_checks():
    with pytest.raises(InsufficientDataError, match="RP needs at least 2"):
        position_repeatability(np.zeros((1, 3)))
    with pytest.raises(InsufficientDataError):
        position_accuracy(np.zeros((0, 3)), [0, 0, 0])
    with pytest.raises(DataError, match="shape"):
        position_accuracy(np.zeros((3, 2)), [0, 0, 0])
    with pytest.raises(DataError, match="NaN"):
        position_repeatability(np.array([[0, 0, 0], [np.nan, 0, 0]]))
    with pytest.raises(DataError, match="commanded_mm"):
        position_accuracy(np.zeros((3, 3)), [0, 0])


def test_vap_distance_mpt():
    means = np.array([[0.0, 0, 0], [3, 0, 0], [0, 4, 0]])
    v, pair = multidirectional_accuracy(means)
    assert v == pytest.approx(5.0) and pair == (1, 2)
    with pytest.raises(InsufficientDataError):
        multidirectional_accuracy(means[:1])
    AD, RD = distance_accuracy([10.0, 12.0, 14.0], 11.0)
    assert AD == pytest.approx(1.0) and RD == pytest.approx(6.0)
    assert distance_accuracy([10.0], 11.0)[1] is None
    assert minimum_posing_time([5.0, 6.0, 7.0, 100.0]) == pytest.approx(6.0)
    with pytest.raises(InsufficientDataError, match="MPT needs 3"):
        minimum_posing_time([5.0, 6.0])


def _overshoot_reference(t, xyz, i_from, i_att, band):
    """Eqs. (5)-(6) for one stop, sample by sample (a plain reading of the seed)."""
    a = xyz[i_att]
    D = [float(np.linalg.norm(xyz[i] - a)) for i in range(i_from, i_att + 1)]
    m = next(i for i, d in enumerate(D) if d <= band)
    outside = [i for i in range(m + 1, len(D)) if D[i] > band]
    if not outside:
        return 0.0, 0.0
    pos = max(D[i] for i in outside)
    n_ = outside[-1] + 1
    return pos, t[i_from + n_] - t[i_from + m]


def test_overshoot_vectorised_matches_sample_by_sample(rng):
    # damped oscillations with noise around random rest points, random bands
    K, L = 40, 120
    t = np.arange(K * L) * 0.01
    xyz = np.zeros((K * L, 3))
    i_from = np.arange(K) * L
    i_att = i_from + L - 5
    for k in range(K):  # build the test data stop by stop
        tau = np.arange(L) * 0.01
        amp = rng.uniform(0.2, 3.0)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        osc = amp * np.exp(-tau * rng.uniform(3, 15)) * np.cos(2 * np.pi * rng.uniform(3, 12) * tau)
        xyz[k * L:(k + 1) * L] = rng.uniform(-500, 500, 3) + osc[:, None] * d + rng.normal(0, 0.01, (L, 3))
    band = rng.uniform(0.05, 1.0, K)
    out = overshoot_settling_stops(t, xyz, i_from, i_att, band)
    for k in range(K):
        pos, pst = _overshoot_reference(t, xyz, i_from[k], i_att[k], band[k])
        assert out["POS_mm"][k] == pytest.approx(pos, abs=1e-12)
        assert out["PST_s"][k] == pytest.approx(pst, abs=1e-12)
        if pos > 0:
            i = out["i_max"][k]
            assert np.linalg.norm(xyz[i] - xyz[i_att[k]]) == pytest.approx(pos)
        else:
            assert out["i_max"][k] == -1
