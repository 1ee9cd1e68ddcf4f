"""Benchmark: FK + parameter Jacobian for 10,000 poses, and IK throughput.

Run by hand: ``.venv/bin/python bench/bench_kinematics.py``. Prints the best
of several repeats (ms) for each figure; no assertion on time.
"""

from __future__ import annotations

import time

import numpy as np

from station.models.kinematics import fk, fk_and_param_jacobian, ik, joint_jacobian, param_jacobian
from station.models.robots import get_robot, gravity_torques


def best_ms(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * min(times)


def main() -> None:
    rng = np.random.default_rng(0)
    robot = get_robot("industrial-3100")
    dh = robot.dh_nominal
    lim = robot.joint_limits_rad
    n = 10_000
    q = lim[:, 0] + (lim[:, 1] - lim[:, 0]) * rng.random((n, 6))
    dh_n = dh + rng.normal(0, 1e-3, (n, 7, 5))

    print(f"robot {robot.name}, N = {n} poses")
    print(f"  fk                          {best_ms(lambda: fk(dh, q)):8.1f} ms")
    print(f"  param_jacobian              {best_ms(lambda: param_jacobian(dh, q)):8.1f} ms")
    print(f"  fk + param_jacobian (1 pass){best_ms(lambda: fk_and_param_jacobian(dh, q)):8.1f} ms")
    print(f"  fk + param_jacobian (2 calls){best_ms(lambda: (fk(dh, q), param_jacobian(dh, q))):7.1f} ms")
    print(f"  same, per-sample dh (N,7,5) {best_ms(lambda: fk_and_param_jacobian(dh_n, q)):8.1f} ms")
    print(f"  joint_jacobian              {best_ms(lambda: joint_jacobian(dh, q)):8.1f} ms")
    print(f"  gravity_torques             {best_ms(lambda: gravity_torques(robot, dh, q, 100.0)):8.1f} ms")

    # IK: random reachable targets (well away from singular poses is not
    # enforced here: the figure includes the hard ones and their restarts)
    m = 1000
    q_true = lim[:, 0] + 0.05 + (lim[:, 1] - lim[:, 0] - 0.1) * rng.random((m, 6))
    T = fk(dh, q_true)
    for label, target, q0 in (
        ("pose targets, seed near truth", T, np.clip(q_true + rng.normal(0, 0.1, q_true.shape), lim[:, 0], lim[:, 1])),
        ("pose targets, seed = home", T, robot.home_q_rad),
        ("position targets, seed = home", T[:, :3, 3], robot.home_q_rad),
    ):
        t0 = time.perf_counter()
        res = ik(dh, target, q0=q0, joint_limits_rad=lim)
        dt = time.perf_counter() - t0
        print(
            f"  ik {label:31s} {m} targets in {1e3 * dt:7.1f} ms = {m / dt:8.0f} targets/s; "
            f"success {res.success.mean():.4f}, mean iterations {res.iterations.mean():.1f}, "
            f"mean starts {res.attempts.mean():.2f}"
        )
    t0 = time.perf_counter()
    ik(dh, T[:1], q0=robot.home_q_rad, joint_limits_rad=lim)
    print(f"  ik single pose target (seed = home) {1e3 * (time.perf_counter() - t0):.1f} ms")


if __name__ == "__main__":
    main()
