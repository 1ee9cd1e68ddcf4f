"""A real `station run` dry run signalled at a random moment (SIGINT, SIGTERM or SIGKILL) and resumed.

The station process runs its own fake cell (no `--arm`), so a signal takes the
simulated robot and tracker down with it, as a crash would; `station run
--resume` starts the cell again, its clock going on after what the run
stored. The moment, the signal and the world are drawn from one seed that the
test prints. Checked against an uninterrupted run of the same seed: the
resumed run is done with every step once (the session steps again), its
analysed stream's time never repeats or goes back, every batch acknowledged
before the signal is still there, the cycle counts are the same and AP/RP
are within the tracker-noise tolerance of :mod:`tests.station.test_resume_anywhere`.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fakes.cells import demo_config
from station.store import RunStore
from tests.pace import LOCKSTEP
from tests.station.test_resume_anywhere import CYCLES, VAP, _analysis, _tolerance

ROOT = Path(__file__).resolve().parents[2]
SCALE = str(LOCKSTEP)  # a pose cycle still takes a few tenths of a second: the signal lands inside steps


def _station(*args):
    return [sys.executable, "-m", "app.cli", *args]


def _batches(db: Path, run_id: str) -> dict:
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT stream, step_idx, attempt, batch_no, data FROM sample_batches WHERE run_id=?",
                           (run_id,)).fetchall()
    finally:
        con.close()
    return {tuple(r[:4]): r[4] for r in rows}


def test_a_signalled_station_run_resumes_to_the_uninterrupted_result(test_seed, tmp_path):
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    rng = np.random.default_rng(seed)
    sig = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL][int(rng.integers(3))]
    total_steps = 6 + CYCLES + VAP + 3
    after = int(rng.integers(3, total_steps - 3))  # from the prompts to the analysis
    delay = float(rng.uniform(0.0, 0.2))  # then a moment into the next step
    print(f"seed {seed}: {sig.name} {delay:.2f} s after {after} steps are done")
    cfg = tmp_path / "station.json"
    cfg.write_text(json.dumps(demo_config(tmp_path, cycles=CYCLES, vap_cycles=VAP, rate_hz=100.0)))
    common = ["--config", str(cfg), "--yes", "--quiet", "--time-scale", SCALE, "--seed", str(seed)]
    ref = subprocess.run(_station("run", "iso9283", "--run-id", "ref", *common), cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert ref.returncode in (0, 1, 3), ref.stderr  # finished: PASS, FAIL or NOT DECIDED (not 2, not 5 ABORTED)

    db = tmp_path / "station.sqlite"
    child = subprocess.Popen(_station("run", "iso9283", "--run-id", "cut", *common), cwd=ROOT,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 180
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)

    def done_cut() -> int:
        try:
            return con.execute("SELECT COUNT(*) FROM steps WHERE run_id='cut' AND status='done'").fetchone()[0]
        except sqlite3.OperationalError:
            return 0

    try:
        while done_cut() < after and child.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        con.close()
    time.sleep(delay)
    if child.poll() is None:
        os.kill(child.pid, sig)
    child.wait(timeout=30)
    err = child.stderr.read().decode()
    child.stderr.close()
    store = RunStore(db)
    before = _batches(db, "cut")
    if store.run("cut").status == "done":
        pytest.skip(f"the run finished before the signal (seed {seed}); nothing to resume")
    resumed = subprocess.run(_station("run", "--resume", "cut", *common[:-4]), cwd=ROOT, capture_output=True,
                             text=True, timeout=300)
    # the resumed run ends with the verdict (and exit code) of the run left alone
    assert resumed.returncode == ref.returncode, (err, resumed.stdout, resumed.stderr)
    assert store.run("cut").status == "done"
    after_batches = _batches(db, "cut")
    assert not [k for k, blob in before.items() if after_batches.get(k) != blob], "acknowledged batches lost"
    done = {}
    for s in store.steps("cut"):
        if s.status == "done":
            done[s.name] = done.get(s.name, 0) + 1
    assert len(done) == total_steps
    for name, n in done.items():
        assert n == 1 or (n == 2 and name in ("check programs", "connect devices", "home")), (name, n)
    ref_res, cut_res = _analysis(store, "ref"), _analysis(store, "cut")  # asserts the time base
    sigma = float(ref_res.extraction.params.noise_mm)
    for p, pr in ref_res.poses.items():
        pc = cut_res.poses[p]
        assert pc.n_cycles == pr.n_cycles == CYCLES
        # family-wise over the poses' two figures each (P4's dAP was 1.01x its single 99.9 % quantile on seed
        # 970463414, the other nine checks far inside theirs)
        tol_ap, tol_rp = _tolerance(pr.attained_mm, pr.commanded_mm, 0, sigma, rng, checks=2 * len(ref_res.poses))
        d_ap = abs(pc.accuracy.AP_mm - pr.accuracy.AP_mm)
        d_rp = abs(pc.repeatability.RP_mm - pr.repeatability.RP_mm)
        print(f"  {p}: dAP {d_ap:.4f} (tol {tol_ap:.4f}) dRP {d_rp:.4f} (tol {tol_rp:.4f}) mm")
        assert d_ap <= tol_ap and d_rp <= tol_rp, (p, d_ap, tol_ap, d_rp, tol_rp)
