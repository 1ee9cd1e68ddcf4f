"""Benchmark: is geometry named on real-shaped sets, and is the written model as good as a plain fit? (issue 43)

Run by hand: ``.venv/bin/python bench/bench_diagnosis_geometry.py [--reps R] [--sets S] [--splits K] [--seed N]``.

Cases (fakes/sim/real_like_arms.py): the FANUC-like one-joint sweeps (36
poses) as drawn by default (2-3 mm nominal error, 0.05-0.15 mm noise) and
as the public FANUC set measured in issue 43 (about 1.3 mm nominal error,
0.2 mm noise per reflector); the ROKAE-like spread poses, 30 and 50. One
replicate is what the acceptance test does: S sets, K random 70/30 splits
each; the diagnosis sees the 70 %, the extended model it writes predicts
the 30 %, against a plain full DH + Hayati least-squares fit (scipy MINPACK)
of the same 70 %. Per case: the share of diagnoses that name geometry, the
share whose written model fell back to the calibration alone, and the
replicates' ratio of mean errors (median, 95th percentile, largest).

The seed is printed; the same seed gives the same figures.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.sim.real_like_arms import fanuc_like, rokae_like  # noqa: E402
from station.analysis.arm.calibration import split_poses  # noqa: E402
from station.analysis.diagnose import diagnose_arm  # noqa: E402
from station.models.arm_extended import ExtendedArm, motion_directions, terms_from_json  # noqa: E402
from station.models.arm_model_file import model_from_json  # noqa: E402
from tests.calibration.reference_fit import plain_fit, position_error  # noqa: E402

CASES = {
    "fanuc36": (fanuc_like, 36, {}),
    "fanuc36-issue": (fanuc_like, 36, {"noise_mm": 0.2, "nominal_mm": (1.1, 1.5)}),
    "rokae30": (rokae_like, 30, {}),
    "rokae50": (rokae_like, 50, {}),
}


def written_error(res, d, test) -> float:
    doc = res.extended_model(joint_limits_rad=d.joint_limits_rad)
    dh_e, B_e, _ = model_from_json(doc)
    arm = ExtendedArm("x", dh_e, B_e, d.joint_limits_rad, terms_from_json(doc["effects"], "m"))
    p = arm.predict(d.q_rad[test], last_dir=motion_directions(d.q_rad)[test], t_s=d.t_s[test])
    return float(np.linalg.norm(p - d.xyz_mm[test], axis=1).mean())


def replicate(make, n, kw, rng, sets, splits):
    ext, ref, named, fell_back, runs = [], [], 0, 0, 0
    for _ in range(sets):
        d = make(rng, n=n, **kw)
        for _ in range(splits):
            sp = split_poses(n, 0.3, kind="random", seed=int(rng.integers(2 ** 31)))
            res = diagnose_arm(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train], t_s=d.t_s[sp.train])
            dh, B = plain_fit(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train])
            ext.append(written_error(res, d, sp.test))
            ref.append(float(position_error(dh, B, d.q_rad[sp.test], d.xyz_mm[sp.test]).mean()))
            named += ("geometric", None) in res.selected
            fell_back += res.written.get("effects_written") is False
            runs += 1
    return float(np.mean(ext)), float(np.mean(ref)), named, fell_back, runs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--sets", type=int, default=2)
    ap.add_argument("--splits", type=int, default=3)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--seed", type=int, default=None)
    args = ap.parse_args()
    seed = int(np.random.SeedSequence().entropy % (2 ** 31)) if args.seed is None else args.seed
    print(f"seed {seed}; {args.reps} replicates of {args.sets} sets x {args.splits} random 70/30 splits per case")
    print(f"{'case':<15}{'geo named':>10}{'fallback':>9}{'ext mm':>8}{'plain mm':>9}{'ratio med':>10}"
          f"{'p95':>7}{'max':>7}{'s':>6}")
    for name in args.cases.split(","):
        make, n, kw = CASES[name]
        rng = np.random.default_rng([seed, sorted(CASES).index(name)])
        t0 = time.perf_counter()
        ratios, e_all, r_all, named, fb, runs = [], [], [], 0, 0, 0
        for _ in range(args.reps):
            e, r, nm, f, k = replicate(make, n, kw, rng, args.sets, args.splits)
            ratios.append(e / r)
            e_all.append(e)
            r_all.append(r)
            named, fb, runs = named + nm, fb + f, runs + k
        print(f"{name:<15}{named / runs:>10.3f}{fb / runs:>9.3f}{np.mean(e_all):>8.4f}{np.mean(r_all):>9.4f}"
              f"{np.median(ratios):>10.3f}{np.quantile(ratios, 0.95):>7.3f}{max(ratios):>7.3f}"
              f"{time.perf_counter() - t0:>6.0f}", flush=True)


if __name__ == "__main__":
    main()
