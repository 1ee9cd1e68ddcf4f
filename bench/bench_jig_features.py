"""Benchmark: the jig's feature point by the seed's algorithm and by the station's.

Run by hand: ``.venv/bin/python bench/bench_jig_features.py [--quick] [--seed N]``.

(a) Seed 002 Table 1 in its own form: a fixed scanner, the jig at 4 poses,
    10 repeated scans each; per pose and algorithm the mean x, y, z, their
    difference to the reference (the true corner), the position accuracy
    (length of that difference) and the standard deviation (ddof = 1) per
    axis, in mm in the scanner frame.
(b) Sweeps over the scanner's noise, the outlier rate and occlusion (an
    object in front of the corner, or in front of half a face): mean and
    largest error of both over random poses, clouds where an algorithm
    found no corner, and for the station's fit the mean ``e^T C^-1 e / 3``
    (1 when its reported uncertainty is right).
(c) Time per cloud at about 200k points (and at the scanner's default
    density, about 10k), best and median of several runs.

Figures go to stdout; nothing is asserted.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np
from scipy.spatial.transform import Rotation

from fakes.sim.scanner import SimScanner, look_at
from station.analysis.arm.jig_features import feature_point
from station.analysis.arm.jig_features_seed import seed_feature_point
from station.errors import InsufficientDataError
from station.models.jig import CornerJig

ALGORITHMS = ("seed", "station")


def _find(name, points, rng):
    if name == "seed":
        return seed_feature_point(points, rng)
    return feature_point(points)


def _corner_pose(corner_mm, rng, tilt_deg=15.0):
    """Tool pose in the scanner frame: corner at ``corner_mm``, tool axis towards the eye, tilted at random."""
    z = -np.asarray(corner_mm) / np.linalg.norm(corner_mm)  # tool +z points at the scanner
    R = look_at(np.zeros(3), z)[:3, :3]
    tilt = Rotation.from_rotvec(np.radians(tilt_deg) * rng.normal(size=3) / math.sqrt(3)).as_matrix()
    T = np.eye(4)
    T[:3, :3] = tilt @ R @ Rotation.from_euler("z", rng.uniform(-180, 180), degrees=True).as_matrix()
    T[:3, 3] = corner_mm
    return T


def _scene(rng, *, occluder=None, **kw):
    """A scanner at the origin (identity base frame) and the jig at a random pose 600-800 mm away."""
    corner = np.array([rng.uniform(-120, 120), rng.uniform(-120, 120), rng.uniform(600, 800)])
    T = _corner_pose(corner, rng)
    jig = CornerJig(edge_mm=60.0)
    occluders = ()
    if occluder is not None:
        geo = jig.in_frame(T)
        if occluder == "corner":
            target, radius = geo["feature_point_mm"], 12.0
        else:
            target, radius = geo["triangles_mm"][rng.integers(3)].mean(axis=0), 15.0
        f = rng.uniform(0.8, 0.9)
        occluders = ((f * target, f * radius),)
    scanner = SimScanner(np.eye(4), jig, occluders=occluders, **kw)
    return scanner, T


# ------------------------------------------------------------------ (a)


def table1(rng, repeats: int) -> None:
    print("(a) seed 002 Table 1 form: 4 poses x %d scans, scanner noise 0.02 mm, 1 %% outliers, mm" % repeats)
    scanner = SimScanner(np.eye(4), CornerJig(edge_mm=60.0))
    corners = [(-75.0, 45.0, 660.0), (105.0, 45.0, 690.0), (135.0, -15.0, 750.0), (-95.0, 20.0, 595.0)]
    poses = [_corner_pose(np.array(c), rng) for c in corners]
    summary = {a: [] for a in ALGORITHMS}
    for p, T in enumerate(poses, start=1):
        scans = [scanner.render(T, rng) for _ in range(repeats)]
        ref = scans[0].feature_point_mm
        print(f"\n  P{p}  reference  x {ref[0]:10.4f}  y {ref[1]:10.4f}  z {ref[2]:10.4f}   ({scans[0].points_mm.shape[0]} points)")
        for a in ALGORITHMS:
            pts = np.array([_find(a, s.points_mm, rng).point_mm for s in scans])
            mean = pts.mean(axis=0)
            diff = mean - ref
            std = pts.std(axis=0, ddof=1)
            acc = float(np.linalg.norm(diff))
            summary[a].append((acc, std))
            print(f"  {a:8s} average    x {mean[0]:10.4f}  y {mean[1]:10.4f}  z {mean[2]:10.4f}")
            print(f"  {'':8s} error      x {diff[0]:10.5f}  y {diff[1]:10.5f}  z {diff[2]:10.5f}   position accuracy {acc:.5f}")
            print(f"  {'':8s} std dev    x {std[0]:10.5f}  y {std[1]:10.5f}  z {std[2]:10.5f}")
    print("\n  over the 4 poses       position accuracy (mm)      standard deviation per axis (mm)")
    for a in ALGORITHMS:
        acc = np.array([s[0] for s in summary[a]])
        std = np.array([s[1] for s in summary[a]])
        print(f"  {a:8s}               {acc.min():.5f} .. {acc.max():.5f}          {std.min():.5f} .. {std.max():.5f}")
    print("  seed 002 Table 1 (real scanner)  0.025 .. 0.095             0.030 .. 0.090")


# ------------------------------------------------------------------ (b)


def _sweep_row(label, rng, n, **kw):
    errs = {a: [] for a in ALGORITHMS}
    fails = {a: 0 for a in ALGORITHMS}
    chi2 = []
    for _ in range(n):
        scanner, T = _scene(rng, **kw)
        scan = scanner.render(T, rng)
        for a in ALGORITHMS:
            try:
                res = _find(a, scan.points_mm, rng)
            except InsufficientDataError:
                fails[a] += 1
                continue
            e = res.point_mm - scan.feature_point_mm
            errs[a].append(float(np.linalg.norm(e)))
            if a == "station":
                chi2.append(float(e @ np.linalg.solve(res.covariance_mm2, e)))
    cells = []
    for a in ALGORITHMS:
        x = np.array(errs[a]) * 1e3
        cells.append(f"{x.mean():9.2f} {x.max():9.2f} {fails[a]:3d}" if x.size else f"{'-':>9s} {'-':>9s} {fails[a]:3d}")
    calib = f"{np.mean(chi2) / 3:6.2f}" if chi2 else "     -"
    print(f"  {label:24s} {cells[0]}   {cells[1]}   {calib}")


def sweeps(rng, n: int) -> None:
    print(f"\n(b) sweeps, {n} random poses each; errors in um (mean, max), failures; chi2/3 of the station's sigma")
    head = f"  {'':24s} {'seed mean':>9s} {'max':>9s} {'no':>3s}   {'stn mean':>9s} {'max':>9s} {'no':>3s}   chi2/3"
    print(head)
    for sigma in (0.005, 0.01, 0.02, 0.05, 0.1):
        _sweep_row(f"noise {sigma:g} mm", rng, n, noise_sigma_mm=sigma, outlier_fraction=0.01)
    for rate in (0.0, 0.05, 0.1, 0.2, 0.3):
        _sweep_row(f"outliers {100 * rate:g} %", rng, n, outlier_fraction=rate)
    for occ, label in ((None, "no occlusion"), ("corner", "corner occluded"), ("face", "half a face occluded")):
        _sweep_row(label, rng, n, occluder=occ)
    _sweep_row("corner occl. + 10 % outl.", rng, n, occluder="corner", outlier_fraction=0.1)


# ------------------------------------------------------------------ (c)


def timing(rng, repeats: int) -> None:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"\n(c) time per cloud, best and median of {repeats} runs (ms); load average {load:.2f} on {os.cpu_count()} CPUs")
    for density, label in ((1.0, "default density"), (64.0, "dense")):
        scanner, T = _scene(rng, density_per_mm2=density)
        pts = scanner.render(T, rng).points_mm
        row = []
        for a in ALGORITHMS:
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                _find(a, pts, rng)
                times.append(time.perf_counter() - t0)
            row.append(f"{a} {1e3 * min(times):7.1f} / {1e3 * float(np.median(times)):7.1f}")
        print(f"  {label:16s} {pts.shape[0]:7d} points   " + "   ".join(row))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer scans, poses and runs")
    ap.add_argument("--seed", type=int, default=2, help="random seed of poses and scans (default 2)")
    ap.add_argument("--part", default="abc", help="which parts to run: any of a, b, c (default abc)")
    args = ap.parse_args(argv)
    if not set(args.part) <= set("abc") or not args.part:
        ap.error(f"--part takes letters from 'abc', got {args.part!r}")
    rng = np.random.default_rng(args.seed)
    if "a" in args.part:
        table1(rng, repeats=10)
    if "b" in args.part:
        sweeps(rng, n=5 if args.quick else 30)
    if "c" in args.part:
        timing(rng, repeats=3 if args.quick else 15)


if __name__ == "__main__":
    main()
