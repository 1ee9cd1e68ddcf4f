import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from station.errors import StationError
from station.runner import Procedure, RunControl, Runner, ScriptedOperator, Step
from station.store import RunStore
from tests.station import toy_procedure as toy

ROOT = Path(__file__).resolve().parents[2]


def run_uninterrupted(tmp_path):
    store = RunStore(tmp_path / "ref.sqlite")
    out = Runner(store, toy.make_procedure()).start("ref", params={})
    assert out.status == "done"
    return store


def test_uninterrupted_run_journals_every_step(tmp_path):
    store = run_uninterrupted(tmp_path)
    steps = store.steps("ref")
    assert [s.status for s in steps] == ["done"] * (toy.N_MEASURE + 2)
    assert store.sample_count("ref", "tracker") == toy.N_MEASURE * toy.BATCHES * toy.PER_BATCH
    assert store.run("ref").status == "done"


def _kill_child_after(tmp_path, n_acks, run_id):
    db = tmp_path / "killed.sqlite"
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.station.toy_procedure", str(db), run_id],
        cwd=ROOT, stdout=subprocess.PIPE, text=True,
    )
    acked = []
    try:
        while len(acked) < n_acks:
            line = proc.stdout.readline()
            if not line:
                break
            if line.startswith("ack"):
                acked.append(tuple(int(v) for v in line.split()[1:]))
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        proc.stdout.close()
    return db, acked


@pytest.mark.parametrize("trial", range(3))
def test_kill_9_at_random_point_then_resume_loses_nothing(rng, tmp_path, trial):
    n_acks = int(rng.integers(1, toy.N_MEASURE * toy.BATCHES - 1))
    db, acked = _kill_child_after(tmp_path, n_acks, "r1")
    assert len(acked) >= n_acks
    store = RunStore(db)
    # every acknowledged batch is there, with the exact values
    everything = store.samples("r1", "tracker", finished_only=False)
    for step_idx, batch in acked:
        expect = toy.values(step_idx - 1, batch)
        sel = everything["step_idx"] == step_idx
        got_t = everything["t"][sel]
        assert np.isin(expect["t"], got_t).all(), f"acknowledged batch {step_idx}/{batch} lost"
    assert store.run("r1").status == "running"  # died without journaling
    out = Runner(store, toy.make_procedure()).resume("r1")
    assert out.status == "done"
    ref = run_uninterrupted(tmp_path)
    a, b = store.samples("r1", "tracker"), ref.samples("ref", "tracker")
    for col in ("t", "x", "y", "z", "step_idx"):
        np.testing.assert_array_equal(a[col], b[col])
    ref_compute = ref.done_steps("ref")[toy.N_MEASURE + 1].output
    assert store.done_steps("r1")[toy.N_MEASURE + 1].output == ref_compute
    # the connect step ran again in the new session before the remaining steps
    connects = [s for s in store.steps("r1") if s.name == "connect"]
    assert len(connects) == 2 and all(s.status == "done" for s in connects)


def test_abort_then_resume(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    control = RunControl()
    proc = toy.make_procedure(announce=lambda m: control.abort() if m == "ack 3 2" else None)
    out = Runner(store, proc, control=control).start("a", params={})
    assert out.status == "aborted"
    assert store.run("a").status == "aborted"
    aborted = [s for s in store.steps("a") if s.status == "aborted"]
    assert [s.name for s in aborted] == ["measure 2"]
    out = Runner(store, toy.make_procedure()).resume("a")
    assert out.status == "done"
    assert store.sample_count("a", "tracker", finished_only=True) == toy.N_MEASURE * toy.BATCHES * toy.PER_BATCH
    # the aborted attempt's samples are kept, marked by attempt
    assert store.sample_count("a", "tracker") > store.sample_count("a", "tracker", finished_only=True)


def test_failure_calls_safe_state_and_is_resumable(tmp_path):
    calls = []
    flaky = {"fail": True}

    def boom(ctx):
        if flaky["fail"]:
            raise StationError("controller fault: protective stop")
        return {"ok": 1}

    proc = Procedure("p", [Step("a", lambda c: {"x": 1}), Step("b", boom)], safe_state=lambda s: calls.append("safe"))
    store = RunStore(tmp_path / "s.sqlite")
    out = Runner(store, proc).start("f", params={})
    assert out.status == "failed" and "protective stop" in out.error
    assert calls == ["safe"]
    flaky["fail"] = False
    out = Runner(store, proc).resume("f")
    assert out.status == "done" and out.outputs["b"]["ok"] == 1
    with pytest.raises(StationError, match="already done"):
        Runner(store, proc).resume("f")


def test_prompts_answered_by_script_and_refusal_stops(tmp_path):
    def mount(ctx):
        if not ctx.confirm("Mount the reflector on the tool flange"):
            raise StationError("operator declined: reflector not mounted")
        return {}

    proc = Procedure("p", [Step("mount reflector", mount)])
    op = ScriptedOperator(True)
    assert Runner(RunStore(tmp_path / "a.sqlite"), proc, operator=op).start("y", params={}).status == "done"
    assert op.asked == ["Mount the reflector on the tool flange"]
    out = Runner(RunStore(tmp_path / "b.sqlite"), proc, operator=ScriptedOperator(False)).start("n", params={})
    assert out.status == "failed" and "declined" in out.error


def test_duplicate_step_names_refused():
    with pytest.raises(StationError, match="unique"):
        Procedure("p", [Step("a", lambda c: None), Step("a", lambda c: None)])


def test_a_paused_run_is_held_only_while_its_checkpoint_waits():
    import threading

    control = RunControl()
    control.checkpoint()  # not paused: passes, never held
    assert not control.held
    control.pause()
    assert control.paused and not control.held  # asked, but the procedure has not reached a checkpoint
    passed = threading.Event()

    def procedure():
        control.checkpoint()
        passed.set()

    t = threading.Thread(target=procedure)
    t.start()
    for _ in range(500):  # the thread reaches its checkpoint
        if control.held:
            break
        passed.wait(0.01)
    assert control.held and not passed.is_set()
    control.resume()
    t.join(5)
    assert passed.is_set() and not control.held and not control.paused
