"""Reading lab files: a SpatialAnalyzer export with two-digit-year stamps at 180 samples per stamp.

    .venv/bin/python bench/bench_lab_files.py [N_ROWS]

Writes an export of N_ROWS points (default 500,000) to a temporary file, reads it with the station's reader
(dates parsed, day/month order settled) and fixes its time base from the coarse stamps (the rate estimated);
prints the rows per second of each part.
"""

from __future__ import annotations

import sys
import tempfile
import time
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from station.analysis.iso9283.lab_files import stream_time_base  # noqa: E402
from station.readers.spatial_analyzer import read_sa_points  # noqa: E402


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 500_000
    rng = np.random.default_rng(0)
    t0 = datetime(2025, 3, 11, 14, 7, 52)
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "export.txt"
        xyz = 1000.0 + rng.normal(0, 0.01, (n, 3))
        with open(f, "w", encoding="utf-8") as fh:
            fh.write("// SpatialAnalyzer SA 2024\n// Points Relative to Coordinate Frame 'A::WORLD'\n"
                     "// AXES = CARTESIAN: X,  Y,  Z (mm)\n")
            for i in range(n):
                stamp = (t0 + timedelta(seconds=i // 180)).strftime("%m/%d/%y %H:%M:%S")
                fh.write(f"Traj,  P1,  {i},  {xyz[i, 0]:.6f},  {xyz[i, 1]:.6f},  {xyz[i, 2]:.6f},  {stamp}\n")
        a = time.perf_counter()
        ps = read_sa_points(f)
        b = time.perf_counter()
        tb = stream_time_base(ps.t_s, ps.n, line=ps.line, source=str(f), tcol="date time")
        c = time.perf_counter()
    print(f"{n} rows: read {b - a:.2f} s ({n / (b - a):,.0f} rows/s), time base {c - b:.3f} s; "
          f"rate {tb.info['rate_hz']:.3f} Hz")


if __name__ == "__main__":
    main()
