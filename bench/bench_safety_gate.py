"""Benchmark: the safety gate checking an ISO 9283 pose program, first and again.

Run by hand: ``.venv/bin/python bench/bench_safety_gate.py [--repeat N]``.

A station checks every cycle's program before it uploads it, from the joints
the controller reports; the same program from the same joints is the same
problem, and the gate reuses what it solved (``station.safety``'s memo of
inverse kinematics). Printed: process time of the first check (the memo
emptied before each) and of a check again, mean of ``--repeat``. No assertion
on time.
"""

from __future__ import annotations

import argparse
import time

import station.safety as safety
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.models.robots import get_robot
from station.programs import iso_pose_program, render_rapid
from station.safety import SafetyGate, SafetyLimits


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()
    robot = get_robot("industrial-3100")
    # the suite's cell box around seed 000's cube (Table 2)
    gate = SafetyGate(robot, SafetyLimits(workspace_min_mm=(-700.0, 1000.0, 700.0),
                                          workspace_max_mm=(700.0, 2400.0, 2100.0), max_tcp_speed_mm_s=2000.0))
    poses = {f"P{i + 1}": tuple(p) for i, p in enumerate(TABLE2_POSES_MM)}
    program = render_rapid(iso_pose_program(robot, poses, cycles=2))
    first = again = 0.0
    for _ in range(args.repeat):
        safety._IK_MEMO.clear()
        t0 = time.process_time()
        gate.check_program(program)
        t1 = time.process_time()
        gate.check_program(program)
        t2 = time.process_time()
        first += t1 - t0
        again += t2 - t1
    n = args.repeat
    print(f"check of a 5-pose ISO program, first   {1e3 * first / n:7.1f} ms")
    print(f"the same program again (memo)          {1e3 * again / n:7.1f} ms")


if __name__ == "__main__":
    main()
