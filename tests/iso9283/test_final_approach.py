"""Approach direction from the final stretch of a move (vAP, seed 000 sec. 3.3).

A robot that passes the pre-point of an ISO 9283 multi-directional approach
with a fine stop but no dwell makes one deceleration phase of two moves; the
direction it came in along is the last stretch, not the chord from where the
merged move started.
"""

import numpy as np

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.extraction import extract_attained_poses


def _leg(a, b, v_mm_s, rate_hz):
    """Straight move a -> b with a cosine speed profile (at rest at both ends)."""
    d = np.linalg.norm(b - a)
    T = max(2 * d / v_mm_s, 0.05)
    s = 0.5 - 0.5 * np.cos(np.pi * np.arange(1, int(T * rate_hz) + 1) / (T * rate_hz))
    return a + s[:, None] * (b - a)


def _stream(poses, dirs, cycles, rng, rate_hz=100.0, sigma=0.01, scatter=0.02):
    pts = [np.repeat(poses[0][None] + np.array([0, 0, -200.0]), 50, axis=0)]
    cur = pts[0][-1]
    truth = []
    for _ in range(cycles):
        for d in dirs:
            for p in poses:
                pre = p - 100.0 * d
                target = p + rng.normal(0, scatter, 3)
                pts += [_leg(cur, pre, 1500.0, rate_hz), _leg(pre, target, 800.0, rate_hz),
                        np.repeat(target[None], int(0.5 * rate_hz), axis=0)]
                cur = target
                truth.append(d)
    xyz = np.vstack(pts)
    xyz = xyz + rng.normal(0, sigma, xyz.shape)
    t = np.arange(len(xyz)) / rate_hz
    return t, xyz, np.array(truth)


def test_merged_pre_point_moves_give_the_final_approach_direction(rng):
    poses = np.array([[0.0, 1700, 1400], [-500, 2200, 1900], [500, 1200, 900]])
    dirs = np.eye(3) * np.array([1.0, 1.0, -1.0])[:, None]  # +x, +y, -z
    cycles = 4
    t, xyz, truth = _stream(poses, dirs, cycles, rng)
    ex = extract_attained_poses(t, xyz, poses, names=["P1", "P2", "P4"],
                                order=["P1", "P2", "P4"])
    at_pose = ex.stops.pose >= 0
    units = ex.stops.approach_unit[at_pose]
    assert units.shape[0] == truth.shape[0]
    # each final approach is along its commanded direction (within a few degrees)
    cosines = np.einsum("ij,ij->i", units, truth)
    assert np.all(cosines > np.cos(np.radians(3.0))), np.degrees(np.arccos(cosines.min()))
    # the chord from where the merged move started would not be: check the test can fail
    chord = ex.stops.position_mm[at_pose] - xyz[ex.stops.i_move_start[at_pose]]
    chord /= np.linalg.norm(chord, axis=1)[:, None]
    assert np.min(np.einsum("ij,ij->i", chord, truth)) < np.cos(np.radians(10.0))

    res = analyze_iso9283(t, xyz, poses, names=["P1", "P2", "P4"], order=["P1", "P2", "P4"])
    for name in ("P1", "P2", "P4"):
        md = res.poses[name].multidirectional
        assert md.n_directions == 3 and md.vAP_mm is not None
