"""Benchmark: are the stated 1-sigma uncertainties of the arm identification honest?

Run by hand: ``.venv/bin/python bench/bench_arm_uncertainty.py [--draws 30]``. RB5-850 with seed
002 Table 3 as the truth, 64-100 random poses, 0.01-0.05 mm noise, the instrument anywhere; for a2,
a3, theta2, theta3 and beta2 the z-score (identified - true) / stated sigma is collected over the
draws for both methods. Honest uncertainties give an rms z near 1.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from fakes.sim.arm_measurements import instrument_frame, measure, random_poses
from station.analysis.arm.identification import identify
from station.models import kinematics as kin
from station.models.robots import get_robot

NAMES = ("a2", "a3", "theta2", "theta3", "beta2")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    nom, truth = get_robot("rb5-850"), get_robot("rb5-850-as-built").dh_nominal
    for method in ("distance", "absolute"):
        z = {n: [] for n in NAMES}
        for k in range(args.draws):
            rng = np.random.default_rng(args.seed + k)
            q = random_poses(nom.joint_limits_rad, int(rng.integers(64, 100)), rng)
            meas = measure(truth, q, instrument_frame(rng), float(rng.uniform(0.01, 0.05)), rng)
            res = identify(nom.dh_nominal, q, meas, method=method)
            for n in NAMES:
                i = kin.PARAM_NAMES.index(n)
                got, want = res.dh.ravel()[i], truth.ravel()[i]
                if n[0] in "tb":
                    got, want = math.degrees(got), math.degrees(want)
                z[n].append((got - want) / res.sigma[n])
        print(f"{method}: " + ", ".join(f"{n} rms z {np.sqrt(np.mean(np.square(v))):.2f} (max {np.max(np.abs(v)):.2f})"
                                        for n, v in z.items()))


if __name__ == "__main__":
    main()
