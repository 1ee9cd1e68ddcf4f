"""Benchmark: how the trailer run's link lengths fall about the truth, through the whole path.

Run by hand: ``.venv/bin/python bench/bench_trailer_run_z.py [--seeds 10] [--first 0] [--no-abort] [--real-time]``.

The flow of ``tests/station/test_trailer_run.py``: the odometry fake on a pty
at 20x (in lockstep with its driver, as a dry run's cell; ``--real-time``: the
unit runs on whatever the station does) with a trailer of random true lengths (1.20-1.30 m, 2.40-2.55 m), the
driver, the procedure (two commands, H and C at 0.18 1/m, 15 s settle, 63 s
each) and the store; by default the run is aborted at a random moment of its
second command and resumed, so the estimate combines two pieces. Printed per
seed and over all: z = (estimate - truth) / stated sigma for L1 and L2, per
piece and combined, and which input each piece used (the set points as an
instrument, or the measured curvature). A calibrated estimator gives z of
mean 0 and spread 1. Takes about 10 s of wall time per seed.
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from fakes.odometry import start_fake
from fakes.sim.trailer import SimTrailer
from fakes.sim.world import make_world
from procedures import trailer as tp
from procedures.devices import DeviceSet
from procedures.trailer import TrailerSession, build_procedure, plan_params
from station.runner import RunControl, Runner
from station.store import RunStore

PLAN = dict(commands=(("H", 0.18), ("C", 0.18)), settle_s=15.0, duration_s=63.0)


def one(seed: int, abort: bool, lockstep: bool = True) -> dict:
    rng = np.random.default_rng(seed)
    L1, L2 = float(rng.uniform(1.20, 1.30)), float(rng.uniform(2.40, 2.55))
    tmp = Path(tempfile.mkdtemp(prefix="bench-trailer-"))
    world = make_world(seed=int(rng.integers(2**31)), time_scale=20.0, effects=None)
    world.trailer = SimTrailer(world.clock, L1_m=L1, L2_m=L2, rng=world.rng)
    fake = start_fake(world, lockstep=lockstep)
    store = RunStore(tmp / "s.sqlite")
    plan = tp.TrailerCalibrationPlan(**PLAN)
    params = {"plan": plan_params(plan), "report_dir": str(tmp / "r")}
    url = f"nmea://{fake.endpoint['device']}" + ("?lockstep=1" if lockstep else "")
    try:
        control = RunControl()
        session = TrailerSession(DeviceSet(urls={"odometry": url}))
        done = threading.Event()

        def abort_in_second_command():
            while not done.is_set():
                steps = store.steps("b") if store.runs() else []
                if any(s.name.startswith("command 2") and s.status == "running" for s in steps) and \
                        store.sample_count("b", "odometry") > store.sample_count("b", "odometry", finished_only=True):
                    time.sleep(float(rng.uniform(0.0, 1.5)))
                    control.abort()
                    return
                time.sleep(0.05)

        th = threading.Thread(target=abort_in_second_command)
        if abort:
            th.start()
        Runner(store, build_procedure(plan), control=control, session=session).start(
            "b", params=params, model="trailer", serial="TR-B")
        done.set()
        if abort:
            th.join()
        session.close()
        if abort:
            session = TrailerSession(DeviceSet(urls={"odometry": url}))
            Runner(store, build_procedure(plan), session=session).resume("b")
            session.close()
        res = store.result("b", "trailer")["result"]
        pieces = [p for p in (res.get("details") or {}).get("pieces", [])] or [res]
        return {"z1": (res["L1_m"] - L1) / res["L1_sigma_m"], "z2": (res["L2_m"] - L2) / res["L2_sigma_m"],
                "pieces": [((p["L1_m"] - L1) / p["L1_sigma_m"], (p["L2_m"] - L2) / p["L2_sigma_m"],
                            (p.get("details") or {}).get("input", "")) for p in pieces]}
    finally:
        fake.close()
        world.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--no-abort", action="store_true", help="one uninterrupted run per seed")
    ap.add_argument("--real-time", action="store_true", help="the unit runs on, not in lockstep with the driver")
    args = ap.parse_args()
    z = []
    for s in range(args.first, args.first + args.seeds):
        r = one(s, not args.no_abort, not args.real_time)
        z.append((r["z1"], r["z2"]))
        parts = "  ".join(f"[{a:+.2f} {b:+.2f} {inp.split()[0] if inp else '?'}]" for a, b, inp in r["pieces"])
        print(f"seed {s:4d}: z(L1) {r['z1']:+.2f}  z(L2) {r['z2']:+.2f}   pieces {parts}", flush=True)
    z = np.array(z)
    print(f"{len(z)} runs: z(L1) mean {z[:, 0].mean():+.2f} sd {z[:, 0].std():.2f}; "
          f"z(L2) mean {z[:, 1].mean():+.2f} sd {z[:, 1].std():.2f}, largest |z(L2)| {np.abs(z[:, 1]).max():.2f}")


if __name__ == "__main__":
    main()
