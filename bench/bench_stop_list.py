"""A stop list of many distinct poses through `station analyze iso9283 --stops --poses` (issue 47 item 10).

    .venv/bin/python bench/bench_stop_list.py [N_POSES ...]

For each N_POSES (default 8,000 and 100,000) writes a stop list of N_POSES poses x 2 cycles and the commanded
poses to a temporary directory, runs the analysis in this process (`app.cli.main`) and prints its wall and CPU time (on a shared machine,
compare CPU times with OMP_NUM_THREADS=1).
The stops were matched to their pose by comparing every stop's name with every pose's (K x P): 8,000 poses
took 3 s and 100,000 over 60 s; the grouping is now one pass over the stops. AP, RP, the scatter and the
JSON's lists were per-pose numpy calls (100,000 poses: 42-46 s CPU); batched, 26-30 s.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.cli import main as cli  # noqa: E402


def run(n_poses: int) -> float:
    rng = np.random.default_rng(0)
    cmd = rng.uniform(-1000.0, 1000.0, (n_poses, 3))
    with tempfile.TemporaryDirectory() as d:
        poses, stops = Path(d) / "poses.csv", Path(d) / "stops.csv"
        poses.write_text("name,x,y,z\n"
                         + "".join(f"Q{i},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(cmd)))
        rows = ["pose,cycle,x,y,z\n"]
        for cycle in (1, 2):
            xyz = cmd + rng.normal(0.0, 0.02, cmd.shape)
            rows += [f"Q{i},{cycle},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(xyz)]
        stops.write_text("".join(rows))
        out = io.StringIO()
        a, c = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(out):
            code = cli(["analyze", "iso9283", "--stops", str(stops), "--poses", str(poses), "--json", str(Path(d) / "r.json")])
        took, cpu = time.perf_counter() - a, time.process_time() - c
    print(f"{n_poses:>8} poses, {2 * n_poses:>8} stops: exit {code}, {took:6.2f} s wall, {cpu:6.2f} s CPU")
    return took


if __name__ == "__main__":
    for n in [int(a) for a in sys.argv[1:]] or [8_000, 100_000]:
        run(n)
