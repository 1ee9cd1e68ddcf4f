"""The drift programme's figures from visits' attained positions (pure: arrays in, figures out)."""

from __future__ import annotations

import numpy as np

from station.analysis.iso9283.drift_programme import drift_figures
from station.analysis.uncertainty import Budget


def _visits(rng, c, a, drifts, sigma, n):
    """Per visit ``{"P1": (stops, times)}``: barycentre ``c + a + drift``, scatter ``sigma`` per coordinate."""
    return [{"P1": (c + a + d + sigma * rng.standard_normal((n, 3)), 600.0 * k + np.arange(n) * 8.0)}
            for k, d in enumerate(drifts)]


def test_dap_and_drp_are_first_against_last_visit_and_hold_the_drawn_drift_within_u(rng):
    c = np.array([0.0, 1700.0, 1400.0])
    a = rng.normal(0.0, 0.5, 3)  # the pose's error
    step = rng.normal(0.0, 0.05, 3)  # the warm-up's displacement per visit, mm
    drifts = [k * step for k in range(4)]
    sigma, n = float(rng.uniform(0.005, 0.03)), 10
    # the stops carry no instrument noise: a budget without the instrument leaves U to their scatter
    budget = Budget(instrument_a_um=0.0, instrument_b_um_per_m=0.0)
    visits, drift, warnings = drift_figures(_visits(rng, c, a, drifts, sigma, n), {"P1": c}, 0.0, budget)
    assert not warnings and [v.visit for v in visits] == [1, 2, 3, 4]
    d = drift["P1"]
    # ISO 9283 drift: |AP(t_1) - AP(t_n)|, AP by seed 000 eq. (1) of each visit
    ap = [float(np.linalg.norm(v.attained_mm.mean(axis=0) - c)) for v in visits]
    assert d.dAP_mm == abs(ap[0] - ap[-1]) and (d.first_visit, d.last_visit) == (1, 4)
    assert d.dRP_mm == abs(visits[0].RP_mm - visits[-1].RP_mm)
    truth = abs(np.linalg.norm(a + drifts[-1]) - np.linalg.norm(a))
    assert abs(d.dAP_mm - truth) <= 2.0 * d.U_dAP_mm, (d, truth)  # one figure: k = 4
    # U from the two visits' means: of the order of sigma / sqrt(n), not of the pose's error
    assert 0.5 * sigma / np.sqrt(n) < d.U_dAP_mm < 8.0 * sigma / np.sqrt(n)
    assert abs(d.shift_mm - np.linalg.norm(drifts[-1])) <= 6.0 * sigma * np.sqrt(2.0 / n)
    assert visits[-1].t_since_start_s == np.mean(1800.0 + np.arange(n) * 8.0)


def test_a_pose_seen_at_one_visit_has_no_drift_and_says_so(rng):
    c = np.array([0.0, 1700.0, 1400.0])
    vs = _visits(rng, c, np.zeros(3), [np.zeros(3)] * 2, 0.01, 5)
    vs[1] = {}
    _, drift, warnings = drift_figures(vs, {"P1": c}, 0.0, Budget())
    assert drift == {} and any("P1" in w and "two needed" in w for w in warnings)
    assert any("visit 2: P1 not attained" in w for w in warnings)
