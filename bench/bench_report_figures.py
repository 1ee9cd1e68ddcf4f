"""Benchmark: the report's figures, drawn into SVG as a run's report draws them.

Run by hand: ``.venv/bin/python bench/bench_report_figures.py [--repeat N]``.

Five poses of 30 attained positions (the cluster figure, three panels), a
60 s speed trace at 50 Hz with two extraction windows, and a bar chart of
twelve cycles against a limit: the three kinds an ISO 9283 report draws
most. The figure is process time per figure (mean of ``--repeat``), after
one warm-up figure that pays matplotlib's imports. No assertion on time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from station import report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    clusters = {f"P{i}": rng.normal(0.0, 0.02, (30, 3)) for i in range(1, 6)}
    t = np.linspace(0.0, 60.0, 3000)
    speed = np.abs(rng.normal(0.0, 50.0, t.size))
    bars = rng.uniform(0.0, 0.01, 12)
    figures = {
        "clusters (3 panels)": lambda: report.plot_clusters(clusters, commanded_mm=np.array([0.01, 0.0, 0.0])),
        "speed and windows": lambda: report.plot_velocity_windows(t, speed, [(1.0, 2.0), (5.0, 6.0)]),
        "bars (12 cycles)": lambda: report.plot_bars([f"cycle {i}" for i in range(12)], bars, limit=0.008,
                                                    ylabel="RP [mm]", title="Repeatability per cycle"),
    }
    report.plot_bars(["a"], [1.0], ylabel="x", title="warm-up")
    for name, draw in figures.items():
        t0 = time.process_time()
        for _ in range(args.repeat):
            svg = draw()
        dt = (time.process_time() - t0) / args.repeat
        print(f"{name:22s} {1000 * dt:7.1f} ms per figure, {len(svg) / 1024:6.1f} KiB of SVG")


if __name__ == "__main__":
    main()
