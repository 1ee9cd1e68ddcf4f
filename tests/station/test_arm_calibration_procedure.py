"""The tracker-based arm calibration procedure on the fake cell (emScon tracker, FTP/Modbus controller).

The cell's arm is the simulated one with its drawn geometric and
non-geometric errors; the seeds of the cell and of the pose selection are
drawn each run. Checked: the run measures every planned pose through the
real drivers, identifies, and the exported model, evaluated by the test's
own forward kinematics, reproduces the reported test errors; an aborted run
resumes at its batch and keeps every measured pose; a plan the gate refuses
never reaches the robot.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from fakes.cells import demo_config
from procedures.arm_calibration import ArmCalPlan, RESULT_KEY, history
from app.assemble import RunRequest, run_procedure
from station.config import StationConfig
from station.errors import PreflightError
from station.models import kinematics as kin
from station.runner import RunControl
from station.store import RunStore
from tests.calibration.test_arm_calibration import independent_fk
from tests.station.abort_at import AbortAtStep
from tests.pace import LOCKSTEP
from tests.calibration.judge import assert_calibrated

TIME_SCALE = LOCKSTEP


def _cfg(tmp_path, **arm):
    d = demo_config(tmp_path, cycles=3, vap_cycles=3, rate_hz=100)
    d["arm_calibration"] = {"train_poses": 31, "test_poses": 9, **arm}
    return StationConfig.model_validate(d)


def _seeds(rng):
    return int(rng.integers(0, 2**31)), int(rng.integers(0, 2**31))


def test_calibration_run_identifies_and_its_model_reproduces_the_test_errors(rng, tmp_path):
    cell_seed, sel_seed = _seeds(rng)
    cfg = _cfg(tmp_path, test_error_limit_mm=0.1)
    code = run_procedure(RunRequest(cfg, "arm-calibration", run_id="c1", yes=True, quiet=True, time_scale=TIME_SCALE,
                                    seed=cell_seed, config_dir=tmp_path, plan_overrides={"selection_seed": sel_seed}))
    assert code.status == "done", code.error
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        doc = store.result("c1", RESULT_KEY)
        plan = ArmCalPlan.from_params(store.run("c1").params)
        hist = history(store, "DEMO-0001")
    assert [h["run_id"] for h in hist] == ["c1"]
    # the diagnosis step: the fake arm has geometric errors of mm, so the simulation is wrong by far more
    # than the noise, and the selected extensions bring the held-out rms down towards the noise floor
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        diag = store.result("c1", "diagnosis")
    assert "geometric" in [st["effect"] for st in diag["steps"]]
    assert diag["final_heldout_rms"] < 0.3 * diag["simulation_heldout_rms"]
    # the fake arm's geometric errors are mm; what is left is the tracker's noise and the non-geometric effects
    assert doc["test"]["mean_abs_before_mm"] > 0.3
    assert_calibrated(doc, 0.2)
    assert doc["train"]["n"] == 31 and doc["test"]["n"] == 9
    # the calibration's characteristics, the test poses' mean error after it judged against its limit
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        rows = {(r["pose"], r["name"]): r for r in store.characteristics("c1")}
    after = rows[("test", "mean_error_after_mm")]
    assert after["value"] == doc["test"]["mean_abs_after_mm"] and after["limit"] == 0.1 and after["unit"] == "mm"
    assert after["passed"] is (after["value"] <= 0.1)
    assert rows[("train", "mean_error_before_mm")]["value"] == doc["train"]["mean_abs_before_mm"]
    assert str(code.verdict) == ("PASS" if after["passed"] else "FAIL")
    # the exported model (with its tracker <- base transform) by an independent FK
    model = json.loads(open(doc["model_file"]).read())
    split = plan.split()
    q_deg = np.array(plan.q_deg)
    p = independent_fk(model, q_deg[split.test])
    B = model["base"]
    p_tracker = p @ np.array(B["rotation_matrix"]).T + np.array(B["translation_mm"])
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        s = store.samples("c1", "points")
    meas = np.full((len(plan.q_deg), 3), np.nan)
    meas[s["pose"].astype(int)] = np.column_stack([s["x"], s["y"], s["z"]])
    err = np.linalg.norm(meas[split.test] - p_tracker, axis=1)
    assert err.mean() == pytest.approx(doc["test"]["mean_abs_after_mm"], abs=1e-6)
    assert (tmp_path / "reports" / "c1.html").exists()
    # the report says how the poses were chosen in words, not as the plan's raw JSON
    text = (tmp_path / "reports" / "c1.html").read_text()
    row = re.search(r"<th class='l'>pose selection</th><td class='l'>([^<]*)</td>", text).group(1)
    assert row.startswith(f"d-optimal from {plan.selection['candidates']} admissible candidate poses")
    assert f"seed {sel_seed}" in row and "{" not in row and "&quot;" not in row
    # the run's export is an arm CSV the command that analyses such runs reads (pose, step_idx not measurements)
    from app.cli import main
    from station.readers.arm_csv import read_arm_csv

    with RunStore(cfg.station.store_file(tmp_path)) as store:
        store.export("c1", tmp_path / "export")
    f = tmp_path / "export" / "samples_points.csv"
    assert open(f).readline().strip().split(",")[:2] == ["pose", "q1"]
    data = read_arm_csv(f)
    assert np.array_equal(data.q_deg, q_deg[s["pose"].astype(int)]) and np.array_equal(
        data.xyz_mm, np.column_stack([s["x"], s["y"], s["z"]]))
    assert main(["calibrate", "arm", "--robot", plan.robot.name, "--data", str(f), "--json", str(tmp_path / "a.json")]) == 0


def test_aborted_calibration_resumes_at_its_batch_and_keeps_every_measured_pose(rng, tmp_path):
    cell_seed, sel_seed = _seeds(rng)
    cfg = _cfg(tmp_path, poses_per_step=5)
    db = cfg.station.store_file(tmp_path)
    control = RunControl()
    stop_after = int(rng.integers(1, 5))  # measured batches before the abort (it comes as the next one starts)

    code = run_procedure(RunRequest(cfg, "arm-calibration", run_id="c2", yes=True, quiet=True, time_scale=TIME_SCALE,
                                    seed=cell_seed, config_dir=tmp_path, plan_overrides={"selection_seed": sel_seed},
                                    control=control, progress=AbortAtStep(control, f"measure {stop_after + 1}")))
    assert code.status == "aborted" and code.exit_code == 5
    with RunStore(db) as store:
        before = store.samples("c2", "points")
        first_q = store.run("c2").params["q_deg"]
    n_before = before["pose"].size
    assert n_before >= 5 * stop_after
    code = run_procedure(RunRequest(cfg, None, resume="c2", yes=True, quiet=True, time_scale=TIME_SCALE, config_dir=tmp_path))
    assert code.status == "done", code.error
    with RunStore(db) as store:
        after = store.samples("c2", "points")
        assert store.run("c2").params["q_deg"] == first_q  # the same poses
        doc = store.result("c2", RESULT_KEY)
        redone = [s for s in store.steps("c2") if s.name == f"measure {stop_after + 1}" and s.status == "done"]
    # the resumed session's cell is a new one, its arm at home: taken forward along the plan's own path to
    # the pose before the batch (each earlier pose's pre-position and pose, unmeasured)
    assert redone[-1].output["approach"] == [f"C{i}{s}" for i in range(1, 5 * stop_after + 1) for s in ("_pre", "")]
    # every point measured before the abort is still there, unchanged
    for k in range(n_before):
        i = np.flatnonzero(after["pose"] == before["pose"][k])
        assert any(np.allclose([after[c][j] for c in "xyz"], [before[c][k] for c in "xyz"]) for j in i)
    assert set(after["pose"].astype(int)) == set(range(40))
    assert_calibrated(doc, 0.2)


def test_a_run_stopped_inside_a_batch_goes_back_over_its_path_before_it_measures_the_batch_again(rng, tmp_path):
    """Abort inside a batch as the arm moves to one of its later poses; the same cell (the arm stays where the
    stop left it) resumes. The resumed batch's first program was gated from the pose before the batch only, so
    the arm is first taken back over the batch's own moves to there; then the batch is measured again and every
    point measured before the abort is kept."""
    from fakes.station import FakeStation
    from procedures.devices import DeviceSet
    from station.config import config_from_dict

    cell_seed, sel_seed = _seeds(rng)
    stop_after = int(rng.integers(1, 5))  # whole batches measured before the abort
    into = int(rng.integers(1, 5))  # poses of the next batch measured before it (the abort comes on the next)
    first = 5 * stop_after
    print(f"abort in batch {stop_after + 1} after {into} of its poses")
    control = RunControl()
    with FakeStation.start(seed=cell_seed, time_scale=TIME_SCALE) as cell:
        d = cell.config_dict(store_path=str(tmp_path / "b.sqlite"), report_dir=str(tmp_path / "reports"))
        d["arm_calibration"] = {"train_poses": 23, "test_poses": 7, "poses_per_step": 5}
        cfg = config_from_dict(d)
        devices = DeviceSet(urls={"tracker": cell.tracker_url, "controller": cell.controller_url},
                            time_scale=TIME_SCALE)
        code = run_procedure(RunRequest(cfg, "arm-calibration", run_id="b1", yes=True, quiet=True, config_dir=tmp_path,
                                        devices=devices, plan_overrides={"selection_seed": sel_seed}, control=control,
                                        progress=AbortAtStep(control, f"measure {stop_after + 1}", f"pose C{first + into + 1}")))
        assert code.status == "aborted"
        db = cfg.station.store_file(tmp_path)
        with RunStore(db) as store:
            before = store.samples("b1", "points", finished_only=False)
        assert before["pose"].size == first + into
        code = run_procedure(RunRequest(cfg, None, resume="b1", yes=True, quiet=True, config_dir=tmp_path, devices=devices))
        assert code.status == "done", code.error
    with RunStore(db) as store:
        after = store.samples("b1", "points", finished_only=False)
        redone = [s for s in store.steps("b1") if s.name == f"measure {stop_after + 1}" and s.status == "done"]
    # back from where the stop left it (on the last program's moves: C(m) -> C(m+1)_pre -> C(m+1), with m the
    # last pose measured) over the batch's own moves to the pose before the batch (C(first); the first is
    # C(first + 1)), each waypoint once
    m = first + into
    full = [f"C{m + 1}", f"C{m + 1}_pre"] + [f"C{i}{s}" for i in range(m, first, -1) for s in ("", "_pre")] + [f"C{first}"]
    assert redone[-1].output["approach"] in (full[1:], full[2:], full[3:]), redone[-1].output
    for k in range(before["pose"].size):  # every point measured before the abort is still there, unchanged
        i = np.flatnonzero(after["pose"] == before["pose"][k])
        assert any(np.allclose([after[c][j] for c in "xyz"], [before[c][k] for c in "xyz"]) for j in i)
    assert set(after["pose"].astype(int)) == set(range(30))


def test_a_pose_outside_the_workspace_is_refused_before_anything_moves(rng, tmp_path):
    cfg = _cfg(tmp_path)
    # a plan edited to reach below the box: preflight names the pose, nothing connects
    from procedures.arm_calibration import plan_from_config

    plan = plan_from_config(cfg, "r1", selection_seed=int(rng.integers(2**31)))
    q = [list(v) for v in plan.q_deg]
    bad = int(rng.integers(1, len(q)))
    lo, hi = np.array(plan.workspace_min_mm), np.array(plan.workspace_max_mm)
    for dq in (40.0, -40.0, 60.0, -60.0, 80.0, -80.0):  # the shoulder turned until the tool leaves the box
        trial = np.array(q[bad])
        trial[1] += dq
        p = kin.tool_position(plan.robot.dh_nominal, np.radians(trial))
        if np.any(p < lo) or np.any(p > hi):
            q[bad] = trial.tolist()
            break
    else:
        pytest.fail("no shoulder turn takes this pose out of the box")
    with pytest.raises(PreflightError, match=f"C{bad + 1}"):
        run_procedure(RunRequest(cfg, "arm-calibration", run_id="c3", yes=True, quiet=True, time_scale=TIME_SCALE,
                                 config_dir=tmp_path, plan_overrides={"q_deg": q, "roles": list(plan.roles),
                                                                      "selection_seed": 1}))
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        assert "c3" not in [r.run_id for r in store.runs()]  # not even started
