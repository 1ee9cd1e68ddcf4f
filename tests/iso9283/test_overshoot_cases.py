"""POS and PST: the two cases of seed Figs. 5-6 (3.2.3) through the whole analysis.

Case 1 (Fig. 5, approach to P1): with the 0.5 mm band the tool enters at
45.10 s, leaves at 45.22 s (0.501762 mm), re-enters at 45.23 s and stays:
POS 0.501762 mm, PST 0.13 s; with P1's own RP (0.200954 mm) as the band the
approach is overdamped: POS 0, PST 0.
Case 2 (Fig. 6): overdamped for 0.5 mm; for 0.2 mm the tool enters at 66.16 s,
leaves at 66.22 s, re-enters at 66.27 s: POS 0.223278 mm, PST 0.11 s.

The approach profiles are written into a stream of whole cycles (the other
poses approached by an overdamped servo), then analysed end to end.  Each run
draws the geometry, the time of the event, and a common scale of distances
and bands (the verdicts and PST do not depend on it; POS scales with it).
"""

from __future__ import annotations

import numpy as np
import pytest

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.poses import TABLE2_POSES_MM

from .synth import NAMES5, iso_stream, random_offsets

RATE = 100.0  # the seed's 0.01 s sampling
SEED_RP_P1 = 0.200954


def case_profile(case: int):
    """Distance to the attained pose at the samples j = 0.. from the first entry (seed times).

    Returns (D_before (30 samples leading to j=0, decreasing), D_after (j >= 0), expected dict).
    """
    if case == 1:
        after = [0.49] + [0.35 - 0.1 * np.sin(np.pi * j / 12) for j in range(1, 12)] + [0.501762, 0.49]
        after += list(0.49 * (90 - np.arange(14, 91)) / 77.0)  # monotone to 0 at 46.0 s (j = 90)
        before = list(0.7 - 0.2 * np.arange(30) / 29.0)  # 0.7 .. 0.5, outside 0.5 (0.5 itself is the band edge)
        before[-1] = 0.505
        expect = {0.5: (0.501762, 0.13), SEED_RP_P1: (0.0, 0.0)}
    else:
        before = list(0.6 - 0.15 * np.arange(30) / 29.0)  # 0.6 .. 0.45: enters 0.5 in here, stays
        after = [0.19, 0.185, 0.18, 0.182, 0.188, 0.195, 0.21, 0.215, 0.223278, 0.218, 0.205, 0.19]
        after += list(0.19 * (44 - np.arange(12, 45)) / 32.0)  # monotone to 0 at 66.6 s (j = 44)
        before = [b if b > 0.5 or k < 20 else min(b, 0.47 - 0.005 * k) for k, b in enumerate(before)]
        before = list(np.maximum(np.minimum.accumulate(before), 0.2))
        expect = {0.5: (0.0, 0.0), SEED_RP_P1: (0.223278, 0.11)}
    return np.array(before), np.array(after), expect


@pytest.mark.parametrize("case", [1, 2])
def test_fig5_fig6_opposite_verdicts_on_the_same_data(rng, case):
    scale = float(rng.uniform(0.3, 3.0))
    n_cycles = 3
    s = iso_stream(rng, n_cycles=n_cycles, rate_hz=RATE, offsets_mm=random_offsets(rng), scatter_mm=0.02,
                   noise_mm=1e-6, wn_hz=20.0, zeta=1.2, dwell_s=2.0)
    t, xyz = s.t, s.xyz.copy()
    before, after, expect = case_profile(case)
    before, after = before * scale, after * scale
    p1 = np.flatnonzero(s.prog.pose == 0)
    for k in p1:  # write the approach into each cycle's stop at P1
        a = s.prog.target_mm[k]
        D = np.linalg.norm(s.clean - a, axis=1)
        # from where the servo is still 1 mm + twice the profile's start away, 20 samples of
        # straight approach lead into the profile (the distance only decreases until the entry)
        jL = int(np.flatnonzero((D >= 2 * before[0] + 1.0) & (t < s.t_arrive[k] + 0.5))[-1])
        e = (s.clean[jL] - a) / D[jL]
        jb = jL + 20
        j0 = jb + before.size
        xyz[jL:jb] = a + np.linspace(D[jL], before[0], 21)[:-1, None] * e
        xyz[jb:j0] = a + before[:, None] * e
        xyz[j0:j0 + after.size] = a + after[:, None] * e
        j_dep = int(round(s.t_depart[k] * RATE))
        assert j_dep - (j0 + after.size) > 0.2 * RATE  # the dwell goes on at rest
        xyz[j0 + after.size:j_dep] = a
    xyz += rng.normal(0, 1e-6, xyz.shape)

    verdicts = {}
    for band in (0.5, SEED_RP_P1):
        res = analyze_iso9283(t, xyz, TABLE2_POSES_MM, names=NAMES5, band_mm=band * scale,
                              limits={"POS_mm": 0.0})
        o = res.poses["P1"].overshoot
        pos, pst = expect[band]
        assert o.n == n_cycles and o.band_source == "limit"
        assert np.allclose(o.POS_j_mm, pos * scale, atol=1e-5)
        assert np.allclose(o.PST_j_s, pst, atol=1e-9)
        assert o.POS_mm == pytest.approx(pos * scale, abs=1e-5)
        assert o.PST_s == pytest.approx(pst, abs=1e-9)
        if pos > 0:  # the sample of the overshoot is the one written with it
            for r, rm in zip(o.rows, o.row_max):
                assert np.linalg.norm(xyz[rm] - xyz[r]) == pytest.approx(pos * scale, abs=1e-5)
        for other in ("P2", "P3", "P4", "P5"):  # the overdamped servo never overshoots
            assert res.poses[other].overshoot.POS_mm == 0.0
        verdicts[band] = (o.approach, [v.passed for v in res.verdicts if v.subject == "P1"][0])
    assert verdicts[0.5] != verdicts[SEED_RP_P1]
    if case == 1:
        assert verdicts[0.5] == ("overshoot", False) and verdicts[SEED_RP_P1] == ("overdamped", True)
    else:
        assert verdicts[0.5] == ("overdamped", True) and verdicts[SEED_RP_P1] == ("overshoot", False)


def test_own_rp_band_and_a_servo_that_overshoots(rng):
    """Without a band the limit band is each pose's own RP (seed 3.2.1); POS/PST follow the true motion."""
    noise = 0.002
    s = iso_stream(rng, n_cycles=5, rate_hz=RATE, scatter_mm=0.05, noise_mm=noise, wn_hz=6.0,
                   zeta=float(rng.uniform(0.3, 0.5)))
    res = analyze_iso9283(s.t, s.xyz, TABLE2_POSES_MM, names=NAMES5)
    st = res.extraction.stops
    for name, pr in res.poses.items():
        o = pr.overshoot
        assert o.band_source == "own_RP" and o.band_mm == pr.repeatability.RP_mm
        assert o.POS_mm > o.band_mm and 0 < o.PST_s < 1.0  # an underdamped servo swings out of the band
        # the overshoot is a true excursion, and after the settling sample the true motion stays in the band
        for j, k in enumerate(np.flatnonzero(np.isin(st.row, o.rows))):
            a_true = s.clean[st.row[k]]
            if o.row_max[j] >= 0:
                assert abs(o.POS_j_mm[j] - np.linalg.norm(s.clean[o.row_max[j]] - a_true)) < 10 * noise
            d_after = np.linalg.norm(s.clean[o.row_settled[j]:st.row[k] + 1] - a_true, axis=1)
            assert d_after.max() < o.band_mm + 10 * noise
