"""Uncertainty of the ISO 9283 figures and the decision rules of ISO 14253-1.

The truth and the instrument are drawn at random (seed printed by the ``rng``
fixture; replay with ``ISO_TEST_SEED``); coverage is checked against the
binomial tolerance of the number of simulated tests.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fakes.sim.iso_stops import simulate_pose_test
from station.analysis.decision import decide
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.analysis.uncertainty import (
    Budget,
    mean_uncertainty,
    parse_tracker_uncertainty,
    population_rp,
    pose_uncertainty,
    three_s_uncertainty,
)
from app.cli import main
from station.errors import ConfigError
from station.verdict import Outcome

from .conftest import rp_population
from .labfiles import write_poses, write_stream_csv
from .synth import NAMES5, iso_stream, random_offsets

CMD = np.array(TABLE2_POSES_MM)


def _band(p: float, n: int, z: float = 3.5) -> float:
    return z * math.sqrt(p * (1 - p) / n)


@pytest.mark.parametrize("n", [10, 30])
def test_coverage_with_the_accuracy_systematic_and_micrometre_reading_noise(rng, n):
    """A tracker whose MPE is a fixed error of the session and whose readings scatter by 0.3-3 um, measuring a
    UR-like arm (stop scatter 3-7 um): a budget that states the reading noise covers AP and RP, and its RP is
    not lost in the MPE: read as per-reading noise (the budget without the noise) the MPE, some 15 um, would
    deflate the arm's 3-7 um scatter to nothing, and U would be about the figure itself."""
    T = 300
    hit_ap = np.zeros(T, bool)
    hit_rp = np.zeros(T, bool)
    rel_rp, rel_old = [], []
    for i in range(T):
        sim = simulate_pose_test(rng, n, sd_range_mm=(0.003, 0.007), reading_noise_um=(0.3, 3.0))
        kw = dict(instrument_a_um=sim.mpe_a_um, instrument_b_um_per_m=sim.mpe_b_um_per_m, trials=2000,
                  seed=int(rng.integers(2**31)))
        b = Budget(**kw, instrument_noise_um=sim.reading_noise_um).with_registration(sim.registration,
                                                                                      sim.fiducials_mm)
        fu = pose_uncertainty(sim.measured_mm, sim.commanded_mm, b, "P1")
        hit_ap[i] = abs(fu["AP_mm"].value - sim.AP_true_mm) <= fu["AP_mm"].U
        hit_rp[i] = abs(fu["RP_mm"].value - sim.RP_true_mm) <= fu["RP_mm"].U
        rel_rp.append(fu["RP_mm"].U / fu["RP_mm"].value)
        if i < 40:
            old = Budget(**kw).with_registration(sim.registration, sim.fiducials_mm)
            rel_old.append(pose_uncertainty(sim.measured_mm, sim.commanded_mm, old, "P1")["RP_mm"].U
                           / fu["RP_mm"].value)
    tol = _band(0.95, T)
    # the systematic error is counted whole though the registration absorbs its offset and angles: a bound
    assert hit_ap.mean() >= 0.95 - tol, f"AP coverage {hit_ap.mean():.3f} at n={n}"
    assert hit_rp.mean() >= 0.95 - tol, f"RP coverage {hit_rp.mean():.3f} at n={n}"
    assert np.median(rel_rp) < {10: 0.8, 30: 0.4}[n], f"median U/RP {np.median(rel_rp):.2f} at n={n}"
    assert np.median(rel_old) > 1.5 * np.median(rel_rp)


def test_population_rp_is_the_limit_of_eq2(rng):
    # isotropic: sigma (E chi_3 + 3 sd chi_3); anisotropic: against a large sample of eq. (2)
    s = rng.uniform(0.01, 0.1)
    assert population_rp(np.full(3, s * s)) == pytest.approx(rp_population(s), rel=1e-6)
    lam = rng.uniform(0.0, 1.0, 3) ** 3 * 0.01
    z = rng.standard_normal((400_000, 3)) * np.sqrt(lam)
    l = np.linalg.norm(z, axis=1)
    big = l.mean() + 3 * l.std(ddof=1)
    # the sample's own error: a few parts in 1e3 at 4e5 points
    assert float(population_rp(lam)) == pytest.approx(big, rel=6e-3)


@pytest.mark.parametrize("n", [5, 10, 30])
def test_coverage_of_ap_and_rp(rng, n):
    """|figure - truth| <= U in about 95 % of simulated tests with a random robot, tracker and registration."""
    T = 300
    hit_ap = np.zeros(T, bool)
    hit_rp = np.zeros(T, bool)
    int_rp = np.zeros(T, bool)
    rel_rp = []
    for i in range(T):
        sim = simulate_pose_test(rng, n)
        b = Budget(instrument_a_um=sim.mpe_a_um, instrument_b_um_per_m=sim.mpe_b_um_per_m, trials=2000,
                   seed=int(rng.integers(2**31))).with_registration(sim.registration, sim.fiducials_mm)
        fu = pose_uncertainty(sim.measured_mm, sim.commanded_mm, b, "P1")
        hit_ap[i] = abs(fu["AP_mm"].value - sim.AP_true_mm) <= fu["AP_mm"].U
        hit_rp[i] = abs(fu["RP_mm"].value - sim.RP_true_mm) <= fu["RP_mm"].U
        rel_rp.append(fu["RP_mm"].U / fu["RP_mm"].value)
        int_rp[i] = fu["RP_mm"].interval[0] <= sim.RP_true_mm <= fu["RP_mm"].interval[1]
    tol = _band(0.95, T)
    assert abs(hit_ap.mean() - 0.95) <= tol, f"AP coverage {hit_ap.mean():.3f} at n={n}"
    assert hit_rp.mean() >= 0.95 - tol, f"RP coverage {hit_rp.mean():.3f} at n={n}"
    # the measurand's PDF is skewed to the right (the scatter's scale is estimated from the stops): its RMS, and
    # so U = 2 u, over-covers (bench: 0.99-0.996 at 5 and 10 cycles; at 30 cycles 0.973 over 100 x 300 draws,
    # and a run of 300 above the binomial band of 0.95 in about 1 % of runs: soak seed 827657788, 0.997); a U
    # of several times the figure would still pass the line above, so instead of an upper bound on the coverage
    # the width is bounded by what 5, 10 or 30 stops allow (median U / RP per run of 300, 40 runs: 0.54-0.60 at
    # 10 cycles, 0.27-0.31 at 30)
    assert np.median(rel_rp) < {5: 1.8, 10: 0.8, 30: 0.4}[n], f"median U/RP {np.median(rel_rp):.2f} at n={n}"
    # the Monte Carlo 95 % coverage interval of the measurand (quantiles of the same draws as U): it too covers
    # more at few cycles, less so than U (bench, 3000 draws: 0.971 at 5 cycles, 0.963 at 10); a 299 of 300
    # draw at 5 cycles is then about a 1 % event (a soak run, seed 1186394634), so the bound above is one-sided
    # there, as for U, whose width is bounded above
    assert int_rp.mean() >= 0.95 - tol, f"RP 95 % interval coverage {int_rp.mean():.3f} at n={n}"
    if n >= 30:
        assert int_rp.mean() <= 0.95 + tol, f"RP 95 % interval coverage {int_rp.mean():.3f} at n={n}"


def test_ap_mc_matches_the_first_order_law_away_from_zero(rng):
    """AP far from 0 is linear in the mean: MC U = 2 u_t, first order U = t_95(nu) u; both within 10 %."""
    x = CMD[0] + np.array([0.5, -0.3, 0.2]) + rng.normal(0, 0.03, (30, 3))
    # an instrument whose accuracy the registration absorbed (stated as the frame's uncertainty, 0 here): the
    # sampling alone, whose t the comparison is about (no registration counts the accuracy as a Gaussian shift)
    b = Budget(trials=40_000, seed=3, registration_at_points=((tuple(CMD[0]), 0.0),))
    fu = pose_uncertainty(x, CMD[0], b, "P1")["AP_mm"]
    assert fu.agree is True
    # the t with 29 dof has sd sqrt(29/27) x its scale
    assert fu.u == pytest.approx(fu.u_gum * math.sqrt(29 / 27), rel=0.03)
    assert fu.interval[0] < fu.value < fu.interval[1]


def test_rp_takes_the_instrument_out_of_the_scatter(rng):
    """A perfect robot measured by a noisy tracker: RP is the tracker's; the truth (0) lies in the intervals."""
    T = 200
    low = inside = 0
    for i in range(T):
        sd_um = rng.uniform(10.0, 30.0)
        x = CMD[0] + rng.normal(0.0, sd_um / 1000.0, (30, 3))
        b = Budget(instrument_a_um=sd_um, instrument_b_um_per_m=0.0, instrument_kind="sd", trials=4000, seed=i)
        fu = pose_uncertainty(x, CMD[0], b)["RP_mm"]
        assert fu.value > 0.5 * rp_population(sd_um / 1000.0)
        low += fu.interval[0] <= 0.0
        inside += fu.value - fu.U <= 0.0
    assert low / T >= 0.95 - _band(0.95, T) and inside / T >= 0.95 - _band(0.95, T), (low / T, inside / T)


def test_scalar_figures_cover(rng):
    """AD-like means and RD-like 3 S: coverage of the truth over random draws."""
    T = 400
    hm = hs = 0
    for i in range(T):
        n = int(rng.integers(5, 31))
        mu, sd, noise = rng.uniform(-1, 1), rng.uniform(0.01, 0.05), rng.uniform(0.0, 0.02)
        v = rng.normal(mu, math.hypot(sd, noise), n)
        b = Budget(trials=2000, seed=i)
        fm = mean_uncertainty("AD_mm", "x", v, float(v.mean()), b)
        fs = three_s_uncertainty("RD_mm", "x", v, float(3 * v.std(ddof=1)), b, noise_var=noise ** 2)
        hm += abs(fm.value - mu) <= fm.U
        hs += fs.interval[0] <= 3 * sd <= fs.interval[1]
    tol = _band(0.95, T)
    assert abs(hm / T - 0.95) <= tol and abs(hs / T - 0.95) <= tol, (hm / T, hs / T)


def test_same_seed_same_figures_and_the_seed_matters():
    x = CMD[1] + np.random.default_rng(5).normal(0, 0.02, (10, 3))
    a = pose_uncertainty(x, CMD[1], Budget(trials=3000, seed=1))
    b = pose_uncertainty(x, CMD[1], Budget(trials=3000, seed=1))
    c = pose_uncertainty(x, CMD[1], Budget(trials=3000, seed=2))
    assert a["RP_mm"].u == b["RP_mm"].u and a["RP_mm"].u != c["RP_mm"].u


# --------------------------------------------------------------------------
# decision rules
# --------------------------------------------------------------------------


def test_guarded_rule_three_outcomes(rng):
    for _ in range(200):
        L = rng.uniform(0.01, 5.0)
        U = rng.uniform(0.001, 0.5) * L
        inside = rng.uniform(0.0, L - U)  # figure + U within the limit
        across = rng.uniform(L - U + 1e-9 * L, L + U)  # in the guard band
        beyond = rng.uniform(L + U + 1e-9 * L, L + 3 * U)
        assert decide(inside, L, U, "guarded").outcome is Outcome.PASS
        d = decide(across, L, U, "guarded")
        assert d.outcome is Outcome.NOT_DECIDED and d.passed is None
        assert d.guard_band == pytest.approx((L - U, L + U))
        assert decide(beyond, L, U, "guarded").outcome is Outcome.FAIL
        # signed figures (AD) by their magnitude
        assert decide(-beyond, L, U, "guarded").outcome is Outcome.FAIL
        # the simple rule: today's comparison whatever U
        assert decide(across, L, U, "simple").outcome is (Outcome.PASS if across <= L else Outcome.FAIL)
    assert decide(1.0, 1.0, 0.0, "guarded").outcome is Outcome.PASS  # no uncertainty: the simple comparison
    assert decide(0.5, 1.0, None, "guarded").outcome is Outcome.NOT_DECIDED  # no U: nothing proven
    with pytest.raises(ConfigError):
        decide(0.5, 1.0, 0.1, "lenient")


def test_tracker_uncertainty_option():
    assert parse_tracker_uncertainty("15+6/m") == dict(instrument_a_um=15.0, instrument_b_um_per_m=6.0,
                                                        instrument_kind="mpe")
    assert parse_tracker_uncertainty("sd:7.5+3/m")["instrument_kind"] == "sd"
    assert parse_tracker_uncertainty("10")["instrument_b_um_per_m"] == 0.0
    for bad in ("", "15+6", "abc", "-1+2/m", "0+0/m"):
        with pytest.raises(ConfigError):
            parse_tracker_uncertainty(bad)
    b = Budget(instrument_a_um=15.0, instrument_b_um_per_m=6.0)
    assert float(b.instrument_sd_mm([0.0, 0.0, 2000.0])) == pytest.approx((15 + 12) / 2 / 1000)


def test_registration_enters_ap_not_rp(rng):
    """A frame uncertainty stated at the poses widens AP's U by it (quadrature) and leaves RP's alone."""
    x = CMD[0] + np.array([0.4, 0.0, 0.0]) + rng.normal(0, 0.02, (30, 3))
    sd_reg = rng.uniform(0.05, 0.2)
    b0 = Budget(trials=40_000, seed=2)
    b1 = Budget(trials=40_000, seed=2, registration_at_points=((tuple(CMD[0]), sd_reg), (tuple(CMD[1]), 9.0)))
    f0, f1 = pose_uncertainty(x, CMD[0], b0), pose_uncertainty(x, CMD[0], b1)
    assert f1["AP_mm"].components["registration"] == pytest.approx(sd_reg)
    assert f1["AP_mm"].u == pytest.approx(math.hypot(f0["AP_mm"].u, sd_reg), rel=0.05)
    assert f1["RP_mm"].u == pytest.approx(f0["RP_mm"].u, rel=0.03)  # other draws of the same PDF


# --------------------------------------------------------------------------
# the command
# --------------------------------------------------------------------------


def _run(capsys, *argv):
    rc = main(["analyze", "iso9283", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.fixture
def files(rng, tmp_path):
    s = iso_stream(rng, n_cycles=15, rate_hz=100.0, offsets_mm=random_offsets(rng), scatter_mm=0.02,
                   noise_mm=0.005, wn_hz=10.0, zeta=0.8)
    return write_stream_csv(tmp_path / "S.csv", s.t, s.xyz), write_poses(tmp_path / "P.csv", NAMES5, CMD)


def test_guarded_rule_on_the_command_exit_codes(tmp_path, files, capsys):
    S, P = files
    rc, out, err = _run(capsys, "--stream", S, "--poses", P, "--limit-mm", "5", "--decision-rule", "guarded",
                        "--mc-trials", "4000", "--json", tmp_path / "g.json")
    d = json.loads((tmp_path / "g.json").read_text())
    rps = [x for x in d["verdicts"] if x["characteristic"] == "RP_mm"]
    v = max(rps, key=lambda x: x["value"])  # the largest RP: every other pose is within a limit set at it
    assert v["rule"] == "guarded" and v["k"] == 2.0 and v["U_mm"] == pytest.approx(2 * v["u_mm"], rel=1e-5)
    assert set(v["budget"]) >= {"sampling", "bias"}
    assert d["uncertainty"]["decision_rule"] == "guarded" and d["uncertainty"]["budget"]["trials"] == 4000
    assert "decision rule: guarded" in out
    rp, U, pose = v["value"], v["U_mm"], v["subject"]

    def at(limit, rule, pose=pose):
        rc, out, err = _run(capsys, "--stream", S, "--poses", P, "--limit", f"RP_mm={limit:.7f}", "--mc-trials",
                            "4000", "--decision-rule", rule, "--json", tmp_path / "x.json")
        x = json.loads((tmp_path / "x.json").read_text())
        mine = next(y for y in x["verdicts"] if y["characteristic"] == "RP_mm" and y["subject"] == pose)
        return rc, out, err, mine

    # on the limit: in the guard band -> not decided (exit 3) under guarded, pass (exit 0) under simple
    rc, out, err, mine = at(rp + 1e-6, "guarded")
    assert rc == 3 and mine["outcome"] == "not decided" and f"RP_mm {pose} not decided" in err
    assert "guard band" in err and "UND  RP_mm" in out
    assert mine["guard_band"] == pytest.approx([mine["limit"] - U, mine["limit"] + U], abs=2e-6)
    rc, out, err, mine = at(rp + 1e-6, "simple")  # the JSON rounds to 1e-6
    assert rc == 0 and mine["passed"] is True
    # inside the conformance zone, and beyond the guard band
    rc, _, _, mine = at(rp + 1.5 * U, "guarded")
    assert mine["outcome"] == "pass" and rc in (0, 3)  # another pose may sit in its own guard band
    # below the guard band: a fail. A limit below figure - U exists where U < RP; at 15 cycles U is about
    # 0.4 RP at most poses, but at the pose of the largest RP it may exceed RP (a high figure drawn from a
    # wide scatter: its sampling uncertainty is wide too), so the pose of the smallest U / RP is taken (over
    # 150 drawn streams that ratio was 0.29-0.53; at the pose of the largest RP up to 1.09)
    w = min(rps, key=lambda x: x["U_mm"] / x["value"])
    rp_w, U_w = w["value"], w["U_mm"]
    assert U_w < rp_w, (U_w, rp_w)
    rc, _, err, mine = at(rp_w - 1.5 * U_w if rp_w > 1.5 * U_w else 0.5 * (rp_w - U_w), "guarded", w["subject"])
    assert rc == 1 and mine["outcome"] == "fail" and f"RP_mm {w['subject']} = " in err


def test_simple_rule_with_a_budget_changes_no_verdict(tmp_path, files, capsys):
    S, P = files
    base = ["--stream", S, "--poses", P, "--limit-mm", "0.05", "--limit", "AP_mm=3"]
    rc0, _, err0 = _run(capsys, *base, "--json", tmp_path / "a.json")
    rc1, out1, err1 = _run(capsys, *base, "--tracker-uncertainty", "15+6/m", "--mc-trials", "2000",
                           "--json", tmp_path / "b.json")
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert rc0 == rc1 and err0 == err1
    assert [(v["value"], v["passed"]) for v in a["verdicts"]] == [(v["value"], v["passed"]) for v in b["verdicts"]]
    assert a["poses"] == b["poses"]
    assert "uncertainty" not in a and "u_mm" not in a["verdicts"][0]
    assert b["verdicts"][0]["rule"] == "simple" and b["verdicts"][0]["U_mm"] > 0


# --------------------------------------------------------------------------
# every characteristic of an analysis
# --------------------------------------------------------------------------


def test_every_characteristic_gets_an_uncertainty(rng):
    """Drift, orientation, AD/RD, MPT, POS/PST and paths of one long synthetic run; vAP of a multi-direction one.

    Each figure's U is positive and finite, its first-order u exists, and the figure lies in its own 95 %
    interval or within U of it (a figure is an estimate of the measurand, not far from it).
    """
    from station.analysis.iso9283.characteristics import analyze_iso9283
    from station.analysis.iso9283.uncertainty import figure_uncertainties

    from .synth import iso_cycle_programme, multidirection_programme, render

    servo = dict(wn_hz=15.0, zeta=0.9)
    abc_cmd = rng.uniform(-1, 1, (5, 3))
    prog = iso_cycle_programme(rng, n_cycles=20, scatter_mm=0.02, abc_commanded_rad=abc_cmd,
                               abc_offset_rad=rng.normal(0, 2e-3, (5, 3)), abc_scatter_rad=2e-4, dwell_s=0.4)
    s = render(rng, prog, start_mm=CMD[0], start_abc_rad=abc_cmd[0], rate_hz=200.0, noise_mm=0.005,
               abc_noise_rad=5e-5, **servo)
    res = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, orientation_rad=s.abc, commanded_orientation_rad=abc_cmd,
                          drift_block=10, linear_paths=[("P2", "P3")], n_planes=5, band_mm=0.05)
    b = Budget(trials=3000, seed=1, rate_hz=200.0, angle_sd_deg=math.degrees(5e-5))
    unc = figure_uncertainties(res, b, s.xyz)
    kinds = {k[0] for k in unc}
    assert {"AP_mm", "RP_mm", "PST_s", "dAP_mm", "dRP_mm", "APa_deg", "RPc_deg", "AD_mm", "RD_mm", "MPT_s",
            "AT_mm", "RT_mm"} <= kinds, kinds
    if any(pr.overshoot is not None and pr.overshoot.POS_mm for pr in res.poses.values()):
        assert "POS_mm" in kinds
    for (ch, subj), fu in unc.items():
        assert math.isfinite(fu.U) and fu.U > 0 and fu.u_gum is not None, (ch, subj, fu)
        lo, hi = fu.interval
        assert lo - fu.U <= fu.value <= hi + fu.U, (ch, subj, fu)
    # vAP: three approach directions
    dir_off = rng.normal(0, 0.4, (3, 3))
    mp = multidirection_programme(rng, commanded=CMD, pose=0, dir_offsets_mm=dir_off, n_each=10, scatter_mm=0.02)
    sv = render(rng, mp, start_mm=CMD[0] - [0, 0, 150.0], rate_hz=200.0, noise_mm=0.005, speed_mm_s=500.0, **servo)
    rv = analyze_iso9283(sv.t, sv.xyz, CMD[[0]], names=[NAMES5[0]])
    fv = figure_uncertainties(rv, b, sv.xyz)[("vAP_mm", NAMES5[0])]
    truth = max(np.linalg.norm(mp.target_mm[mp.direction == h].mean(axis=0) - mp.target_mm[mp.direction == k].mean(axis=0))
                for h in range(3) for k in range(3))
    assert abs(fv.value - truth) <= 2.5 * fv.U  # the figure's scatter about a truth drawn from 10 stops each


def test_stop_list_with_the_guarded_rule(tmp_path, rng, capsys):
    from .labfiles import write_stops

    n = 12
    names = ["P1", "P2"]
    pose = [p for _ in range(n) for p in names]
    cycle = [c for c in range(n) for _ in names]
    pts = np.array([CMD[names.index(p)] + 0.3 + rng.normal(0, 0.02, 3) for p in pose])
    S = write_stops(tmp_path / "s.csv", pose, cycle, pts[:, None, :])
    P = write_poses(tmp_path / "p.csv", names, CMD[:2])
    rc, out, err = _run(capsys, "--stops", S, "--poses", P, "--limit", "AP_mm=5", "--decision-rule", "guarded",
                        "--mc-trials", "2000", "--json", tmp_path / "o.json")
    d = json.loads((tmp_path / "o.json").read_text())
    assert rc == 0, err
    ap = [v for v in d["verdicts"] if v["characteristic"] == "AP_mm"]
    assert len(ap) == 2 and all(v["outcome"] == "pass" and 0 < v["U_mm"] < 0.2 for v in ap)
    assert {f["characteristic"] for f in d["uncertainty"]["figures"]} >= {"AP_mm", "RP_mm"}
