"""RTDE in lockstep: every data package reaches the driver, and what that costs.

Run by hand::

    .venv/bin/python bench/bench_rtde_lockstep.py [--rate 10] [--seconds 30] [--time-scale 1e4]

A lockstep UR fake (the dry-run cells' controller) whose clock runs on while
the simulated UR5e sweeps between two poses, and the driver's receive process
(``ur_rtde``'s receive interface) saying which package it kept through
``input_double_register_22`` (``station.protocols.ur.LOCKSTEP_STORED_REGISTER``).
Prints the packages sent and kept, gaps in the kept timestamps, the simulated
seconds per real second the stream allowed and the round trip per package. The
same without the register (the fake streams in batches, ``ur_rtde`` keeps the
newest of each) for comparison.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

try:
    import fakes  # noqa: F401
except ModuleNotFoundError:  # run from a checkout without an installed package
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_rtde import keep_moving  # noqa: E402
from drivers.ur import RtdeSidecar  # noqa: E402
from fakes.sim.clock import SimClock  # noqa: E402
from fakes.sim.world import make_world  # noqa: E402
from fakes.ur import start_fake  # noqa: E402
from station.protocols.ur import LOCKSTEP_STORED_REGISTER  # noqa: E402


def one(rate_hz: float, seconds: float, time_scale: float, kept_register: int | None) -> dict:
    world = make_world(robot="ur5e", seed=0, clock=SimClock(time_scale, lockstep=True))
    fake = start_fake(world, lockstep=True)
    keep_moving(world, 2.5 * seconds + 30)
    running = world.clock.keep_running()
    side = RtdeSidecar(fake.endpoint["host"], rate_hz, stored_register=kept_register)
    try:
        side.start(30.0)
        rows, t_start, wall0 = [], None, None
        while True:
            r, _dropped, connected = side.drain()
            if len(r):
                rows.append(r)
                if t_start is None:
                    t_start, wall0, sent0 = r[0, 0], time.monotonic(), fake.packets_sent
                if r[-1, 0] - t_start >= seconds:
                    break
            if not connected:
                raise SystemExit("the RTDE link dropped")
            time.sleep(0.02)
        wall = time.monotonic() - wall0
        t = np.concatenate(rows)[:, 0]
        t = t[(t >= t_start) & (t - t_start <= seconds)]
        sent = int(round(seconds * rate_hz)) + 1
        gaps = np.round(np.diff(t) * rate_hz).astype(int)
        return {"kept": len(t), "window": sent, "gaps_gt1": int(np.sum(gaps > 1)), "wall_s": wall,
                "sim_per_real": seconds / wall, "round_trip_ms": 1e3 * wall / max(1, len(t) - 1)}
    finally:
        side.close()
        running.cancel()
        fake.close()
        world.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=10.0, help="RTDE output frequency, Hz")
    ap.add_argument("--seconds", type=float, default=30.0, help="simulated seconds")
    ap.add_argument("--time-scale", type=float, default=1e4, help="the clock's pace bound")
    args = ap.parse_args()
    print(f"lockstep UR fake, {args.rate:g} Hz, {args.seconds:g} simulated s, time scale <= {args.time_scale:g}")
    for label, reg in (("kept package acknowledged (register 22)", LOCKSTEP_STORED_REGISTER),
                       ("no acknowledgement (batches)", None)):
        r = one(args.rate, args.seconds, args.time_scale, reg)
        print(f"{label}: kept {r['kept']} of {r['window']} packages in the window, gaps > 1 period "
              f"{r['gaps_gt1']}; wall {r['wall_s']:.2f} s = {r['sim_per_real']:.0f} simulated s per s; "
              f"{r['round_trip_ms']:.2f} ms per kept package")
    return 0


if __name__ == "__main__":
    sys.exit(main())
