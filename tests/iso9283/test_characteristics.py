"""Every characteristic of the analysis against the truth of synthetic streams.

Thresholds: k sigma / sqrt(n) from the tracker noise and the scatter drawn,
plus the servo residue actually present at the attained samples (what the
least-velocity window cannot see, measured on the noise-free motion).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.errors import ConfigError

from .conftest import chi3_q, rp_estimate_sd, rp_population
from .synth import NAMES5, iso_cycle_programme, iso_stream, multidirection_programme, random_offsets, render

CMD = np.array(TABLE2_POSES_MM)
RATE = 200.0
SERVO = dict(wn_hz=15.0, zeta=0.9)
Q = chi3_q(1e-6)


def residue(res, s):
    """Largest distance between the true position at an attained sample and the stop's target."""
    st = res.extraction.stops
    a = st.status == 0
    real = (s.prog.dwell_s > 0) & (s.prog.pose >= 0)
    return float(np.linalg.norm(s.clean[st.row[a]] - s.prog.target_mm[real], axis=1).max())


def test_ap_rp_known_offsets_and_scatter(rng):
    n, noise, scatter = 30, 0.01, float(rng.uniform(0.02, 0.08))
    off = random_offsets(rng)
    s = iso_stream(rng, n_cycles=n, rate_hz=RATE, offsets_mm=off, scatter_mm=scatter, noise_mm=noise, **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, limits={"RP_mm": 10.0})
    assert not res.partial and res.iso_conformant and res.passed is True
    r0 = residue(res, s)
    sig = math.hypot(noise, scatter)
    for p, name in enumerate(NAMES5):
        pr = res.poses[name]
        assert pr.n_cycles == n and pr.attained_cycle.tolist() == list(range(n))
        acc, rep = pr.accuracy, pr.repeatability
        ap_vec = np.array([acc.APx_mm, acc.APy_mm, acc.APz_mm])
        assert np.linalg.norm(ap_vec - off[p]) < Q * sig / math.sqrt(n) + r0
        assert abs(acc.AP_mm - np.linalg.norm(off[p])) < Q * sig / math.sqrt(n) + r0
        assert abs(rep.RP_mm - rp_population(sig)) < 5 * rp_estimate_sd(sig, n) + 4 * r0
        # the numbers carry their provenance
        assert acc.n == rep.n == n and np.array_equal(acc.rows, pr.attained_row)
        assert np.allclose(s.xyz[pr.attained_row], pr.attained_mm)


def test_vap_from_three_approach_directions(rng):
    n_each, noise, scatter = 10, 0.005, 0.02
    pose = int(rng.integers(0, 5))
    dir_off = rng.normal(0, 0.4, (3, 3))
    prog = multidirection_programme(rng, commanded=CMD, pose=pose, dir_offsets_mm=dir_off, n_each=n_each,
                                    scatter_mm=scatter)
    s = render(rng, prog, start_mm=CMD[pose] - [0, 0, 150.0], rate_hz=RATE, noise_mm=noise, speed_mm_s=500.0, **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD[[pose]], names=[NAMES5[pose]])
    pr = res.poses[NAMES5[pose]]
    md = pr.multidirectional
    assert md.n_directions == 3 and sorted(g.label for g in md.groups) == ["+x", "+y", "+z"]
    assert all(g.n == n_each for g in md.groups)
    truth_means = np.array([prog.target_mm[prog.direction == d].mean(axis=0) for d in range(3)])
    v_true = max(np.linalg.norm(truth_means[h] - truth_means[k]) for h in range(3) for k in range(3))
    r0 = residue(res, s)
    assert abs(md.vAP_mm - v_true) < 2 * (Q * noise / math.sqrt(n_each) + r0)
    # 30 approach start points, far from the pose: reported, not used
    ex = res.extraction
    assert int(np.count_nonzero(ex.stops.status == 1)) == 3 * n_each
    # AP/RP use one direction (the largest group, ties: the first)
    assert pr.n_cycles == n_each and md.groups[0].label == "+x"
    d = res.to_dict()["poses"][NAMES5[pose]]
    assert d["vAP_mm"] == pytest.approx(md.vAP_mm, abs=1e-6) and d["n_directions"] == 3


def test_distance_accuracy_and_repeatability(rng):
    n, noise, scatter = 20, 0.005, float(rng.uniform(0.02, 0.1))
    off = random_offsets(rng)
    s = iso_stream(rng, n_cycles=n, rate_hz=RATE, offsets_mm=off, scatter_mm=scatter, noise_mm=noise, **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5)
    (d,) = res.distances
    assert (d.pose_a, d.pose_b, d.n) == ("P2", "P4", n)
    prog = s.prog
    ta, tb = prog.target_mm[prog.pose == 1], prog.target_mm[prog.pose == 3]
    D_true = np.linalg.norm(ta - tb, axis=1)
    r0 = residue(res, s)
    assert d.Dc_mm == pytest.approx(np.linalg.norm(CMD[1] - CMD[3]))
    assert abs(d.AD_mm - (D_true.mean() - d.Dc_mm)) < 5 * math.sqrt(2) * noise / math.sqrt(n) + 2 * r0
    # RD = 3 S_D; the scatter along the P2-P4 line is sqrt(2) (scatter^2 + noise^2)^0.5
    sd_d = math.sqrt(2) * math.hypot(scatter, noise)
    assert abs(d.RD_mm - 3 * sd_d) < 5 * 3 * sd_d / math.sqrt(2 * (n - 1)) + 6 * r0
    assert np.allclose(np.linalg.norm(s.xyz[d.rows_a] - s.xyz[d.rows_b], axis=1), d.D_mm)


def _posing_time_reference(t, xyz, c_prev, band_prev, ps_next, c_next, band_next):
    """Posing time by the definition, sample by sample (leave the start band .. settle in the end band)."""
    a0, a1 = xyz[c_prev], xyz[c_next]
    i = c_prev
    while np.linalg.norm(xyz[i + 1] - a0) <= band_prev:
        i += 1
    leave = i
    D = [np.linalg.norm(xyz[j] - a1) for j in range(ps_next, c_next + 1)]
    m = next(j for j, x in enumerate(D) if x <= band_next)
    out = [j for j in range(m + 1, len(D)) if D[j] > band_next]
    settle = ps_next + (out[-1] + 1 if out else m)
    return t[settle] - t[leave]


def test_minimum_posing_time(rng):
    n = 5
    s = iso_stream(rng, n_cycles=n, rate_hz=RATE, offsets_mm=random_offsets(rng), noise_mm=0.005,
                   wn_hz=8.0, zeta=float(rng.uniform(0.4, 0.9)))
    band = float(rng.uniform(0.05, 0.3))
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, band_mm=band, limits={"MPT_s": 100.0})
    st = res.extraction.stops
    assert len(res.posing_times) == 5
    durations = s.t_arrive - s.t_move_start
    for m in res.posing_times:
        a, b = NAMES5.index(m.from_pose), NAMES5.index(m.to_pose)
        ks = [k for k in range(1, st.n) if st.pose[k - 1] == a and st.pose[k] == b]
        ref = [_posing_time_reference(s.t, s.xyz, st.i_center[k - 1], band, st.i_phase_start[k], st.i_center[k],
                                      band) for k in ks]
        assert m.n_available == len(ks) and m.n == 3
        assert np.allclose(m.times_s, ref, atol=1e-12)
        assert m.MPT_s == pytest.approx(np.mean(ref[:3]), abs=1e-12)
        prof = durations[(s.prog.pose == b)][1:]  # commanded profile durations of this move
        assert prof.min() - 0.05 < m.MPT_s < prof.max() + 0.6  # a stop takes the profile plus settling
    assert all(v.passed for v in res.verdicts if v.characteristic == "MPT_s")


def test_drift_over_a_long_run(rng):
    n, noise, scatter = 40, 0.005, 0.02
    drift = rng.normal(size=3)
    drift *= 0.01 / np.linalg.norm(drift)  # mm per cycle
    prog = iso_cycle_programme(rng, n_cycles=n, scatter_mm=scatter, drift_mm_per_cycle=drift, dwell_s=0.4)
    s = render(rng, prog, start_mm=CMD[0], rate_hz=100.0, noise_mm=noise, **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, drift_block=10)
    r0 = residue(res, s)
    sig = math.hypot(noise, scatter)
    for name in NAMES5:
        dr = res.poses[name].drift
        assert dr.AP_mm.size == 4 and dr.n_per_block.tolist() == [10] * 4
        assert abs(dr.shift_mm - 30 * 0.01) < Q * sig * math.sqrt(2 / 10) + 2 * r0
        assert dr.dAP_mm == pytest.approx(abs(dr.AP_mm[-1] - dr.AP_mm[0]))
        assert np.all(np.diff(dr.block_t_s) > 0)
    short = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, drift_block=25)
    assert all(p.drift is None for p in short.poses.values())


def test_orientation_accuracy_and_repeatability(rng):
    n, sa, na = 20, 2e-4, 5e-5  # rad
    abc_cmd = rng.uniform(-1, 1, (5, 3))
    abc_off = rng.normal(0, 2e-3, (5, 3))
    prog = iso_cycle_programme(rng, n_cycles=n, scatter_mm=0.02, abc_commanded_rad=abc_cmd, abc_offset_rad=abc_off,
                               abc_scatter_rad=sa)
    s = render(rng, prog, start_mm=CMD[0], start_abc_rad=abc_cmd[0], rate_hz=RATE, noise_mm=0.005,
               abc_noise_rad=na, **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, orientation_rad=s.abc, commanded_orientation_rad=abc_cmd,
                          limits={"RPa_deg": 1.0})
    sig = math.hypot(sa, na)
    for p, name in enumerate(NAMES5):
        o = res.poses[name].orientation
        assert o.n == n
        assert np.all(np.abs(o.AP_rad - abc_off[p]) < 5 * sig / math.sqrt(n) + 1e-6)
        assert np.all(np.abs(o.RP_rad - 3 * sig) < 5 * 3 * sig / math.sqrt(2 * (n - 1)) + 3e-6)
    d = res.to_dict()["poses"]["P1"]["orientation"]
    assert d["RPa_deg"] == pytest.approx(math.degrees(res.poses["P1"].orientation.RP_rad[0]), abs=1e-6)
    assert all(v.passed for v in res.verdicts)
    no_cmd = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, orientation_rad=s.abc)
    assert no_cmd.poses["P1"].orientation.AP_rad is None
    assert np.allclose(no_cmd.poses["P1"].orientation.RP_rad, res.poses["P1"].orientation.RP_rad)


def test_path_accuracy_of_linear_moves(rng):
    n, noise, scatter = 8, 0.002, 0.05
    off = random_offsets(rng, 1.0)
    s = iso_stream(rng, n_cycles=n, rate_hz=RATE, offsets_mm=off, scatter_mm=scatter, noise_mm=noise, **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, linear_paths=[("P2", "P3"), ("P3", "P4")], n_planes=5)
    assert [(p.from_pose, p.to_pose) for p in res.paths] == [("P2", "P3"), ("P3", "P4")]
    prog = s.prog
    for pa in res.paths:
        a, b = NAMES5.index(pa.from_pose), NAMES5.index(pa.to_pose)
        kb = np.flatnonzero(prog.pose == b)
        kb = kb[kb > 0]
        A, B = CMD[a], CMD[b]
        u = (B - A) / np.linalg.norm(B - A)
        As, Bs = prog.target_mm[kb - 1], prog.target_mm[kb]  # true start and end of each traversal
        # the servo keeps a straight reference straight: each path is the segment As-Bs
        lam = (pa.plane_s_mm[None, :] - ((As - A) @ u)[:, None]) / ((Bs - As) @ u)[:, None]
        X = As[:, None, :] + lam[..., None] * (Bs - As)[:, None, :]  # (n, m, 3)
        bary = X.mean(axis=0)
        at_true = np.linalg.norm(bary - (A + pa.plane_s_mm[:, None] * u), axis=1)
        l_true = np.linalg.norm(X - bary, axis=2)
        rt_true = l_true.mean(axis=0) + 3 * l_true.std(axis=0, ddof=1)
        assert pa.n == kb.size
        assert np.all(np.abs(pa.AT_i_mm - at_true) < Q * noise / math.sqrt(pa.n) * 2)
        assert np.all(np.abs(pa.RT_i_mm - rt_true) < 8 * noise)
        assert pa.AT_mm == pytest.approx(pa.AT_i_mm.max()) and pa.RT_mm == pytest.approx(pa.RT_i_mm.max())


def test_json_keys_verdicts_and_partial_results(rng):
    s = iso_stream(rng, n_cycles=4, rate_hz=100.0, offsets_mm=random_offsets(rng), scatter_mm=0.03,
                   noise_mm=0.01, skip=[(2, 3)], **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, limits={"RP_mm": 0.5, "AP_mm": 0.0})
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert set(d["poses"]) == set(NAMES5)
    for name, p in d["poses"].items():
        for key in ("AP_mm", "RP_mm", "POS_mm", "PST_s", "n_cycles", "vAP_mm", "attained", "commanded_mm"):
            assert key in p
        # P5 of cycle 2 comes from P3 through P4 without a stop: its final approach is still along
        # P4->P5, so every pose has one approach direction
        assert p["vAP_mm"] is None and p["n_directions"] == 1
        assert len(p["attained"]["x_mm"]) == p["n_cycles"] == res.poses[name].n_cycles
        assert p["RP_mm"] == pytest.approx(res.poses[name].repeatability.RP_mm, abs=1e-6)
    assert d["poses"]["P4"]["n_cycles"] == 3 and d["poses"]["P5"]["n_cycles"] == 4  # cycle 2: no P4
    assert d["extraction"]["missing"] == [{"cycle": 2, "pose": "P4", "reason": d["extraction"]["missing"][0]["reason"],
                                           "t_after_s": d["extraction"]["missing"][0]["t_after_s"],
                                           "t_before_s": d["extraction"]["missing"][0]["t_before_s"]}]
    assert d["partial"] is True and res.partial and not res.iso_conformant
    # RP passes 0.5 mm, AP cannot pass 0 mm: the whole result fails
    by = {(v["characteristic"], v["subject"]): v["passed"] for v in d["verdicts"]}
    assert all(by[("RP_mm", n)] is True for n in NAMES5) and all(by[("AP_mm", n)] is False for n in NAMES5)
    assert d["passed"] is False and res.passed is False
    # a limit just under a pose's RP fails it, just over passes it
    rp = res.poses["P3"].repeatability.RP_mm
    for lim, want in ((rp * 0.999, False), (rp * 1.001, True)):
        r2 = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, limits={"RP_mm": lim})
        assert [v.passed for v in r2.verdicts if v.subject == "P3"] == [want]
    # one cycle: RP cannot be computed; its verdict is undecided, not a number
    one = s.t < s.t_depart[4]
    r1 = analyze_iso9283(s.t[one], s.xyz[one], CMD, names=NAMES5, limits={"RP_mm": 0.5})
    assert r1.partial and r1.passed is None
    assert all(p.repeatability is None and p.n_cycles == 1 for p in r1.poses.values())
    assert any("RP needs at least 2" in w for w in r1.warnings)
    assert all(v.passed is None and v.value is None for v in r1.verdicts)
    with pytest.raises(ConfigError, match="unknown limit 'RPP_mm'"):
        analyze_iso9283(s.t, s.xyz, CMD, limits={"RPP_mm": 1})


def test_the_reasons_a_run_is_not_iso_conformant_are_named(rng):
    """Fewer cycles, a skipped stop and an undecidable limit each give their own reason; a clean 30-cycle run none."""
    from station.analysis.iso9283.characteristics import conformance_text

    n = int(rng.integers(4, 9))
    cyc, p = int(rng.integers(1, n - 1)), int(rng.integers(1, 5))  # a stop in the middle of the run
    s = iso_stream(rng, n_cycles=n, rate_hz=RATE, skip=((cyc, p),), **SERVO)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, limits={"RP_mm": 10.0, "vAP_mm": 1.0, "AT_mm": 1.0})
    assert not res.iso_conformant and len(res.iso_reasons) == 4, res.iso_reasons
    short, missing, undecided, not_computed = res.iso_reasons
    counts = {name: res.poses[name].n_cycles for name in NAMES5}
    assert short == "fewer than 30 cycles at " + ", ".join(f"{k} {v}" for k, v in counts.items())
    assert missing.startswith(f"missing stops: {NAMES5[p]} in cycle(s) {cyc} ")
    assert undecided.startswith("limit(s) not decided: vAP_mm P1 (1 approach direction(s), 3 needed)")
    assert not_computed == "limit(s) given for characteristics this analysis did not compute: AT_mm"
    assert conformance_text(res.iso_reasons).startswith("ISO 9283 conformant: no: fewer than 30 cycles")
    assert res.to_dict()["iso_reasons"] == list(res.iso_reasons)
    full = iso_stream(rng, n_cycles=30, rate_hz=RATE, **SERVO)
    ok = analyze_iso9283(full.t, full.xyz, CMD, names=NAMES5, limits={"RP_mm": 10.0})
    assert ok.iso_conformant and ok.iso_reasons == () and conformance_text(ok.iso_reasons) == "ISO 9283 conformant: yes"
