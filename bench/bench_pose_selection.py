"""Benchmark: calibration test error with D-optimal poses against random poses of the same count.

Run by hand: ``.venv/bin/python bench/bench_pose_selection.py [--draws 20] [--robot rb5-850]``.

Each draw: a true arm near the nominal one (lengths ~0.5 mm, angles ~0.1 deg
off), 1,000 random admissible candidate poses, noise 0.03 mm, the instrument
anywhere. N poses are chosen by :func:`select_poses` and N at random from the
same candidates; each set is measured and identified; the test error is the
identified model against the true arm over 300 held-out poses (rigid motion
removed). Prints mean and 90th percentile over the draws, and the time of the
selection.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fakes.sim.arm_measurements import instrument_frame, measure, random_poses
from station.analysis.arm.identification import identify, rigid_fit
from station.analysis.arm.pose_selection import select_poses
from station.models import kinematics as kin
from station.models.robots import get_robot


def _perturbed(dh, rng):
    d = dh.copy()
    d[:, [0, 2]] += rng.normal(0.0, 0.5, (7, 2))
    d[:, [1, 3]] += np.radians(rng.normal(0.0, 0.1, (7, 2)))
    par = np.abs(np.sin(d[:5, 1])) < 0.1
    d[:5, 4][par] += np.radians(rng.normal(0.0, 0.05, par.sum()))
    return d


def _test_error(true, dh, q):
    pt, pm = kin.tool_position(true, q), kin.tool_position(dh, q)
    T = rigid_fit(pm, pt)
    return float(np.mean(np.linalg.norm(pm @ T[:3, :3].T + T[:3, 3] - pt, axis=1)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--robot", default="rb5-850")
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    nom = get_robot(args.robot)
    print(f"{args.robot}, {args.draws} draws, 1000 candidates, noise 0.03 mm; test error mean over 300 held-out "
          f"poses, mm (mean over draws / 90th percentile)")
    print(f"{'method':<9}{'N':>4}{'selected':>18}{'random':>18}{'less':>8}{'select ms':>11}")
    for method, sizes in (("absolute", (12, 16, 24, 48)), ("distance", (14, 18, 24, 48))):
        for n in sizes:
            e = {"sel": [], "rnd": []}
            t_sel = []
            for _ in range(args.draws):
                true = _perturbed(nom.dh_nominal, rng)
                cand = random_poses(nom.joint_limits_rad, 1000, rng)
                t0 = time.perf_counter()
                sel = select_poses(nom.dh_nominal, cand, n)
                t_sel.append(time.perf_counter() - t0)
                rnd = rng.choice(1000, n, replace=False)
                q_test = random_poses(nom.joint_limits_rad, 300, rng)
                B = instrument_frame(rng)
                for key, idx in (("sel", sel.indices), ("rnd", rnd)):
                    q = cand[idx]
                    res = identify(nom.dh_nominal, q, measure(true, q, B, 0.03, rng), method=method,
                                   allow_rank_deficient=True)
                    e[key].append(_test_error(true, res.dh, q_test))
            s, r = np.array(e["sel"]), np.array(e["rnd"])
            print(f"{method:<9}{n:>4}{s.mean():>10.4f} /{np.percentile(s, 90):>6.4f}"
                  f"{r.mean():>10.4f} /{np.percentile(r, 90):>6.4f}{100 * (1 - s.mean() / r.mean()):>7.0f}%"
                  f"{1e3 * np.median(t_sel):>11.0f}")


if __name__ == "__main__":
    main()
