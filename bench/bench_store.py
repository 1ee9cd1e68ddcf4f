"""Benchmark: pushing a one-hour 1 kHz ISO run to the central store; fleet queries on 1,000 robots x 50 runs.

Run by hand: ``.venv/bin/python bench/bench_store.py [--samples 3600000] [--per-batch 100] [--robots 1000] [--runs 50]``.

Starts a private PostgreSQL server (as the tests do, but with fsync on, as a
plant's server would run), writes a local SQLite store with one run of
``--samples`` tracker samples (t, x, y, z, status) in batches of
``--per-batch`` (the ISO procedure commits what each read brings, ~0.1 s at
1 kHz), pushes it with :func:`station.store.forward.push` and checks that the
centre holds every sample; then pushes again (nothing to send). Then loads a
simulated fleet and times each fleet question on PostgreSQL and on SQLite.
Last, makes one ISO run on the fake cell, archives it ``--copies`` times and
re-analyses them in 1 and 2 processes (runs per minute per core).
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.fleet.questions import drifting, over_limits_now, robot_history, since_overhaul  # noqa: E402
from app.terminal import InteractiveOperator  # noqa: E402
from station.store import RunStore  # noqa: E402
from station.store.forward import push  # noqa: E402
from tests.store.fleetgen import load_fleet, make_fleet  # noqa: E402
from tests.store.pgserver import PgServer  # noqa: E402


def bench_push(server: PgServer, tmp: Path, n_samples: int, per_batch: int, chunk: int) -> None:
    rng = np.random.default_rng()
    local = RunStore(tmp / "local.sqlite", station="cell-1")
    local.create_run("SN-1-iso", "iso9283", model="industrial-3100", serial="SN-1", overhaul_state="after",
                     config={}, params={})
    att = local.step_started("SN-1-iso", 0, "cycles")
    t0 = time.perf_counter()
    t = np.arange(n_samples) / 1000.0
    xyz = rng.normal(size=(n_samples, 3)) * 1000.0
    for s in range(0, n_samples, per_batch):
        e = min(s + per_batch, n_samples)
        local.append_samples("SN-1-iso", "tracker", 0, att, {"t": t[s:e], "x": xyz[s:e, 0], "y": xyz[s:e, 1],
                                                             "z": xyz[s:e, 2], "status": np.zeros(e - s)})
    local.step_ended("SN-1-iso", 0, att, "done")
    local.set_run_status("SN-1-iso", "done")
    t_write = time.perf_counter() - t0
    n_batches = -(-n_samples // per_batch)
    mb = n_samples * 5 * 8 / 1e6
    print(f"local SQLite: {n_samples:,} samples in {n_batches:,} batches ({mb:.0f} MB) written in {t_write:.1f} s "
          f"(each batch its own synchronous commit)")
    central = RunStore(server.create_db("bench_push"))
    t0 = time.perf_counter()
    rep = push(local, central, station="cell-1", chunk_batches=chunk)
    t_push = time.perf_counter() - t0
    n_central = central.sample_count("SN-1-iso")
    assert n_central == n_samples and rep.samples_sent == n_samples, (n_central, rep.samples_sent)
    print(f"push to PostgreSQL (fsync on, {chunk} batches per transaction): {t_push:.2f} s "
          f"= {n_samples / t_push / 1e6:.2f} M samples/s, {mb / t_push:.0f} MB/s; centre holds all {n_central:,}")
    t0 = time.perf_counter()
    rep = push(local, central, station="cell-1")
    print(f"push again: {time.perf_counter() - t0:.3f} s, {rep.batches_sent} batches sent")
    t0 = time.perf_counter()
    got = central.samples("SN-1-iso", "tracker")
    print(f"read back from the centre: {time.perf_counter() - t0:.2f} s; equal: "
          f"{bool(np.array_equal(got['x'], xyz[:, 0]))}")
    local.close()
    central.close()


def _timed(label: str, fn, repeat: int = 3):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    print(f"  {label:<44} {best * 1e3:8.1f} ms  ({len(out)} rows)")
    return out


def bench_fleet(store: RunStore, robots: int, runs: int, label: str) -> None:
    rng = np.random.default_rng()
    fleet = make_fleet(rng, robots, runs)
    t0 = time.perf_counter()
    load_fleet(store, fleet)
    print(f"{label}: {robots} robots x {runs} runs x 5 poses loaded in {time.perf_counter() - t0:.1f} s")
    _timed("history of one robot (all poses)", lambda: robot_history(store, "SN-00007", "RP_mm"))
    _timed("change and trend since overhaul, every robot", lambda: since_overhaul(store, "RP_mm"))
    _timed("over limits now, every robot", lambda: over_limits_now(store, "RP_mm"))
    found = _timed("drifting robots (trend test, FDR 0.05)", lambda: drifting(store, "RP_mm"))
    hit = {d["serial"] for d in found}
    print(f"  drifting: found {len(hit & fleet.drifting)} of {len(fleet.drifting)} drifting robots, "
          f"{len(hit - fleet.drifting)} false flags")


def bench_reanalysis(tmp: Path, cycles: int, copies: int) -> None:
    """One real ISO run on the fake cell (through the drivers), archived ``copies`` times, re-analysed."""
    from fakes.station import FakeStation
    from app.assemble import RunRequest, run_procedure
    from station.config import config_from_dict
    from app.reanalysis import reanalyze

    db = tmp / "iso.sqlite"
    t0 = time.perf_counter()
    with FakeStation.start(seed=int(np.random.default_rng().integers(0, 2**31)), time_scale=20.0) as cell:
        cfg = config_from_dict(cell.config_dict(store_path=str(db), report_dir=str(tmp / "reports"),
                                                iso9283={"cycles": cycles, "vap_cycles": cycles}))
        assert run_procedure(RunRequest(cfg, "iso9283", arm=True, operator=InteractiveOperator(io.StringIO("y\n" * 50), io.StringIO()), quiet=True, run_id="iso-0", config_dir=tmp)).status == "done"
    with RunStore(db) as store:
        n = store.sample_count("iso-0")
        for k in range(1, copies):
            for table in ("runs", "steps", "sample_batches", "results", "characteristics"):
                cols = [r[1] for r in store.backend.query(f"PRAGMA table_info({table})")]
                sel = ", ".join(f"'iso-{k}'" if c == "run_id" else c for c in cols)
                store.backend.execute(f"INSERT INTO {table} ({', '.join(cols)}) SELECT {sel} FROM {table}"
                                      " WHERE run_id='iso-0'")
    print(f"re-analysis: one ISO run of {cycles}+{cycles} cycles ({n:,} samples) made in "
          f"{time.perf_counter() - t0:.0f} s, archived {copies} times")
    ids = [f"iso-{k}" for k in range(copies)]
    for jobs in (1, 2):
        t0 = time.perf_counter()
        done = reanalyze(db, ids, jobs=jobs, force=True)
        wall = time.perf_counter() - t0
        assert not any(d.error for d in done) and max(d.max_change for d in done) == 0.0
        print(f"  {jobs} process(es): {copies} runs in {wall:.1f} s = {60 * copies / wall:.0f} runs/min "
              f"({60 * copies / wall / jobs:.0f} runs/min/core; {np.mean([d.seconds for d in done]):.2f} s per run "
              "inside a worker)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=3_600_000)
    ap.add_argument("--per-batch", type=int, default=100)
    ap.add_argument("--chunk", type=int, default=500)
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--iso-cycles", type=int, default=30)
    ap.add_argument("--copies", type=int, default=8)
    args = ap.parse_args(argv)
    server = PgServer(fsync=True)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            bench_push(server, Path(tmp), args.samples, args.per_batch, args.chunk)
            with RunStore(server.create_db("bench_fleet")) as pg:
                bench_fleet(pg, args.robots, args.runs, "fleet on PostgreSQL")
            with RunStore(Path(tmp) / "fleet.sqlite") as lite:
                bench_fleet(lite, args.robots, args.runs, "fleet on SQLite")
            bench_reanalysis(Path(tmp), args.iso_cycles, args.copies)
    finally:
        server.close()


if __name__ == "__main__":
    main()
