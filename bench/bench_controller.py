"""Controller path figures: gate time, upload time, interpreter throughput vs clock speed.

Run by hand: ``.venv/bin/python bench/bench_controller.py``. Prints

* the safety gate's time for an ISO 9283 30-cycle pose program and a vAP program;
* FTP upload with read-back verification (the RAPID file of that program);
* for several clock speeds, a 5-cycle run through driver and fake: host time,
  and the idle gaps the interpreter left between moves (non-zero gaps mean the
  fake could not plan the next move before the previous one ended: the
  highest gap-free ``time_scale`` on this machine).
"""

from __future__ import annotations

import time

import numpy as np

from drivers.controller import ControllerDriver
from fakes.controller import start_fake
from fakes.sim.world import make_world
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.models.robots import get_robot
from station.programs import iso_pose_program, render_rapid, vap_program
from station.safety import SafetyGate, SafetyLimits

POSES = {f"P{i + 1}": p for i, p in enumerate(TABLE2_POSES_MM)}
LIMITS = SafetyLimits(workspace_min_mm=(-700, 1000, 700), workspace_max_mm=(700, 2400, 2100), max_tcp_speed_mm_s=2000)


def main() -> None:
    robot = get_robot("industrial-3100")
    gate = SafetyGate(robot, LIMITS)
    iso = render_rapid(iso_pose_program(robot, POSES, cycles=30))
    vap = render_rapid(vap_program(robot, {k: POSES[k] for k in ("P1", "P2", "P4")}, cycles=30))
    for name, prog in (("ISO pose, 30 cycles", iso), ("vAP P1/P2/P4, 30 cycles", vap)):
        t = time.perf_counter()
        n = 5
        for _ in range(n):
            gate.check_program(prog)
        print(f"gate {name}: {1e3 * (time.perf_counter() - t) / n:.1f} ms per check")

    for scale in (10.0, 25.0, 50.0, 100.0, 200.0):
        world = make_world(robot, seed=1, time_scale=scale, effects=None)
        fake = start_fake(world)
        try:
            with ControllerDriver.from_url(fake.url, gate=gate, timeout_s=5) as drv:
                t = time.perf_counter()
                drv.upload(iso)
                t_up = time.perf_counter() - t
                prog = render_rapid(iso_pose_program(robot, POSES, cycles=5, name="BENCH"))
                t0 = world.clock.now()
                t = time.perf_counter()
                st = drv.run(prog, timeout_s=300)
                wall = time.perf_counter() - t
            moves = [m for m in world.arm.moves if m.t_start >= t0]
            gaps = np.array([b.t_start - a.t_end for a, b in zip(moves[:-1], moves[1:])])
            sim = moves[-1].t_end - moves[0].t_start
            print(
                f"time_scale {scale:6.0f}: upload+verify {1e3 * t_up:5.1f} ms; 5-cycle run {wall:5.2f} s host "
                f"({sim:.1f} s sim, {st.moves_done} moves); idle gaps total {gaps.sum():.2f} s sim, "
                f"max {gaps.max():.3f} s"
            )
        finally:
            fake.close()
            world.close()


if __name__ == "__main__":
    main()
