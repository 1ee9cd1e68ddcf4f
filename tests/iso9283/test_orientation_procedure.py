"""Orientation in the ISO 9283 procedure: a T-Mac on the tool over emScon (6D continuous time) against the
fake station. Orientation AP and RP (a, b, c) per pose within U of the simulated arm's truth (its drawn
kinematic and stopping errors, seen through the run's own registered frame), in the stored rows, the JSON,
the console and the report; orientation vAP (a, b, c) per vAP pose within U of the truth of its approach
directions; every orientation figure in the robot's history and page; a position-only tracker's run is as before
(no orientation rows)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from scipy import stats

from app.assemble import RunRequest, run_procedure
from fakes.sim.six_dof import T_MAC_ANGLE_SD_DEG
from fakes.station import FakeStation
from procedures.devices import DeviceSet
from procedures.iso9283 import IsoPlan, registration_of, summary
from station.analysis.iso9283.orientation import abc_of_matrices
from station.config import config_from_dict
from station.errors import ConfigError
from station.programs.builders import TOOL_DOWN
from station.runner import ScriptedOperator
from station.store import RunStore
from tests.pace import LOCKSTEP

#: two procedure runs on the fakes (about a minute each on a shared machine)
pytestmark = pytest.mark.timeout(900)

CYCLES = 5
#: vAP cycles: each direction of a vAP pose is approached once a cycle; 4 stops a direction give vAP its U
VAP_CYCLES = 4
KEYS = [f"{kind}{ax}_deg" for ax in "abc" for kind in ("AP", "RP")]
VKEYS = [f"vAP{ax}_deg" for ax in "abc"]


def _run(tmp, seed, *, six_dof: bool, run_id: str):
    with FakeStation.start(seed=seed, time_scale=LOCKSTEP) as station:
        limits = {"rp_limit_mm": 0.5, **({"apa_limit_deg": 5.0} if six_dof else {})}
        d = station.config_dict(store_path=str(tmp / "s.sqlite"), report_dir=str(tmp / "reports"),
                                iso9283={"cycles": CYCLES, "vap_cycles": VAP_CYCLES}, limits=limits)
        if six_dof:
            d["devices"]["tracker"]["six_dof"] = True
        d["uncertainty"] = {"mc_trials": 4000}
        devices = DeviceSet(urls={"tracker": station.tracker_url, "controller": station.controller_url},
                            time_scale=station.world.clock.time_scale)
        out = run_procedure(RunRequest(config_from_dict(d), "iso9283", devices=devices,
                                       operator=ScriptedOperator(True), quiet=True, run_id=run_id, config_dir=tmp))
        assert out.status == "done", out.error
        with RunStore(tmp / "s.sqlite") as store:
            truth = (_true_orientation(store, run_id, station.world), _true_vap_orientation(store, run_id, station.world)
                     ) if six_dof else None
    return truth


def _wrap_deg(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def _true_orientation(store, run_id, world) -> dict:
    """Per pose: the angles (deg) of the arm's true TCP rotation at the attained instants, as the tracker reads
    them, its noise aside (its session's small systematic rotation in), in the run's registered frame."""
    reg = registration_of({s.name: s.output for s in store.steps(run_id) if s.status == "done"})
    tr = world.tracker
    from station.models.rotation import rotvec_to_matrix

    R_read = rotvec_to_matrix(tr.systematic_rotvec_rad) @ tr.tracker_T_base[:3, :3]
    out = {}
    for name, pose in store.result(run_id, "iso9283")["pose"]["poses"].items():
        t = np.asarray(pose["attained"]["t_s"])
        R_base = world.arm.tool_pose(t - tr.latency_s)[:, :3, :3]
        out[name] = np.degrees(abc_of_matrices(reg.R.T @ R_read @ R_base))
    return out


def _true_vap_orientation(store, run_id, world) -> dict:
    """Per vAP pose: ``(vAP_a, vAP_b, vAP_c)`` (deg) of the arm's true angles at the attained instants of each
    approach direction (as :func:`_true_orientation` reads them), and the directions' stop counts."""
    from procedures.iso9283 import STREAM, stream_steps
    from station.models.rotation import rotvec_to_matrix

    reg = registration_of({s.name: s.output for s in store.steps(run_id) if s.status == "done"})
    done = store.done_steps(run_id)
    index = {s.name: i for i, s in done.items()}
    _, vap_steps = stream_steps(IsoPlan.from_params(store.run(run_id).params))
    t = np.sort(store.samples(run_id, STREAM, steps=[index[n] for n in vap_steps if n in index])["t"], kind="stable")
    tr = world.tracker
    R_read = rotvec_to_matrix(tr.systematic_rotvec_rad) @ tr.tracker_T_base[:3, :3]
    cmd = np.degrees(abc_of_matrices(TOOL_DOWN))[0]
    out = {}
    for name, pose in store.result(run_id, "iso9283")["vap"]["poses"].items():
        means, ns = [], []
        for g in pose["directions"]:
            R_base = world.arm.tool_pose(t[np.asarray(g["rows"])] - tr.latency_s)[:, :3, :3]
            means.append(np.mean(_wrap_deg(np.degrees(abc_of_matrices(reg.R.T @ R_read @ R_base)) - cmd), axis=0))
            ns.append(len(g["rows"]))
        out[name] = (np.ptp(np.array(means), axis=0), ns)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory, request):
    from tests.seeding import session_seed

    tmp = tmp_path_factory.mktemp("orient")
    seed = int(np.random.default_rng([session_seed(request.config), 9283]).integers(0, 2**31 - 1))
    truth = _run(tmp, seed, six_dof=True, run_id="six")
    _run(tmp, seed, six_dof=False, run_id="three")
    return tmp, seed, truth


#: one-sided tail of each noise check (30 per run: the family's false alarms stay near 3e-4)
TAIL = 1e-5


def test_orientation_figures_are_the_arms_truth_within_their_uncertainty(runs):
    tmp, seed, (truth, _) = runs
    print(f"world seed {seed}")
    cmd = np.degrees(abc_of_matrices(TOOL_DOWN))[0]
    with RunStore(tmp / "s.sqlite") as store:
        rows = {(r["pose"], r["name"]): r for r in store.characteristics("six")}
        res = store.result("six", "iso9283")["pose"]
    unc = {(u["characteristic"], u["subject"]): u["U_deg"] for u in res["uncertainty_figures"]
           if u["characteristic"] in KEYS}
    sd = T_MAC_ANGLE_SD_DEG
    outside, checked = [], 0
    for name, ang in truth.items():
        n = res["poses"][name]["orientation"]["n"]
        assert n == len(ang) >= CYCLES
        ap_true = np.mean(_wrap_deg(ang - cmd), axis=0)
        s_true = np.std(_wrap_deg(ang - ang[0]), axis=0, ddof=1)
        for j, ax in enumerate("abc"):
            for key, true in ((f"AP{ax}_deg", ap_true[j]), (f"RP{ax}_deg", 3.0 * s_true[j])):
                row = rows[(name, key)]
                assert row["unit"] == "deg"
                assert res["poses"][name]["orientation"][key] == pytest.approx(row["value"], abs=1e-6)
                U = unc[(key, name)]
                print(f"{name} {key}: {row['value']:.5f} deg, U {U:.5f}, truth {true:.5f}")
                checked += 1
                if abs(row["value"] - true) > U:
                    outside.append((name, key, row["value"], true, U))
            # from the noise: AP differs from the truth by the mean of n readings' noise (sd / sqrt(n))
            ap = rows[(name, f"AP{ax}_deg")]["value"]
            assert abs(ap - ap_true[j]) <= stats.norm.isf(TAIL / 2) * sd / math.sqrt(n), (name, ax, ap, ap_true[j])
            # RP = 3 S of readings whose variance is the arm's and the noise's: S^2 (n-1) / var ~ chi2(n-1)
            S2 = (rows[(name, f"RP{ax}_deg")]["value"] / 3.0) ** 2
            var = sd ** 2 + s_true[j] ** 2
            lo, hi = stats.chi2.ppf([TAIL, 1 - TAIL], n - 1) / (n - 1) * var
            assert lo <= S2 <= hi, (name, ax, S2, lo, hi)
    # each figure's interval value +/- U covers the truth with 95 %: of 30 figures, 7 or more outside has
    # probability 8e-5
    assert checked == 30 and len(outside) <= 6, outside
    # the arm's drawn kinematic errors tilt the tool by more than the figures are unsure of
    assert any(abs(rows[(p, k)]["value"]) > unc[(k, p)] for p in truth for k in ("APa_deg", "APb_deg", "APc_deg"))


def test_orientation_rows_are_in_the_limits_console_and_report(runs):
    tmp, _, _ = runs
    with RunStore(tmp / "s.sqlite") as store:
        rows = store.characteristics("six")
        lines = summary(store, "six")
        report = [s.output for s in store.steps("six") if s.name == "report"][0]["report"]
    names = {r["name"] for r in rows}
    assert set(KEYS) <= names
    judged = [r for r in rows if r["name"] == "APa_deg"]
    assert len(judged) == 5 and all(r["limit"] == 5.0 and r["passed"] is not None for r in judged)
    header = lines[0]
    assert all(f"{k[:-4]} deg" in header for k in KEYS)
    html = open(report, encoding="utf-8").read()
    assert "APa_deg" in html or "APa" in html
    assert "6-DoF target on the tool" in html


def test_a_position_only_tracker_states_no_orientation(runs):
    tmp, _, _ = runs
    with RunStore(tmp / "s.sqlite") as store:
        rows = store.characteristics("three")
        res = store.result("three", "iso9283")["pose"]
        samples = store.samples("three", "tracker")
    assert not {r["name"] for r in rows} & set(KEYS + VKEYS)
    assert all(p["orientation"] is None for p in res["poses"].values())
    assert "qw" not in samples and {"t", "x", "y", "z", "status"} <= set(samples)
    # the same world measured with a 6-DoF target: the position figures are the same numbers
    six = {(r["pose"], r["name"]): r["value"] for r in store_rows(tmp, "six") if r["name"] not in KEYS + VKEYS}
    three = {(r["pose"], r["name"]): r["value"] for r in rows}
    assert six.keys() == three.keys()
    for k, v in three.items():
        assert six[k] == pytest.approx(v, rel=1e-9, abs=1e-9), k


def test_a_stored_6dof_run_reanalyses_to_the_same_orientation_figures(runs):
    from procedures.iso9283 import reanalyse

    tmp, _, _ = runs
    with RunStore(tmp / "s.sqlite") as store:
        result, rows = reanalyse(store, "six")
        stored = {(r["pose"], r["name"]): r["value"] for r in store.characteristics("six")
                  if r["name"] in KEYS + VKEYS}
    again = {(r["pose"], r["name"]): r["value"] for r in rows if r["name"] in KEYS + VKEYS}
    assert again.keys() == stored.keys() and len(again) == 30 + 9
    for k, v in stored.items():
        assert again[k] == pytest.approx(v, rel=1e-12, abs=1e-12), k
    assert result["pose"]["poses"]["P1"]["orientation"]["n"] >= CYCLES


def test_preflight_refuses_orientation_a_tracker_cannot_measure(runs):
    from dataclasses import replace

    from procedures.iso9283 import orientation_problems

    tmp, _, _ = runs
    with RunStore(tmp / "s.sqlite") as store:
        plan = IsoPlan.from_params(store.run("six").params)
    assert plan.orientation and plan.angle_sd_deg == T_MAC_ANGLE_SD_DEG and plan.limits["APa_deg"] == 5.0
    assert orientation_problems(plan, DeviceSet(urls={"tracker": "emscon://127.0.0.1:700"})) == []
    (p,) = orientation_problems(plan, DeviceSet(urls={"tracker": "geocom:///dev/ttyUSB0"}))
    assert p.startswith("devices.tracker.six_dof: this tracker (geocom) streams positions only")
    (p,) = orientation_problems(replace(plan, orientation=False), DeviceSet(urls={"tracker": "emscon://h"}))
    assert p.startswith("limits APa_deg: orientation limits need a 6-DoF tracker")


def store_rows(tmp, run_id):
    with RunStore(tmp / "s.sqlite") as store:
        return store.characteristics(run_id)


def test_six_dof_is_refused_for_a_tracker_that_cannot(tmp_path):
    with FakeStation.start(seed=1, time_scale=LOCKSTEP) as station:
        d = station.config_dict(store_path=str(tmp_path / "s.sqlite"))
    d["devices"]["tracker"] = {"url": "geocom:///dev/ttyUSB0", "six_dof": True}
    with pytest.raises(ConfigError, match="six_dof needs an emScon tracker"):
        config_from_dict(d)
    d["devices"]["tracker"] = {"url": "emscon://127.0.0.1", "angle_sd_deg": 0.02}
    with pytest.raises(ConfigError, match="angle_sd_deg applies to a 6-DoF tracker only"):
        config_from_dict(d)
    d["devices"]["tracker"] = {"url": "emscon://127.0.0.1", "six_dof": True, "angle_sd_deg": -1}
    with pytest.raises(ConfigError, match="angle_sd_deg"):
        config_from_dict(d)
    json.dumps(d)


def test_a_robots_history_and_page_follow_its_orientation_figures_run_by_run(runs):
    """The fleet history (``store.history``, what ``station store fleet history`` and the robot page read) holds
    APa..RPc of the 6-DoF run per pose, and the robot page (the names it follows, :func:`history_names`) plots
    each, its worst pose per run; the position-only run of the same robot adds no values to them."""
    from app.web.pages import robot_page
    from station.characteristics import history_names

    tmp, _, _ = runs
    names = history_names()
    assert set(KEYS + VKEYS) <= set(names)
    with RunStore(tmp / "s.sqlite") as store:
        serial = store.run("six").serial
        assert store.run("three").serial == serial
        stored = {(r["pose"], r["name"]): r["value"] for r in store.characteristics("six")
                  if r["name"] in KEYS + VKEYS}
        history = {name: store.history(serial, name) for name in names}
    assert len(stored) == 30 + 9
    for key in KEYS + VKEYS:
        rows = history[key]
        assert {r["run_id"] for r in rows} == {"six"}, key
        assert {(r["pose"], key): r["value"] for r in rows} == pytest.approx(
            {k: v for k, v in stored.items() if k[1] == key}, abs=0), key
    html = robot_page(serial, list(names), history, "token")
    for key in KEYS + VKEYS:
        worst = max((v for (p, k), v in stored.items() if k == key), key=abs)
        section = html.split(f"<h2>{key}</h2>", 1)[1].split("<h2>", 1)[0]
        assert "<figure class='history'>" in section, key
        (shown_value,) = [float(v) for v in
                          re.findall(r"<tr><td>six</td><td>\w*</td><td>([-0-9.e+]+)</td>", section)]
        assert shown_value == pytest.approx(worst, rel=1e-3), key


def test_orientation_vap_is_the_spread_of_the_directions_true_angles_within_its_uncertainty(runs):
    """vAP_a, vAP_b, vAP_c of each vAP pose (eq. (7) per angle: max - min of the approach directions' mean
    angles) against the same of the arm's true angles at the attained stops: apart by the readings' noise
    only (each direction's mean off by sd / sqrt(n_g); a max - min moves by at most twice the largest), and
    within U; stated in the rows, the vAP JSON and its uncertainty figures."""
    tmp, _, (_, vtruth) = runs
    with RunStore(tmp / "s.sqlite") as store:
        rows = {(r["pose"], r["name"]): r for r in store.characteristics("six") if r["name"] in VKEYS}
        vres = store.result("six", "iso9283")["vap"]
    unc = {(u["characteristic"], u["subject"]): u["U_deg"] for u in vres["uncertainty_figures"]
           if u["characteristic"] in VKEYS}
    assert set(rows) == {(p, k) for p in vtruth for k in VKEYS} and len(rows) == 9
    sd = T_MAC_ANGLE_SD_DEG
    outside = []
    for name, (true, ns) in vtruth.items():
        assert len(ns) == 3 and min(ns) >= VAP_CYCLES
        for j, key in enumerate(VKEYS):
            row = rows[(name, key)]
            assert row["unit"] == "deg" and row["value"] >= 0.0
            assert vres["poses"][name]["orientation"][key] == pytest.approx(row["value"], abs=1e-6)
            U = unc[(key, name)]
            print(f"{name} {key}: {row['value']:.5f} deg, U {U:.5f}, truth {true[j]:.5f}")
            # 9 figures x 3 directions: each direction's noise within its two-sided TAIL / 27 bound
            bound = 2.0 * stats.norm.isf(TAIL / (2 * 27)) * sd / math.sqrt(min(ns))
            assert abs(row["value"] - true[j]) <= bound, (name, key, row["value"], true[j], bound)
            if abs(row["value"] - true[j]) > U:
                outside.append((name, key, row["value"], true[j], U))
    # U covers at least 95 % (the truth here is the stops' own, nearer than the population's): of 9
    # figures, 5 or more outside has probability below 3e-5
    assert len(outside) <= 4, outside


def test_orientation_vap_is_max_minus_min_of_the_directions_means(rng):
    """The formula on drawn means, across the +/-180 deg seam of a tool-down orientation: deviations from one
    reference do not wrap, raw angles would."""
    from station.analysis.iso9283.characteristics import _wrap, multidirectional_orientation
    from station.errors import InsufficientDataError

    k = int(rng.integers(3, 7))
    dev = rng.normal(0.0, 0.002, size=(k, 3))
    dev[:2, 0] = rng.uniform(0.5e-3, 2e-3) * np.array([1.0, -1.0])  # a on both sides of the seam below
    v = multidirectional_orientation(dev)
    assert np.allclose(v, dev.max(axis=0) - dev.min(axis=0), rtol=0, atol=1e-15)
    ref = np.array([np.pi - 1e-4, 0.0, -np.pi + 1e-4])
    raw = _wrap(ref + dev)  # attained angles straddling the seam
    assert np.allclose(multidirectional_orientation(_wrap(raw - ref)), v, atol=1e-12)
    assert multidirectional_orientation(raw)[0] > 6.0  # what wrapping the deviations avoids
    with pytest.raises(InsufficientDataError, match="at least 2 approach directions"):
        multidirectional_orientation(dev[:1])


def test_orientation_vap_of_a_drawn_multidirectional_stream(rng):
    """The stream analysis of drawn approaches from three directions, each with its own tool tilt: vAP_a, b, c
    are max - min of the directions' true mean angles (the drawn rest angles), apart by the readings' noise
    only, with a U that covers them; a stream without angles states none."""
    from dataclasses import replace

    from station.analysis.iso9283.characteristics import analyze_iso9283
    from station.analysis.iso9283.poses import TABLE2_POSES_MM
    from station.analysis.iso9283.uncertainty import figure_uncertainties
    from station.analysis.uncertainty import Budget

    from .synth import multidirection_programme, render

    cmd_mm = np.array(TABLE2_POSES_MM)[[0]]
    abc_cmd = np.array([[math.pi - 1e-3, 0.01, -math.pi + 2e-3]])  # tool down: a and c at the +/-180 deg seam
    n_each, noise_rad = 6, 5e-5
    mp = multidirection_programme(rng, commanded=cmd_mm, pose=0, dir_offsets_mm=rng.normal(0, 0.3, (3, 3)),
                                  n_each=n_each, scatter_mm=0.02)
    d = mp.direction
    tilt = rng.normal(0, 2e-3, (3, 3))
    target = abc_cmd[0] + np.where(d[:, None] >= 0, tilt[d], 0.0) + rng.normal(0.0, 2e-4, (d.size, 3))
    sv = render(rng, replace(mp, target_abc_rad=target), start_mm=cmd_mm[0] - [0, 0, 150.0],
                start_abc_rad=abc_cmd[0], rate_hz=200.0, noise_mm=0.005, abc_noise_rad=noise_rad, speed_mm_s=500.0,
                wn_hz=15.0, zeta=0.9)
    res = analyze_iso9283(sv.t, sv.xyz, cmd_mm, names=["P1"], orientation_rad=sv.abc,
                          commanded_orientation_rad=abc_cmd)
    md = res.poses["P1"].multidirectional
    assert md.n_directions == 3 and md.vAP_rad is not None
    means = np.array([[np.mean(target[(d == k), j] - abc_cmd[0, j]) for j in range(3)] for k in range(3)])
    true = means.max(axis=0) - means.min(axis=0)
    # each direction's mean reading is off by the noise's mean over its stops (sd / sqrt(n_each)), and by the
    # servo's residue at the instants taken (well under the noise at 15 Hz after a dwell)
    bound = 2.0 * stats.norm.isf(TAIL / (2 * 9)) * noise_rad / math.sqrt(n_each)
    assert np.all(np.abs(md.vAP_rad - true) <= bound), (md.vAP_rad, true, bound)
    assert np.degrees(md.vAP_rad) == pytest.approx(
        [res.to_dict()["poses"]["P1"]["orientation"][k] for k in VKEYS], abs=1e-6)
    unc = figure_uncertainties(res, Budget(trials=4000, seed=1, angle_sd_deg=math.degrees(noise_rad)), sv.xyz)
    for j, key in enumerate(VKEYS):
        fu = unc[(key, "P1")]
        assert fu.value == pytest.approx(math.degrees(md.vAP_rad[j]))
        # U from the directions' scatter (2e-4 rad a stop): of the order of 2 x sqrt(2) x scatter / sqrt(n)
        assert 0.5 * math.degrees(2e-4) / math.sqrt(n_each) < fu.U < 8 * math.degrees(2e-4) / math.sqrt(n_each)
    bare = analyze_iso9283(sv.t, sv.xyz, cmd_mm, names=["P1"])
    assert bare.poses["P1"].multidirectional.vAP_rad is None
    assert not any(k[0] in VKEYS for k in figure_uncertainties(bare, Budget(trials=500, seed=1), sv.xyz))
