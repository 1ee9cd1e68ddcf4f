"""A stop list of many distinct poses through `station analyze iso9283 --stops --poses` (issue 47 item 10).

    .venv/bin/python bench/bench_stop_list.py [--cycles C] [N_POSES ...]

For each N_POSES (default 8,000 and 100,000) writes a stop list of N_POSES poses x C cycles (default 2) and the
commanded poses to a temporary directory, runs the analysis in this process (`app.cli.main`) and prints its wall
and CPU time and the process's peak RSS so far (on a shared machine, compare CPU times with OMP_NUM_THREADS=1).
A normal lab list: `--cycles 30 5`.
The stops were matched to their pose by comparing every stop's name with every pose's (K x P): 8,000 poses
took 3 s and 100,000 over 60 s; the grouping is now one pass over the stops. AP, RP, the scatter and the
JSON's lists were per-pose numpy calls (100,000 poses: 42-46 s CPU); batched, 26-30 s. Then the reader checks
whole columns, the poses are grouped in one sort, their JSON text is written from numbers rounded together a
batch at a time (never the whole record in memory) and the cycle collector is paused for the run: 11-12 s CPU
on a loaded machine where the version before took 25-29 s, peak RSS about 0.5 GB (was 0.97 GB).
"""

from __future__ import annotations

import contextlib
import io
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cli import main as cli  # noqa: E402


def run(n_poses: int, cycles: int = 2) -> float:
    rng = np.random.default_rng(0)
    cmd = rng.uniform(-1000.0, 1000.0, (n_poses, 3))
    with tempfile.TemporaryDirectory() as d:
        poses, stops = Path(d) / "poses.csv", Path(d) / "stops.csv"
        poses.write_text("name,x,y,z\n"
                         + "".join(f"Q{i},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(cmd)))
        rows = ["pose,cycle,x,y,z\n"]
        for cycle in range(1, cycles + 1):
            xyz = cmd + rng.normal(0.0, 0.02, cmd.shape)
            rows += [f"Q{i},{cycle},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(xyz)]
        stops.write_text("".join(rows))
        out = io.StringIO()
        a, c = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(out):
            code = cli(["analyze", "iso9283", "--stops", str(stops), "--poses", str(poses), "--json", str(Path(d) / "r.json")])
        took, cpu = time.perf_counter() - a, time.process_time() - c
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{n_poses:>8} poses, {cycles * n_poses:>8} stops: exit {code}, {took:6.2f} s wall, {cpu:6.2f} s CPU, "
          f"peak RSS so far {rss:.0f} MB")
    return took


if __name__ == "__main__":
    argv = sys.argv[1:]
    n_cycles = 2
    if argv[:1] == ["--cycles"]:
        n_cycles, argv = int(argv[1]), argv[2:]
    for n in [int(a) for a in argv] or [8_000, 100_000]:
        run(n, n_cycles)
