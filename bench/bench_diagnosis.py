"""Benchmark of the arm diagnosis: false-discovery and miss rates over random draws, and the time for 500 poses.

Run by hand: ``.venv/bin/python bench/bench_diagnosis.py [--draws N]``.
Each draw: realistic geometric errors, one hidden effect on a random joint
(strength U(0.6, 1.0) x the noise RMS, as the tests draw it) or none, 160 poses.
A miss: the hidden effect (with its joint) is neither selected nor named as
ambiguous with a selected step. A false discovery: any other selected effect.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.sim.diagnosis_data import simulate_arm_data  # noqa: E402
from station.analysis.diagnose import diagnose_arm  # noqa: E402
from station.models.effects import realistic_effects  # noqa: E402
from station.models.robots import get_robot  # noqa: E402
from tests.diagnosis.hidden import compliance_joints, found, make_case  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--alpha", type=float, default=0.05)
    args = ap.parse_args()
    robot = get_robot("industrial-3100")
    rng = np.random.default_rng()
    effects = ["none", "backlash", "encoder_eccentricity", "joint_compliance", "thermal_drift"]
    tally = {e: [0, 0, 0] for e in effects}  # draws, misses, draws with a false discovery
    by_joint = {}
    for k in range(args.draws):
        effect = effects[k % len(effects)]
        joint = None
        if effect in ("backlash", "encoder_eccentricity"):
            joint = int(rng.integers(1, 7))
        elif effect == "joint_compliance":
            joint = int(rng.choice(compliance_joints(robot)))
        d = make_case(robot, [] if effect == "none" else [(effect, joint)], rng)
        res = diagnose_arm(robot.dh_nominal, d.q_rad, d.xyz_mm, t_s=d.t_s, robot=robot, alpha=args.alpha)
        t = tally[effect]
        t[0] += 1
        if effect != "none":
            miss = not found(res, effect, joint)
            t[1] += miss
            bj = by_joint.setdefault((effect, joint), [0, 0])
            bj[0] += 1
            bj[1] += miss
        extra = [s for s in res.selected if s not in (("geometric", None), (effect, joint))]
        t[2] += bool(extra)
    print(f"alpha {args.alpha}, 160 poses, strength U(0.6, 1.0) x noise RMS")
    print(f"{'hidden':<22}{'draws':>6}{'miss rate':>11}{'false-discovery rate':>22}")
    for e, (n, miss, fd) in tally.items():
        print(f"{e:<22}{n:>6}{(miss / n if e != 'none' else float('nan')):>11.3f}{fd / n:>22.3f}")
    print("misses by joint: " + ", ".join(f"{e}[{j}] {m}/{n}" for (e, j), (n, m) in sorted(by_joint.items(), key=str) if m))
    # time for 500 poses with every effect on
    times = []
    for _ in range(3):
        d = simulate_arm_data(robot, realistic_effects(robot, rng), rng, n=500)
        t0 = time.perf_counter()
        res = diagnose_arm(robot.dh_nominal, d.q_rad, d.xyz_mm, t_s=d.t_s, robot=robot)
        times.append(time.perf_counter() - t0)
    print(f"500 poses, all effects on: {np.median(times):.2f} s median of 3 ({len(res.steps)} steps in the last)")


if __name__ == "__main__":
    main()
