"""A controller's path interpolator: straight and circular segments, corner zones, a speed profile.

What a robot controller does with a run of Cartesian moves that blend into
each other (RAPID zones, KRL ``C_DIS``, URScript ``r``): it lays the segments
end to end, rounds every corner whose move has a zone by a curve that leaves
the path ``zone`` before the corner and joins it ``zone`` after it (a
quadratic Bezier with the corner as its control point: on a 90 degree corner
it passes ``zone / (2 sqrt 2)`` from the corner), limits the speed where the
path bends (lateral acceleration at most the path acceleration) and plans one
jerk-limited speed profile over the whole run: from rest, at each move's programmed speed,
to rest at the last (fine) target. The interpolator's own timing ripple (a
small periodic modulation of the path speed, a servo and drive property)
rides on the cruise.

:func:`plan_path` returns the interpolation knots (time, pose) that the
controller hands to its axes, and :func:`solve_knots` their joint angles by
IK of the controller's (nominal) model, slowed uniformly where an axis would
exceed its speed or acceleration limit. Pure functions; lengths mm, times s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from station.errors import DataError
from station.models import kinematics as kin

__all__ = ["Segment", "PathPlan", "Ripple", "circle_through", "arc_points", "plan_path", "solve_knots"]

#: spacing of the dense path the interpolator works on, mm
STEP_MM = 0.25
#: junctions whose tangents turn less than this are passed without rounding, rad
TANGENT_TOL_RAD = math.radians(0.5)
#: time step of the speed profile, s
TIME_STEP_S = 0.001
#: spacing of the IK anchor points solved one after another (they seed the knots), mm
ANCHOR_MM = 40.0


@dataclass(frozen=True)
class Segment:
    """One move of a run: to ``end_pose`` (4x4, mm) along a line, or an arc through ``via_mm``.

    ``speed_mm_s`` is the programmed path speed, ``zone_mm`` the corner zone at
    its end (0: the run stops there; only the last segment of a run may stop).
    """

    end_pose: np.ndarray
    speed_mm_s: float
    zone_mm: float = 0.0
    via_mm: np.ndarray | None = None


@dataclass(frozen=True)
class Ripple:
    """The interpolator's speed ripple: ``v (1 + amplitude sin(2 pi frequency_Hz t + phase_rad))``."""

    amplitude: float = 0.0
    frequency_Hz: float = 1.0
    phase_rad: float = 0.0


@dataclass
class PathPlan:
    """Interpolation knots of a run.

    Attributes
    ----------
    t_knots : ndarray (K + 1,)
        Knot times from the run's start, s.
    poses : ndarray (K + 1, 4, 4)
        Commanded TCP poses at the knots (nominal model), mm.
    s_knots : ndarray (K + 1,)
        Arc length at the knots, mm.
    length_mm : float
    segment_ends_s : ndarray
        Arc length where each segment's own target is passed (or reached), mm.
    """

    t_knots: np.ndarray
    poses: np.ndarray
    s_knots: np.ndarray
    length_mm: float
    segment_ends_s: np.ndarray


def circle_through(p0, p1, p2) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Centre, radius and the in-plane unit axes (u towards p0, w = n x u) of the circle through three points."""
    p0, p1, p2 = (np.asarray(p, float) for p in (p0, p1, p2))
    a, b = p1 - p0, p2 - p0
    n = np.cross(a, b)
    nn = float(n @ n)
    if nn < 1e-12 * max(float(a @ a) * float(b @ b), 1e-30):
        raise DataError(f"arc points {p0.tolist()}, {p1.tolist()}, {p2.tolist()} are on one line: no circle")
    c = p0 + (np.cross(n, a) * float(b @ b) + np.cross(b, n) * float(a @ a)) / (2.0 * nn)
    r = float(np.linalg.norm(p0 - c))
    u = (p0 - c) / r
    w = np.cross(n / math.sqrt(nn), u)
    return c, r, u, w


def _angle(c, u, w, p) -> float:
    d = np.asarray(p, float) - c
    return math.atan2(float(d @ w), float(d @ u)) % (2 * math.pi)


def _sweep(c, u, w, via, p1) -> float:
    """Signed angle from the start (along ``u``) to ``p1`` the way that passes ``via``, rad."""
    a_via, a_end = _angle(c, u, w, via), _angle(c, u, w, p1)
    if a_end == 0.0:
        a_end = 2 * math.pi
    return a_end if a_via <= a_end else a_end - 2 * math.pi  # the other way round passes the via point


def arc_points(p0, via, p1, n: int) -> np.ndarray:
    """``n`` points from ``p0`` through ``via`` to ``p1`` on their circle (the sweep that passes ``via``)."""
    c, r, u, w = circle_through(p0, via, p1)
    ang = np.linspace(0.0, _sweep(c, u, w, via, p1), n)
    return c + r * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w)


def _dense(p0, seg: Segment) -> np.ndarray:
    p1 = np.asarray(seg.end_pose, float)[:3, 3]
    if seg.via_mm is None:
        n = max(int(math.ceil(np.linalg.norm(p1 - p0) / STEP_MM)), 1) + 1
        return p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)
    c, r, u, w = circle_through(p0, seg.via_mm, p1)
    length = abs(_sweep(c, u, w, seg.via_mm, p1)) * r
    return arc_points(p0, seg.via_mm, p1, max(int(math.ceil(length / STEP_MM)), 2) + 1)


def _cum(pts: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])


def _at(pts: np.ndarray, cum: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Point and unit tangent at arc length ``s`` of a dense polyline."""
    i = int(np.clip(np.searchsorted(cum, s) - 1, 0, len(pts) - 2))
    d = pts[i + 1] - pts[i]
    L = float(np.linalg.norm(d))
    f = (s - cum[i]) / L if L > 0 else 0.0
    return pts[i] + f * d, d / L


def _blend(pts_a, pts_b, r_mm):
    """Cut ``r`` off the end of ``a`` and the start of ``b`` and join them by a Bezier round the corner."""
    ca, cb = _cum(pts_a), _cum(pts_b)
    r = min(r_mm, 0.5 * ca[-1], 0.5 * cb[-1])
    _, ta = _at(pts_a, ca, ca[-1])
    _, tb = _at(pts_b, cb, 0.0)
    if r <= 0 or math.acos(float(np.clip(ta @ tb, -1.0, 1.0))) < TANGENT_TOL_RAD:
        return pts_a, pts_b, None
    A, _ = _at(pts_a, ca, ca[-1] - r)
    B, _ = _at(pts_b, cb, r)
    C = pts_a[-1]
    n = max(int(math.ceil(2 * r / STEP_MM)), 4) + 1
    u = np.linspace(0.0, 1.0, n)[:, None]
    curve = (1 - u) ** 2 * A + 2 * u * (1 - u) * C + u ** 2 * B
    a_keep = pts_a[ca < ca[-1] - r]
    b_keep = pts_b[cb > r]
    return np.concatenate([a_keep, curve]), b_keep, r


def _speed_limit(pts: np.ndarray, cum: np.ndarray, v_prog: np.ndarray, a: float) -> np.ndarray:
    """Programmed speed, capped where the path bends so the lateral acceleration stays within ``a``."""
    k = np.zeros(len(pts))
    if len(pts) >= 3:
        d1 = pts[1:-1] - pts[:-2]
        d2 = pts[2:] - pts[1:-1]
        l1, l2 = np.linalg.norm(d1, axis=1), np.linalg.norm(d2, axis=1)
        ok = (l1 > 1e-9) & (l2 > 1e-9)
        cosang = np.where(ok, np.einsum("ij,ij->i", d1, d2) / np.maximum(l1 * l2, 1e-18), 1.0)
        turn = np.arccos(np.clip(cosang, -1.0, 1.0))
        k[1:-1] = np.where(ok, turn / np.maximum(0.5 * (l1 + l2), 1e-9), 0.0)
        k = np.maximum.reduce([k, np.roll(k, 1), np.roll(k, -1)])  # a little margin either side of a kink
    return np.minimum(v_prog, np.sqrt(a / np.maximum(k, 1e-12)))


def _profile(cum: np.ndarray, vmax: np.ndarray, a: float) -> np.ndarray:
    """Speed along the path: at most ``vmax``, |dv/dt| <= a, from rest to rest (forward and backward passes)."""
    v = vmax.copy()
    v[0] = v[-1] = 0.0
    ds = np.diff(cum)
    for i in range(1, len(v)):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * a * ds[i - 1]))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * a * ds[i]))
    return v


def _times(cum: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Time at each point of a rest-to-rest profile (trapezoid rule on 1/v, exact on the ramps)."""
    ds = np.diff(cum)
    vm = v[:-1] + v[1:]
    dt = np.where(vm > 0, 2.0 * ds / np.maximum(vm, 1e-12), 0.0)
    return np.concatenate([[0.0], np.cumsum(dt)])


def plan_path(start_pose, segments: list[Segment], *, accel_mm_s2: float, ipo_period_s: float = 0.02,
              jerk_time_s: float = 0.1, ripple: Ripple | None = None) -> PathPlan:
    """Interpolation knots of a run of blended segments from ``start_pose`` (4x4, mm).

    Parameters
    ----------
    start_pose : (4, 4)
    segments : list of Segment
        The moves of the run; every zone but the last one's rounds its corner.
    accel_mm_s2 : float
        Path acceleration (also the lateral limit where the path bends).
    ipo_period_s : float
        Knot spacing, s.
    jerk_time_s : float
        Time over which the acceleration ramps up (the profile's jerk limit).
    ripple : Ripple, optional
        Speed ripple of the interpolator (none by default).
    """
    if not segments:
        raise DataError("a path needs at least one segment")
    if not (math.isfinite(accel_mm_s2) and accel_mm_s2 > 0):
        raise DataError(f"accel_mm_s2 must be > 0, got {accel_mm_s2!r}")
    T0 = np.asarray(start_pose, float)
    pieces, p = [], T0[:3, 3]
    for seg in segments:
        pieces.append(_dense(p, seg))
        p = np.asarray(seg.end_pose, float)[:3, 3]
    if not any(_cum(piece)[-1] > 0.0 for piece in pieces):
        raise DataError("a run of blended moves that does not move the tool point has no path to blend: turn the "
                        "tool about its held point with fine stops")
    # corners: each piece keeps its own points up to where the next blend starts
    out, seg_of = [], []
    cur = pieces[0]
    for j in range(len(segments)):
        if j + 1 < len(segments):
            cur, nxt, _ = _blend(cur, pieces[j + 1], segments[j].zone_mm)
        else:
            nxt = None
        if out:
            cur = cur[1:] if np.allclose(cur[0], out[-1][-1]) else cur
        out.append(cur)
        seg_of.append(np.full(len(cur), j))
        cur = nxt
    pts = np.concatenate(out)
    owner = np.concatenate(seg_of)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts, owner = pts[keep], owner[keep]
    cum = _cum(pts)
    L = float(cum[-1])
    ends = np.array([cum[owner == j][-1] if np.any(owner == j) else L for j in range(len(segments))])
    v_prog = np.array([segments[j].speed_mm_s for j in owner], float)
    vmax = _speed_limit(pts, cum, v_prog, accel_mm_s2)
    for j, seg in enumerate(segments[:-1]):
        if seg.zone_mm == 0 and np.any(owner == j):  # a fine point inside the run: stop there
            vmax[np.flatnonzero(owner == j)[-1]] = 0.0
    v = _profile(cum, vmax, accel_mm_s2)
    t = _times(cum, v)
    # the speed in time on a fine grid, its ramps smoothed over the jerk time (a moving mean turns the
    # trapezoid into an S-curve with the same peak acceleration), the ripple on it; s(t) its integral
    dt = TIME_STEP_S
    tg = np.arange(0.0, float(t[-1]) + dt, dt)
    vg = np.interp(np.interp(tg, t, cum), cum, v)
    n_box = max(int(round(jerk_time_s / dt)), 1)
    vg = np.convolve(np.concatenate([vg, np.zeros(n_box)]), np.ones(n_box) / n_box)[: vg.size + n_box]
    tg = np.arange(vg.size) * dt
    if ripple is not None and ripple.amplitude:
        vg = vg * (1.0 + ripple.amplitude * np.sin(2 * math.pi * ripple.frequency_Hz * tg + ripple.phase_rad))
    sg = np.concatenate([[0.0], np.cumsum(0.5 * (vg[1:] + vg[:-1]) * dt)])
    sg *= L / sg[-1]
    T = float(tg[-1])
    n_k = max(int(math.ceil(T / ipo_period_s)), 2)
    t_k = np.linspace(0.0, T, n_k + 1)
    s_k = np.interp(t_k, tg, sg)
    s_k[0], s_k[-1] = 0.0, L
    xyz = np.stack([np.interp(s_k, cum, pts[:, i]) for i in range(3)], axis=1)
    # orientation: slerped along each segment's arc length from the previous target's to its own
    rots = Rotation.from_matrix(np.stack([T0[:3, :3]] + [np.asarray(s.end_pose, float)[:3, :3] for s in segments]))
    s_nodes = np.concatenate([[0.0], ends])
    s_nodes = np.maximum.accumulate(s_nodes + np.arange(len(s_nodes)) * 1e-9)
    R = Slerp(s_nodes, rots)(np.clip(s_k, s_nodes[0], s_nodes[-1]))
    poses = np.repeat(np.eye(4)[None], len(t_k), axis=0)
    poses[:, :3, :3] = R.as_matrix()
    poses[:, :3, 3] = xyz
    poses[0] = T0
    poses[-1, :3, 3] = np.asarray(segments[-1].end_pose, float)[:3, 3]
    return PathPlan(t_k, poses, s_k, L, ends)


def solve_knots(dh, q_start, plan: PathPlan, joint_limits_rad, joint_speed_limits_rad_s, joint_accel_limits_rad_s2,
                *, tol_mm: float = 1e-5) -> tuple[np.ndarray, np.ndarray, float]:
    """Knot times, joint angles at the knots (nominal IK on the branch of ``q_start``) and the largest
    ratio of an axis's acceleration to its limit before any slowing down; the times are slowed uniformly
    until no axis exceeds its limits. Raises DataError naming where the path is unreachable."""
    from station.models.motion import spline_trajectory

    lim = np.asarray(joint_limits_rad, float)
    q0 = np.asarray(q_start, float)
    # anchors every ANCHOR_MM, each seeded from the one before: the branch is followed, not guessed
    n_a = max(int(math.ceil(plan.length_mm / ANCHOR_MM)), 1)
    s_a = np.linspace(0.0, plan.length_mm, n_a + 1)
    idx = np.clip(np.searchsorted(plan.s_knots, s_a), 0, len(plan.s_knots) - 1)
    idx[0] = 0
    idx = np.unique(idx)
    q_a = [q0]
    for i in idx[1:]:
        r = kin.ik(dh, plan.poses[i][None], q_a[-1][None], lim, tol_mm=tol_mm, n_restarts=0)
        if not r.all_success:
            raise DataError(f"path leaves the reachable space at {np.round(plan.poses[i, :3, 3], 3).tolist()} mm "
                            f"(IK residual {float(r.residual_mm[0]):.3g} mm)")
        q_a.append(r.q_rad[0])
    q_a = np.array(q_a)
    seeds = np.stack([np.interp(plan.s_knots, plan.s_knots[idx], q_a[:, j]) for j in range(6)], axis=1)
    sol = kin.ik(dh, plan.poses[1:], seeds[1:], lim, tol_mm=tol_mm, n_restarts=0)
    if not sol.all_success:
        bad = int(np.nonzero(~sol.success)[0][0]) + 1
        raise DataError(f"path leaves the reachable space at {np.round(plan.poses[bad, :3, 3], 3).tolist()} mm "
                        f"(knot {bad} of {len(plan.t_knots) - 1})")
    q_k = np.concatenate([q0[None], sol.q_rad])
    jumps = np.max(np.abs(np.diff(q_k, axis=0)), axis=0)
    if np.any(jumps > 0.5):
        j = int(np.argmax(jumps))
        raise DataError(f"path crosses a singularity or a branch change: joint {j + 1} jumps "
                        f"{math.degrees(float(jumps[j])):.1f} deg between two knots")
    t_k = plan.t_knots
    traj = spline_trajectory(t_k, q_k)
    t_chk = np.linspace(0.0, traj.duration_s, 4 * len(t_k) + 1)
    v_ratio = float(np.max(np.abs(traj.evaluate(t_chk, 1)) / np.asarray(joint_speed_limits_rad_s, float)))
    a_ratio = float(np.max(np.abs(traj.evaluate(t_chk, 2)) / np.asarray(joint_accel_limits_rad_s2, float)))
    k = max(1.0, v_ratio, math.sqrt(a_ratio))
    return (t_k * k * (1.0 + 1e-9) if k > 1.0 else t_k), q_k, a_ratio
