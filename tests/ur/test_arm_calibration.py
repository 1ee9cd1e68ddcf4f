"""Arm calibration on a UR: the procedure on the UR fake through ``ur_rtde``.

The cell: the UR5e world (drawn geometric and non-geometric errors), the
emScon tracker fake and the UR fake. Checked: the joint angles the
identification uses are the arm's own RTDE readings while the tracker
measured (the simulated encoders, not the commanded angles); the identified
plain-DH model, evaluated by the test's own forward kinematics at those
angles, reproduces the reported test errors; it is written as UR
calibration deltas, and a second calibration of the same arm read back from
that file starts where the first ended.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from fakes.cells import demo_config
from procedures.arm_calibration import RESULT_KEY, ArmCalPlan
from app.assemble import RunRequest, run_procedure
from station.config import StationConfig
from station.models.arm_model_file import read_ur_calibration
from station.store import RunStore
from tests.calibration.test_arm_calibration import independent_fk
from tests.pace import UR_AT_RTDE_HZ as TIME_SCALE
from tests.pace import UR_RTDE_HZ
from tests.calibration.judge import assert_calibrated


def _cfg(tmp_path, **arm):
    d = demo_config(tmp_path, cycles=3, vap_cycles=3, rate_hz=100, robot="ur5e")
    # a UR's joints turn 180 deg/s: at the default 20 % a wrist turn can carry the TCP past the 1 m/s cap
    d["arm_calibration"] = {"train_poses": 31, "test_poses": 9, "speed_percent": 10.0, **arm}
    return StationConfig.model_validate(d)


def _run(cfg, tmp_path, run_id, cell_seed, sel_seed):
    code = run_procedure(RunRequest(cfg, "arm-calibration", run_id=run_id, yes=True, quiet=True, time_scale=TIME_SCALE,
                                    seed=cell_seed, config_dir=tmp_path, plan_overrides={"selection_seed": sel_seed},
                                    fake_options={"rtde_hz": UR_RTDE_HZ}))
    assert code.exit_code == 0
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        return (store.result(run_id, RESULT_KEY), ArmCalPlan.from_params(store.run(run_id).params),
                store.samples(run_id, "points"))


def test_ur_calibration_uses_rtde_joints_and_its_deltas_start_the_next(tmp_path, test_seed):
    seed = test_seed
    print(f"seed {seed}")
    rng = np.random.default_rng(seed)
    cell_seed, sel_seed = int(rng.integers(2**31)), int(rng.integers(2**31))
    doc, plan, s = _run(_cfg(tmp_path), tmp_path, "c1", cell_seed, sel_seed)
    assert doc["joints"] == "measured"
    q_meas = np.full((len(plan.q_deg), 6), np.nan)
    q_meas[s["pose"].astype(int)] = np.column_stack([s[f"q{j}"] for j in range(1, 7)])
    assert np.all(np.isfinite(q_meas))
    # the arm's own readings, not the commanded angles: they differ by the arm's stop scatter and servo error
    dq = np.abs(q_meas - np.array(plan.q_deg))
    assert dq.max() > 1e-6 and dq.max() < 0.05
    # plain DH (no beta) so the controller can take it; errors fall from the arm's mm to well below
    model = json.loads(open(doc["model_file"]).read())
    assert all(abs(j["beta_deg"]) < 1e-9 for j in model["joints"])
    # (a UR5e's drawn errors are a few tenths of a mm at the tool, the tracker's noise a few um)
    assert doc["test"]["mean_abs_before_mm"] > 0.05
    assert_calibrated(doc, 0.3)
    # the exported model at the measured joints, by an independent FK, gives the reported test errors
    split = plan.split()
    p = independent_fk(model, q_meas[split.test])
    B = model["base"]
    p_tracker = p @ np.array(B["rotation_matrix"]).T + np.array(B["translation_mm"])
    meas = np.full((len(plan.q_deg), 3), np.nan)
    meas[s["pose"].astype(int)] = np.column_stack([s["x"], s["y"], s["z"]])
    err = np.linalg.norm(meas[split.test] - p_tracker, axis=1)
    assert err.mean() == pytest.approx(doc["test"]["mean_abs_after_mm"], abs=1e-6)
    # the UR deltas read back give the identified model (the controller's form: nominal + deltas)
    back = read_ur_calibration(doc["ur_calibration_file"], plan.robot.dh_nominal)
    ident = np.array([[j["a_mm"], np.radians(j["alpha_deg"]), j["d_mm"], np.radians(j["theta_deg"])]
                      for j in model["joints"]])
    assert np.allclose(back[:6, :4], ident, atol=1e-9)
    # the next calibration of the same arm starts from them: its "before" is the first run's "after" level
    doc2, plan2, _ = _run(_cfg(tmp_path, ur_calibration=doc["ur_calibration_file"]), tmp_path, "c2", cell_seed,
                          sel_seed + 1)
    assert np.allclose(np.array(plan2.start_dh)[:6, :4], ident, atol=1e-9)
    assert doc2["test"]["mean_abs_before_mm"] < 0.5 * doc["test"]["mean_abs_before_mm"]


def test_killed_ur_calibration_resumes_with_every_measured_pose(tmp_path, test_seed):
    """``kill -9`` of the station during a UR calibration (the cobot may be mid-program), then resume."""
    import subprocess
    import time
    from pathlib import Path

    from fakes.station import FakeStation
    from station.config import config_from_dict
    from tests.person import Terminal, run_at_terminal
    from tests.ur.test_iso_procedure import _batches, _done_steps, _station

    root = Path(__file__).resolve().parents[2]
    seed = test_seed
    rng = np.random.default_rng(seed)
    with FakeStation.start(seed=seed, time_scale=TIME_SCALE, robot="ur5e", rtde_hz=UR_RTDE_HZ) as cell:
        d = cell.config_dict(store_path=str(tmp_path / "k.sqlite"), report_dir=str(tmp_path / "reports"))
        d["arm_calibration"] = {"train_poses": 23, "test_poses": 8, "speed_percent": 10.0, "poses_per_step": 4,
                                "candidates": 600}
        config_from_dict(d)
        cfg = tmp_path / "k.json"
        cfg.write_text(json.dumps(d))
        db = tmp_path / "k.sqlite"
        # steps: check programs, prompts, connect, 8 measuring batches, identify, diagnose, report
        kill_after = int(rng.integers(5, 11))
        print(f"seed {seed}, kill after {kill_after} steps")
        term = Terminal()  # the person at the terminal answers the armed run's prompts
        child = subprocess.Popen(_station("run", "arm-calibration", "--config", str(cfg), "--arm", "--quiet",
                                          "--run-id", "k1"), cwd=root, stdout=subprocess.DEVNULL,
                                 **term.child_streams())
        deadline = time.monotonic() + 240
        while _done_steps(db) < kill_after and child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(float(rng.uniform(0, 0.5)))
        os.kill(child.pid, 9)
        child.wait(timeout=10)
        err = term.close()
        before = _batches(db)
        assert RunStore(db).run("k1").status in ("running", "done"), err
        resumed = run_at_terminal(_station("run", "--resume", "k1", "--config", str(cfg), "--arm", "--quiet"),
                                  cwd=root, timeout=300)
        store = RunStore(db)
        assert store.run("k1").status == "done", f"{resumed.stdout} {resumed.stderr}"
    after = _batches(db)
    assert not [k for k, blob in before.items() if after.get(k) != blob]
    doc = store.result("k1", RESULT_KEY)
    plan = ArmCalPlan.from_params(store.run("k1").params)
    s = store.samples("k1", "points")
    assert set(s["pose"].astype(int)) == set(range(len(plan.q_deg)))  # every pose measured, none lost
    assert np.all(np.isfinite([s[f"q{j}"] for j in range(1, 7)]))
    assert doc["joints"] == "measured"
    assert_calibrated(doc, 0.3)
