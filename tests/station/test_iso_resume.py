"""Kill the station process at random points of an ISO 9283 run, resume, compare.

The fake cell runs in this test process (it is the "hardware": it survives
the station process, as a real robot and tracker would). The station runs in
a child process (`station run iso9283 --arm --yes`) and is killed with
SIGKILL once a randomly drawn number of steps is journaled done; a second
child resumes the run with `station run --resume`.

Checked: every sample batch committed before the kill is still there,
byte for byte; the resumed run completes every step exactly once (plus the
per-session steps again); its analysis has every cycle of every pose and no
missing stop; and its results agree with an uninterrupted run on an
identical fake cell within what the robot's own repeatability allows (the
stop-to-stop scatter is random, so two runs are two samples of it).
"""

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fakes.station import FakeStation
from procedures.iso9283 import registration_of
from tests.person import Terminal, run_at_terminal
from station.config import config_from_dict
from station.store import RunStore
from tests.pace import LOCKSTEP

ROOT = Path(__file__).resolve().parents[2]
CYCLES, VAP = 3, 2


def _config(cell, tmp_path, name):
    import json

    cfg = cell.config_dict(store_path=str(tmp_path / f"{name}.sqlite"), report_dir=str(tmp_path / "reports"),
                           iso9283={"cycles": CYCLES, "vap_cycles": VAP})
    config_from_dict(cfg)
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(cfg))
    return path


def _station(*args):
    return [sys.executable, "-m", "app.cli", *args]


def _done_steps(db: Path) -> int:
    if not db.exists():
        return 0
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)
        try:
            return con.execute("SELECT COUNT(*) FROM steps WHERE status='done'").fetchone()[0]
        finally:
            con.close()
    except sqlite3.OperationalError:
        return 0


def _batches(db: Path) -> dict:
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT stream, step_idx, attempt, batch_no, data FROM sample_batches").fetchall()
    finally:
        con.close()
    return {tuple(r[:4]): r[4] for r in rows}


def _pose_table(store, run_id):
    return {(c["pose"], c["name"]): c["value"] for c in store.characteristics(run_id)}


@pytest.mark.parametrize("trial", range(2))
def test_killed_run_resumes_with_nothing_lost(rng, tmp_path, trial):
    seed = int(rng.integers(0, 2**31))
    total_steps = 6 + CYCLES + VAP + 3
    kill_after = int(rng.integers(5, total_steps - 1))  # somewhere from registration to analysis
    with FakeStation.start(seed=seed, time_scale=LOCKSTEP) as cell:
        cfg = _config(cell, tmp_path, "killed")
        db = tmp_path / "killed.sqlite"
        term = Terminal()  # the person at the terminal answers the armed run's prompts
        child = subprocess.Popen(_station("run", "iso9283", "--config", str(cfg), "--arm", "--quiet",
                                          "--run-id", "k1"), cwd=ROOT, stdout=subprocess.DEVNULL,
                                 **term.child_streams())
        deadline = time.monotonic() + 120
        while _done_steps(db) < kill_after and child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        # let it get into the next step's sampling for a random moment, then kill it
        time.sleep(float(rng.uniform(0, 0.3)))
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
        err = term.close()
        before = _batches(db)
        assert RunStore(db).run("k1").status in ("running", "done"), err
        resumed = run_at_terminal(_station("run", "--resume", "k1", "--config", str(cfg), "--arm", "--quiet"),
                                  cwd=ROOT, timeout=180)
        # the verdict's code (2: done already; 4: 3 cycles are not ISO 9283 conformant, which --arm requires)
        assert resumed.returncode in (0, 1, 2, 3, 4), resumed.stderr
        store = RunStore(db)
        if store.run("k1").status != "done":
            pytest.fail(f"resumed run not done: {resumed.stdout} {resumed.stderr}")
        after = _batches(db)
        lost = [k for k, blob in before.items() if after.get(k) != blob]
        assert not lost, f"acknowledged batches changed or lost after resume: {lost[:5]}"
        steps = store.steps("k1")
        done = {}
        for s in steps:
            if s.status == "done":
                done.setdefault(s.name, 0)
                done[s.name] += 1
        # each non-session step exactly once; the session steps again after the resume
        for name, n in done.items():
            if name in ("check programs", "clear the cell", "connect devices", "home"):
                assert n >= 1
            else:
                assert n == 1, (name, n)
        assert len(done) == total_steps
        res = _pose_table(store, "k1")
        for p in ("P1", "P2", "P3", "P4", "P5"):
            assert res[(p, "n_cycles")] == CYCLES
        assert store.result("k1", "iso9283")["pose"]["extraction"]["missing"] == []

    # an uninterrupted run on an identical cell
    with FakeStation.start(seed=seed, time_scale=LOCKSTEP) as cell:
        cfg = _config(cell, tmp_path, "ref")
        ref = run_at_terminal(_station("run", "iso9283", "--config", str(cfg), "--arm", "--quiet",
                                       "--run-id", "r1"), cwd=ROOT, timeout=180)
        # done: the verdict's exit code (5 would be unfinished); --arm requires ISO 9283 conformance, which 3
        # cycles never meet: never a PASS
        assert ref.returncode in (1, 3, 4), ref.stderr
        assert "not conformant (required)" in ref.stdout, ref.stdout
    ref_store = RunStore(tmp_path / "ref.sqlite")
    ref_res = _pose_table(ref_store, "r1")
    # each run registered the tracker to the base on its own: the two frames differ by the registration's
    # noise, which moves a commanded point by `shift` as seen from the other frame
    reg_k = registration_of({s.name: s.output for s in store.steps("k1") if s.status == "done"})
    reg_r = registration_of({s.name: s.output for s in ref_store.steps("r1") if s.status == "done"})
    commanded = store.result("k1", "iso9283")["pose"]["poses"]
    for p in ("P1", "P2", "P3", "P4", "P5"):
        c = np.asarray(commanded[p]["commanded_mm"])
        shift = np.linalg.norm(reg_r.to_base(reg_k.to_tracker(c)) - c)
        # AP is the mean of CYCLES stops: two runs differ by the stop scatter, whose std RP/3 bounds
        s = max(res[(p, "RP_mm")], ref_res[(p, "RP_mm")]) / 3
        tol = 5 * s * np.sqrt(2 / CYCLES) + 3 * shift + 0.02
        assert abs(res[(p, "AP_mm")] - ref_res[(p, "AP_mm")]) < tol, (p, res[(p, "AP_mm")], ref_res[(p, "AP_mm")], shift)
