"""Faults on the UR path of the ISO 9283 procedure, through the UR fake's fault injection and ``ur_rtde``.

A protective stop, an emergency stop, a dropped RTDE connection and a script
the controller refuses each stop the run at a step the runner can resume,
with the robot left safe (no program running, the arm at rest); after what a
person does on the pendant (unlock, turn the e-stop back and release the
brakes; nothing for the link and the refusal), the resumed run completes
with every sample committed before the fault still there.
"""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from fakes.station import FakeStation
from app.assemble import RunRequest, run_procedure
from station.config import config_from_dict
from station.store import RunStore
from tests.person import person_typing_yes
from tests.pace import UR_RTDE_HZ
from tests.ur.test_iso_procedure import TIME_SCALE, UR_ISO

#: the first motion of the pose cycles, after home (1) and the axis registration (2 joints x N points,
#: each joint's sweep entered by one approach move)
FIRST_CYCLE_MOTION = 1 + 2 * (UR_ISO["axis_sweep_points"] + 1) + 1


def _batches(db) -> dict:
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT stream, step_idx, attempt, batch_no, data FROM sample_batches").fetchall()
    finally:
        con.close()
    return {tuple(r[:4]): r[4] for r in rows}


def _at_rest(cell) -> bool:
    t = cell.world.clock.now()
    q = cell.world.arm.actual_q_rad(np.array([t - 0.1, t]))
    return bool(np.max(np.abs(q[1] - q[0])) < 1e-7)


def _wait_sim(cell, seconds: float) -> None:
    """Let the cell's world run ``seconds`` on (it is in lockstep: it stands still unless asked)."""
    cell.world.clock.sleep(seconds)


def _run(cfg, tmp_path, **kw):
    return run_procedure(RunRequest(cfg, "iso9283", arm=True, operator=person_typing_yes(), quiet=True,
                                    config_dir=tmp_path, **kw))


@pytest.mark.parametrize("fault", ["protective_stop_move", "emergency_stop_move", "rtde_drop_after_s",
                                   "refuse_script"])
def test_a_fault_stops_the_ur_run_safe_and_resumably(tmp_path, fault, test_seed):
    seed = test_seed
    rng = np.random.default_rng(seed)
    value = {
        "protective_stop_move": int(rng.integers(FIRST_CYCLE_MOTION, FIRST_CYCLE_MOTION + 10)),
        "emergency_stop_move": int(rng.integers(FIRST_CYCLE_MOTION, FIRST_CYCLE_MOTION + 10)),
        # the first RTDE session starts at "connect devices"; home and registration take ~25 s simulated, the
        # pose cycles ~80 s more: the drop falls in the registration's end or the pose cycles
        "rtde_drop_after_s": float(np.round(rng.uniform(20.0, 60.0), 2)),
        "refuse_script": int(rng.integers(3, 2 * UR_ISO["axis_sweep_points"] + 4)),  # home, registration, cycle 1
    }[fault]
    print(f"seed {seed}: {fault}={value}")
    with FakeStation.start(seed=seed, time_scale=TIME_SCALE, robot="ur5e", rtde_hz=UR_RTDE_HZ,
                           faults={f"controller.{fault}": str(value)}) as cell:
        d = cell.config_dict(store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
                             iso9283=UR_ISO)
        cfg = config_from_dict(d)
        code = _run(cfg, tmp_path, run_id="f1")
        store = RunStore(tmp_path / "s.sqlite")
        run = store.run("f1")
        assert code != 0 and run.status in ("failed", "aborted"), (code, run.status)
        failed = [s for s in store.steps("f1") if s.status not in ("done", "pending")]
        assert failed, "no step recorded the fault"
        message = failed[-1].message or ""
        expect = {"protective_stop_move": "protective stop", "emergency_stop_move": "emergency stop",
                  "rtde_drop_after_s": "RTDE", "refuse_script": "did not start"}[fault]
        assert expect in message, message
        # left safe: no program of the station's running, the arm at rest
        ur = cell.controller
        assert ur.ctl.runtime_state != 2 or not ur.interpreter.stoppable()
        _wait_sim(cell, 0.5)
        assert _at_rest(cell)
        before = _batches(tmp_path / "s.sqlite")
        # what the person at the pendant does
        if fault == "protective_stop_move":
            _wait_sim(cell, 5.5)  # a protective stop unlocks 5 s after it happened
            assert ur.dashboard_reply("unlock protective stop")[0] == "Protective stop releasing"
        elif fault == "emergency_stop_move":
            # resuming while the button is still pressed is refused before anything moves
            assert _run(cfg, tmp_path, resume="f1") != 0
            assert "emergency stop" in (store.steps("f1")[-1].message or "") or any(
                "emergency stop" in (s.message or "") for s in store.steps("f1"))
            ur.sim_release_emergency_stop()
            assert ur.dashboard_reply("brake release")[0] == "Brake releasing"
        code = _run(cfg, tmp_path, resume="f1")
        assert code.exit_code == 0, [s.message for s in store.steps("f1") if s.message]
    after = _batches(tmp_path / "s.sqlite")
    assert not [k for k, blob in before.items() if after.get(k) != blob]
    store = RunStore(tmp_path / "s.sqlite")
    assert store.run("f1").status == "done"
    chars = {(c["pose"], c["name"]): c["value"] for c in store.characteristics("f1")}
    for p in ("P1", "P2", "P3", "P4", "P5"):
        assert chars[(p, "n_cycles")] == UR_ISO["cycles"]
