"""A UR path run killed mid-path is taken up on resume: ``kill -9`` of the station while the cobot is inside a
path cycle's path, then ``station run --resume``: the interrupted cycle is driven again from its start (its
programme's approach first), nothing acknowledged is lost, and every path states its figures from all its
cycles, within U of what the tracker reads of the arm's true motion."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np

from fakes.station import FakeStation
from procedures.iso9283_path import PathPlan, step_names
from station.config import config_from_dict
from station.store import RunStore
from tests.pace import UR_AT_RTDE_HZ, UR_RTDE_HZ
from tests.person import Terminal, run_at_terminal
from tests.station.test_iso_path_procedure import _within_U_of_the_arm
from tests.ur.test_iso_procedure import UR_ISO, _batches, _done_steps, _station

SECTION = {"path_cycles": 2, "path_speed_fracs": [0.5], "path_kinds": ["line", "rectangle_blend"],
           "path_limits": {"CR_mm": 50.0, "AT_mm": 50.0}}


def _in_path(arm, clock, fraction: float) -> bool:
    """The arm is at least ``fraction`` into a path move (a blended run or a straight move) and not near its end."""
    now = float(clock.now())
    for m in list(arm.moves)[-4:]:
        if m.kind == "linear" and m.t_start <= now <= m.t_end:
            done = (now - m.t_start) / max(m.t_end - m.t_start, 1e-9)
            return fraction <= done <= 0.9
    return False


def test_a_ur_path_run_killed_mid_path_is_taken_up_from_the_paths_start(tmp_path, test_seed):
    root = Path(__file__).resolve().parents[2]
    rng = np.random.default_rng(test_seed)
    first_path_step = 6  # check programs, mount reflector, clear the cell, connect, home, register
    n_path_steps = 2 * SECTION["path_cycles"]
    kill_in = int(rng.integers(0, n_path_steps))  # the path cycle step the kill lands in
    fraction = float(rng.uniform(0.1, 0.6))
    with FakeStation.start(seed=test_seed, time_scale=UR_AT_RTDE_HZ, robot="ur5e", rtde_hz=UR_RTDE_HZ) as cell:
        d = cell.config_dict(store_path=str(tmp_path / "k.sqlite"), report_dir=str(tmp_path / "reports"),
                             iso9283=UR_ISO)
        d["iso9283_path"] = SECTION
        config_from_dict(d)
        cfg = tmp_path / "k.json"
        cfg.write_text(json.dumps(d))
        db = tmp_path / "k.sqlite"
        term = Terminal()
        child = subprocess.Popen(_station("run", "iso9283-path", "--config", str(cfg), "--arm", "--quiet",
                                          "--run-id", "k1"), cwd=root, stdout=subprocess.DEVNULL,
                                 **term.child_streams())
        deadline = time.monotonic() + 400
        arm, clock = cell.world.arm, cell.world.clock
        while child.poll() is None and time.monotonic() < deadline and not (
                _done_steps(db) == first_path_step + kill_in and _in_path(arm, clock, fraction)):
            time.sleep(0.005)
        assert child.poll() is None, (term.close(), "the run ended before the kill")
        t_kill = float(clock.now())
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
        term.close()
        killed_in = RunStore(db).steps("k1")[-1]
        print(f"killed {fraction:.2f} into a path move of {killed_in.name!r} at t = {t_kill:.3f} s")
        assert killed_in.name.startswith("path ") and killed_in.status != "done", killed_in
        before = _batches(db)
        resumed = run_at_terminal(_station("run", "--resume", "k1", "--config", str(cfg), "--arm", "--quiet"),
                                  cwd=root, timeout=400)
        store = RunStore(db)
        assert store.run("k1").status == "done", f"{resumed.stdout} {resumed.stderr}"
        plan = PathPlan.from_params(store.run("k1").params)
        rows = {(r["pose"], r["name"]): r for r in store.characteristics("k1")}
        # the interrupted cycle was driven again from its start: once done, after the kill, beside its attempt
        attempts = [s for s in store.steps("k1") if s.name == killed_in.name]
        assert [s.status for s in attempts][-1] == "done" and len(attempts) == 2, attempts
        done = store.done_steps("k1")
        idx = next(i for i, s in done.items() if s.name == killed_in.name)
        t_redo = store.samples("k1", "tracker", steps=[idx])["t"]
        assert t_redo.size and float(np.min(t_redo)) > t_kill
        # every path found all its cycles and states all its figures, within U of the arm's true motion
        for name in step_names(plan):
            assert rows[(name, "n_cycles")]["value"] == plan.path_cycles, name
        assert all(r["value"] is not None for r in rows.values()), rows
        _within_U_of_the_arm(store, "k1", plan, rows, cell.world)
    after = _batches(db)
    lost = [k for k, blob in before.items() if after.get(k) != blob]
    assert not lost, f"acknowledged batches changed or lost after resume: {lost[:5]}"


def test_a_ur_path_paused_on_the_pendant_mid_path_fails_its_cycle_and_a_resume_drives_it_again(tmp_path, test_seed):
    """A person pauses the cobot's programme inside a path (the dashboard, as the pendant does) and plays it on
    after a while: the controller halted the path and went on from where it stood, so that cycle is no whole
    pass; its step fails naming the pause, and the resumed run drives the cycle again from its start: every path
    states its figures from all its cycles, within U of the arm's true motion."""
    import threading

    from app.assemble import RunRequest, run_procedure
    from tests.person import person_typing_yes

    rng = np.random.default_rng(test_seed)
    fraction, hold_s = float(rng.uniform(0.1, 0.6)), float(rng.uniform(0.3, 1.5))
    with FakeStation.start(seed=test_seed, time_scale=UR_AT_RTDE_HZ, robot="ur5e", rtde_hz=UR_RTDE_HZ) as cell:
        d = cell.config_dict(store_path=str(tmp_path / "p.sqlite"), report_dir=str(tmp_path / "reports"),
                             iso9283=UR_ISO)
        d["iso9283_path"] = SECTION
        cfg = config_from_dict(d)
        arm, clock, ur = cell.world.arm, cell.world.clock, cell.controller
        paused_at: list[float] = []
        stop = threading.Event()

        def person() -> None:  # pauses inside the first path it sees, plays on after hold_s of the cobot's time
            while not stop.is_set() and not _in_path(arm, clock, fraction):
                time.sleep(0.002)
            if stop.is_set():
                return
            reply, _ = ur.dashboard_reply("pause")
            assert reply == "Pausing program", reply
            paused_at.append(float(clock.now()))
            while not stop.is_set() and float(clock.now()) < paused_at[0] + hold_s:
                time.sleep(0.002)
            assert ur.dashboard_reply("play")[0] == "Starting program"

        watcher = threading.Thread(target=person, daemon=True)
        watcher.start()
        try:
            first = run_procedure(RunRequest(cfg, "iso9283-path", arm=True, operator=person_typing_yes(), quiet=True,
                                             run_id="p1", config_dir=tmp_path))
        finally:
            stop.set()
            watcher.join(10)
        store = RunStore(tmp_path / "p.sqlite")
        failed = [s for s in store.steps("p1") if s.status == "failed"]
        print(f"paused {fraction:.2f} into a path move at t = {paused_at} s for {hold_s:.2f} s: "
              f"{[s.name for s in failed]}")
        assert paused_at and first.status == "failed", (paused_at, first.status, first.error)
        assert failed[-1].name.startswith("path ") and "paused on the controller" in failed[-1].message, failed
        again = run_procedure(RunRequest(cfg, None, resume="p1", arm=True, operator=person_typing_yes(), quiet=True,
                                         config_dir=tmp_path))
        assert again.status == "done", again.error
        plan = PathPlan.from_params(store.run("p1").params)
        rows = {(r["pose"], r["name"]): r for r in store.characteristics("p1")}
        attempts = [s.status for s in store.steps("p1") if s.name == failed[-1].name]
        assert attempts == ["failed", "done"], attempts
        for name in step_names(plan):
            assert rows[(name, "n_cycles")]["value"] == plan.path_cycles, name
        assert all(r["value"] is not None for r in rows.values()), rows
        _within_U_of_the_arm(store, "p1", plan, rows, cell.world)
