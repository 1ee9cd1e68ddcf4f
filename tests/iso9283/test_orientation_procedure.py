"""Orientation in the ISO 9283 procedure: a T-Mac on the tool over emScon (6D continuous time) against the
fake station. Orientation AP and RP (a, b, c) per pose within U of the simulated arm's truth (its drawn
kinematic and stopping errors, seen through the run's own registered frame), in the stored rows, the JSON,
the console and the report; a position-only tracker's run is as before (no orientation rows)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from app.assemble import RunRequest, run_procedure
from fakes.sim.six_dof import T_MAC_ANGLE_SD_DEG
from fakes.station import FakeStation
from procedures.devices import DeviceSet
from procedures.iso9283 import registration_of, summary
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
KEYS = [f"{kind}{ax}_deg" for ax in "abc" for kind in ("AP", "RP")]


def _run(tmp, seed, *, six_dof: bool, run_id: str):
    with FakeStation.start(seed=seed, time_scale=LOCKSTEP) as station:
        limits = {"rp_limit_mm": 0.5, **({"apa_limit_deg": 5.0} if six_dof else {})}
        d = station.config_dict(store_path=str(tmp / "s.sqlite"), report_dir=str(tmp / "reports"),
                                iso9283={"cycles": CYCLES, "vap_cycles": 2}, limits=limits)
        if six_dof:
            d["devices"]["tracker"]["six_dof"] = True
        d["uncertainty"] = {"mc_trials": 4000}
        devices = DeviceSet(urls={"tracker": station.tracker_url, "controller": station.controller_url},
                            time_scale=station.world.clock.time_scale)
        out = run_procedure(RunRequest(config_from_dict(d), "iso9283", devices=devices,
                                       operator=ScriptedOperator(True), quiet=True, run_id=run_id, config_dir=tmp))
        assert out.status == "done", out.error
        with RunStore(tmp / "s.sqlite") as store:
            truth = _true_orientation(store, run_id, station.world) if six_dof else None
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
    tmp, seed, truth = runs
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
    assert not {r["name"] for r in rows} & set(KEYS)
    assert all(p["orientation"] is None for p in res["poses"].values())
    assert "qw" not in samples and {"t", "x", "y", "z", "status"} <= set(samples)
    # the same world measured with a 6-DoF target: the position figures are the same numbers
    six = {(r["pose"], r["name"]): r["value"] for r in store_rows(tmp, "six") if r["name"] not in KEYS}
    three = {(r["pose"], r["name"]): r["value"] for r in rows}
    assert six.keys() == three.keys()
    for k, v in three.items():
        assert six[k] == pytest.approx(v, rel=1e-9, abs=1e-9), k


def test_a_stored_6dof_run_reanalyses_to_the_same_orientation_figures(runs):
    from procedures.iso9283 import reanalyse

    tmp, _, _ = runs
    with RunStore(tmp / "s.sqlite") as store:
        result, rows = reanalyse(store, "six")
        stored = {(r["pose"], r["name"]): r["value"] for r in store.characteristics("six") if r["name"] in KEYS}
    again = {(r["pose"], r["name"]): r["value"] for r in rows if r["name"] in KEYS}
    assert again.keys() == stored.keys() and len(again) == 30
    for k, v in stored.items():
        assert again[k] == pytest.approx(v, rel=1e-12, abs=1e-12), k
    assert result["pose"]["poses"]["P1"]["orientation"]["n"] >= CYCLES


def test_preflight_refuses_orientation_a_tracker_cannot_measure(runs):
    from dataclasses import replace

    from procedures.iso9283 import IsoPlan, orientation_problems

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
