"""Benchmark: the UR fake's cost per RTDE batch (process time, no sockets).

Run by hand: ``.venv/bin/python bench/bench_ur_stream_cpu.py [--seconds 2]``.

The fake's stream computes the columns of its client's recipe for every batch
of due samples: joints, the TCP pose and speed (forward kinematics, rotation
vectors), modes and registers. At an accelerated pace it wakes for one or two
packets at a time, so the cost per batch, not per sample, sets its CPU. The
recipe is the UR driver's (``drivers.ur.rtde_variables``). Printed: thread time
per batch and per sample for batches of 1, 4 and 16 samples at 500 Hz while the
simulated arm is at rest. No assertion on time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from drivers.ur import rtde_variables
from fakes.sim.world import make_world
from fakes.ur import FaultPlan, _Controller


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="thread time spent per batch size")
    args = ap.parse_args()
    world = make_world(robot="ur5e", seed=1, time_scale=1.0)
    try:
        ctl = _Controller(world, FaultPlan.parse(None))
        names = list(rtde_variables(12))
        t0 = world.clock.now() + 1.0
        for n in (1, 4, 16):
            ts = t0 + np.arange(n) / 500.0
            ctl.columns(names, ts)
            k, start = 0, time.thread_time()
            while time.thread_time() - start < args.seconds:
                ctl.columns(names, ts)
                k += 1
            per = (time.thread_time() - start) / k
            print(f"batch of {n:2d}: {1e6 * per:7.1f} us per batch, {1e6 * per / n:6.1f} us per sample")
    finally:
        world.close()


if __name__ == "__main__":
    main()
