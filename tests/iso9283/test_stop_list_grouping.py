"""Stops grouped by pose in one pass (issue 47 item 10): the same groups, scatter and per-pose stops as the scan of
every stop per pose it replaces (that scan took K x P steps: 100,000 poses over a minute)."""

from __future__ import annotations

import math

import numpy as np

from station.analysis.iso9283.lab_files import stop_scatter_mm
from station.analysis.iso9283.stop_list import analyze_stop_list, rows_by_label


def _random_list(rng):
    """Poses with 1-4 stops each, in shuffled order, a few stops far from their pose."""
    n_poses = int(rng.integers(5, 60))
    names = [f"P{int(i)}" for i in rng.permutation(10 * n_poses)[:n_poses]]
    cmd = rng.uniform(-1000.0, 1000.0, (n_poses, 3))
    pose, cycle, pts = [], [], []
    for i, name in enumerate(names):
        for c in range(int(rng.integers(1, 5))):
            pose.append(name)
            cycle.append(c + 1)
            pts.append(cmd[i] + rng.normal(0.0, 0.05, 3) + (rng.random() < 0.05) * 100.0)
    order = rng.permutation(len(pose))
    return names, cmd, [pose[k] for k in order], np.array(cycle)[order], np.array(pts)[order]


def test_rows_by_label_equals_a_scan_per_label(rng):
    for _ in range(20):
        labels = [f"L{int(x)}" for x in rng.integers(0, int(rng.integers(1, 40)), int(rng.integers(1, 300)))]
        arr = np.array(labels, dtype=object)
        want = {lab: np.flatnonzero(arr == lab) for lab in dict.fromkeys(labels)}
        got = rows_by_label(labels)
        assert list(got) == list(want)  # first appearance order
        for lab in want:
            assert np.array_equal(got[lab], want[lab])


def test_stop_scatter_equals_the_scan_per_pose(rng):
    for _ in range(10):
        _, _, pose, _, pts = _random_list(rng)
        arr = np.array(pose, dtype=object)
        dev = dof = 0
        for p in set(pose):
            m = arr == p
            if m.sum() >= 2:
                dev += float(np.sum((pts[m] - pts[m].mean(axis=0)) ** 2))
                dof += 3 * (int(m.sum()) - 1)
        assert math.isclose(stop_scatter_mm(pts, pose), math.sqrt(dev / dof) if dof else 0.0, rel_tol=1e-12)


def test_each_pose_gets_the_stops_the_scan_gave(rng):
    for _ in range(5):
        names, cmd, pose, cycle, pts = _random_list(rng)
        res = analyze_stop_list(pose, cycle, pts[:, None, :], commanded_mm=cmd, names=names, distance_pairs=None)
        arr = np.array(pose, dtype=object)
        far = np.linalg.norm(pts - cmd[[names.index(p) for p in pose]], axis=1) > res.assign_tol_mm
        assert np.array_equal(res.stop_far, far)
        for name in names:
            k = np.flatnonzero((arr == name) & ~far)
            k = k[np.argsort(cycle[k], kind="stable")]
            pr = res.poses[name]
            assert np.array_equal(pr.attained_row, k) and np.array_equal(pr.attained_cycle, cycle[k])
            assert np.allclose(pr.attained_mm, pts[k])
            if k.size:
                ap_mm = float(np.linalg.norm(pts[k].mean(axis=0) - cmd[names.index(name)]))
                assert math.isclose(pr.accuracy.AP_mm, ap_mm, rel_tol=1e-9, abs_tol=1e-12)
