"""Benchmark: simulate and sample one hour of tracker data at 1 kHz.

Run by hand::

    .venv/bin/python bench/bench_sim.py [--hours 1.0] [--rate 1000] [--chunk-s 60]

The simulated cell (industrial-3100, realistic effects, servo and stop scatter,
on a ManualClock) runs ISO 9283 cycles (P2, P3, P4, P5, P1 with 0.5 s dwells)
for the requested time; the tracker model then measures the whole stream in
chunks, as a tracker fake or ``station simulate`` does. Prints the time to
queue the moves, the time to measure, the sample rate achieved (samples per
host second) and the peak resident memory.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.sim.clock import ManualClock  # noqa: E402
from fakes.sim.world import make_world  # noqa: E402
from station.analysis.iso9283.poses import TABLE2_POSES_MM  # noqa: E402
from fakes.sim.iso_run import CYCLE_ORDER, commanded_joints  # noqa: E402


def run(hours: float, rate_hz: float, chunk_s: float, effects: str | None) -> dict:
    world = make_world(seed=1, clock=ManualClock(), effects=effects, tracker_rate_hz=rate_hz)
    _, q = commanded_joints(world.robot, np.array(TABLE2_POSES_MM))
    names = ("P1", "P2", "P3", "P4", "P5")
    arm = world.arm
    t0 = time.perf_counter()
    arm.move_joint(q[0])
    n_moves = 0
    while arm.queue_end_s < hours * 3600.0:
        for name in CYCLE_ORDER:
            arm.move_joint(q[names.index(name)])
            arm.dwell(0.5)
            n_moves += 1
    t_plan = time.perf_counter() - t0
    end = arm.queue_end_s
    src = world.tracker_source()
    t1 = time.perf_counter()
    n = 0
    checksum = 0.0
    t = 0.0
    while t < end:  # the clock follows the measurement, as in a live run
        t_next = min(t + chunk_s, end)
        ts = src.sample_times(t, t_next)
        world.clock.sleep_until(t_next)
        xyz, valid = src.measure(ts)
        n += ts.size
        checksum += float(np.nansum(xyz[:1]))
        t = t_next
    t_meas = time.perf_counter() - t1
    return {
        "effects": effects or "none",
        "sim_s": end,
        "moves": n_moves,
        "samples": n,
        "plan_s": t_plan,
        "measure_s": t_meas,
        "rate": n / t_meas,
        "segments_kept": arm._seg.n,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--chunk-s", type=float, default=60.0)
    args = ap.parse_args()
    for effects in ("realistic", None):
        r = run(args.hours, args.rate, args.chunk_s, effects)
        print(
            f"effects={r['effects']:9s} simulated {r['sim_s']:.0f} s ({r['moves']} moves), "
            f"{r['samples']} samples at {args.rate:g} Hz: queue {r['plan_s']:.2f} s, "
            f"measure {r['measure_s']:.1f} s = {r['rate'] / 1e3:.0f} k samples/s "
            f"({r['sim_s'] / (r['plan_s'] + r['measure_s']):.0f}x real time); segments kept {r['segments_kept']}"
        )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"peak resident memory {peak_mb:.0f} MB")


if __name__ == "__main__":
    main()
