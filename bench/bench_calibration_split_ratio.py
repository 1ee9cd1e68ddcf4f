"""Benchmark: how the calibration test's statistic spreads over seeds, by hand.

Run: ``.venv/bin/python bench/bench_calibration_split_ratio.py [--arm fanuc|rokae] [--poses N] [--seeds M]
[--first S] [--splits K]``.

``tests/calibration/test_real_pose_sets.py::test_random_splits_hold_out_as_well_as_a_plain_full_fit`` asks
that the calibration's held-out mean error, averaged over K random 70/30 splits (a new set every four),
be within 1.05x of a plain full DH + Hayati fit's on the same splits. This draws the test's sets for seeds
S .. S+M-1 (the test's own draw order) and prints, per seed, the ratio of the means and how the held-out
poses beyond the training range (sweep ends, where a fit extrapolates) fared; then the ratio's median,
largest values and the share of seeds above 1.05: the test's chance to fail with a calibration as good as
this one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.sim.real_like_arms import fanuc_like, rokae_like  # noqa: E402
from station.analysis.arm.calibration import calibrate_arm, split_poses  # noqa: E402
from tests.calibration.reference_fit import plain_fit, position_error  # noqa: E402

ARMS = {"fanuc": fanuc_like, "rokae": rokae_like}


def ratio_of_means(make, n: int, seed: int, splits: int) -> tuple[float, list[float], float, float]:
    """The test's statistic for one seed; the per-split ratios; mean errors on extrapolated poses (ours, ref)."""
    rng = np.random.default_rng(seed)
    ours, ref, out_ours, out_ref = [], [], [], []
    for k in range(splits):
        if k % 4 == 0:
            d = make(rng, n=n)
        sp = split_poses(n, 0.3, kind="random", seed=int(rng.integers(2 ** 31)))
        cal = calibrate_arm(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", split=sp)
        dh, B = plain_fit(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train])
        e_ours = cal.test.after_mm
        e_ref = position_error(dh, B, d.q_rad[sp.test], d.xyz_mm[sp.test])
        ours.append(e_ours.mean())
        ref.append(e_ref.mean())
        q_tr, q_te = d.q_rad[sp.train], d.q_rad[sp.test]
        margin = np.radians(2.0)
        outside = ((q_te < q_tr.min(axis=0) - margin) | (q_te > q_tr.max(axis=0) + margin)).any(axis=1)
        out_ours += list(e_ours[outside])
        out_ref += list(e_ref[outside])
    per_split = list(np.array(ours) / np.array(ref))
    return float(np.mean(ours) / np.mean(ref)), per_split, _mean(out_ours), _mean(out_ref)


def _mean(values: list) -> float:
    return float(np.mean(values)) if values else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", choices=sorted(ARMS), default="fanuc")
    ap.add_argument("--poses", type=int, default=36)
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--splits", type=int, default=16)
    a = ap.parse_args(argv)
    ratios = []
    for seed in range(a.first, a.first + a.seeds):
        r, per_split, o, f = ratio_of_means(ARMS[a.arm], a.poses, seed, a.splits)
        ratios.append(r)
        print(f"seed {seed}: ratio {r:.4f} (splits {min(per_split):.3f}-{max(per_split):.3f}); "
              f"extrapolated poses: ours {o:.3f} mm, plain fit {f:.3f} mm", flush=True)
    ratios = np.array(ratios)
    top = ", ".join(f"{v:.4f}" for v in np.sort(ratios)[::-1][:3])
    print(f"{a.arm} {a.poses} poses, {a.splits} splits, {len(ratios)} seeds: median {np.median(ratios):.4f}, "
          f"largest {top}; above 1.05: {int((ratios > 1.05).sum())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
