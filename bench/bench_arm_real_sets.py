"""Benchmark: calibration and diagnosis on real-looking arm sets (issue 22), by hand.

Run: ``.venv/bin/python bench/bench_arm_real_sets.py [--sets N] [--splits K] [--seed S]``.

Cases (fakes/sim/real_like_arms.py): a FANUC-like arm, 36 poses moved one
joint at a time (J6 sweep last), three reflectors; ROKAE-like arms, 30 and
50 spread poses, a 6-DoF target; 2-3 mm nominal error, 0.05-0.15 mm noise,
0-2 hidden joint effects drawn at random. Each set is split K times at
random 70/30. Per case:

* calibration (absolute): held-out mean error against a plain full DH +
  Hayati least-squares fit (scipy MINPACK, every parameter free) on the same
  split: the ratio of the means over all splits, and its worst set;
* diagnosis trained on the 70 %: the extended model it writes, predicting
  the 30 % (nested: it never saw them), against geometry alone (the
  calibration on the same 70 %); miss rate (hidden effects not named, per
  hidden effect) and false-discovery rate (splits naming an effect that was
  not hidden).

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
from station.analysis.arm.calibration import calibrate_arm, split_poses  # noqa: E402
from station.analysis.diagnose import diagnose_arm  # noqa: E402
from station.models.arm_extended import ExtendedArm, motion_directions, terms_from_json  # noqa: E402
from station.models.arm_model_file import model_from_json  # noqa: E402
from tests.calibration.reference_fit import plain_fit, position_error  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sets", type=int, default=10)
    ap.add_argument("--splits", type=int, default=4)
    ap.add_argument("--seed", type=int, default=None)
    args = ap.parse_args()
    seed = int(np.random.SeedSequence().entropy % (2 ** 31)) if args.seed is None else args.seed
    print(f"seed {seed}, {args.sets} sets x {args.splits} random 70/30 splits per case")
    rng = np.random.default_rng(seed)
    print(f"{'case':<14}{'calib/plain':>12}{'worst set':>10}{'ext mm':>9}{'geo mm':>9}{'ext/geo':>8}"
          f"{'miss':>7}{'FDR':>7}{'named geo':>10}{'s/diag':>8}")
    for make, n in ((fanuc_like, 36), (rokae_like, 30), (rokae_like, 50)):
        ours, ref, per_set, ext, geo = [], [], [], [], []
        hidden_n = missed = fd = named_geo = runs = 0
        t_diag = 0.0
        for _ in range(args.sets):
            d = make(rng, n=n)
            o_set, r_set = [], []
            for _ in range(args.splits):
                sp = split_poses(n, 0.3, kind="random", seed=int(rng.integers(2 ** 31)))
                cal = calibrate_arm(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", split=sp, alternative=False)
                dh, B = plain_fit(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train])
                o_set.append(cal.test.after_mm.mean())
                r_set.append(position_error(dh, B, d.q_rad[sp.test], d.xyz_mm[sp.test]).mean())
                t0 = time.perf_counter()
                res = diagnose_arm(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train], t_s=d.t_s[sp.train])
                t_diag += time.perf_counter() - t0
                doc = res.extended_model(joint_limits_rad=d.joint_limits_rad)
                dh_e, B_e, _ = model_from_json(doc)
                arm = ExtendedArm("x", dh_e, B_e, d.joint_limits_rad, terms_from_json(doc["effects"], "m"))
                p = arm.predict(d.q_rad[sp.test], last_dir=motion_directions(d.q_rad)[sp.test], t_s=d.t_s[sp.test])
                ext.append(np.linalg.norm(p - d.xyz_mm[sp.test], axis=1).mean())
                geo.append(cal.test.after_mm.mean())
                sel = [s for s in res.selected if s != ("geometric", None)]
                named_geo += ("geometric", None) in res.selected
                hidden_n += len(d.hidden)
                missed += sum(1 for h in d.hidden if h not in sel)
                fd += any(s not in d.hidden for s in sel)
                runs += 1
            ours += o_set
            ref += r_set
            per_set.append(np.mean(o_set) / np.mean(r_set))
        print(f"{make.__name__ + str(n):<14}{np.mean(ours) / np.mean(ref):>12.3f}{max(per_set):>10.3f}"
              f"{np.mean(ext):>9.4f}{np.mean(geo):>9.4f}{np.mean(ext) / np.mean(geo):>8.3f}"
              f"{(missed / hidden_n if hidden_n else float('nan')):>7.2f}{fd / runs:>7.2f}"
              f"{named_geo / runs:>10.2f}{t_diag / runs:>8.2f}")


if __name__ == "__main__":
    main()
