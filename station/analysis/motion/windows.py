"""A stream cut into moves and their approach windows, along the travel (no model fitted here).

The moves between rests come from :func:`station.analysis.iso9283.motion_clock.find_moves`
(in rows); each rest is matched to the nearest commanded pose. For every move:

1. the deceleration phase (after the peak speed, below :data:`DECEL_SPEED_FRACTION`
   of it, more than :data:`PROJECT_MM` from the rest) is fitted by a parabola in
   time: its curvature gives the deceleration ``a`` (mm/s^2) and its vertex the
   time ``T*`` the command ends (first estimates the diagnosis refines);
2. the window runs from :data:`T_CRUISE_S` before the deceleration set in
   (``T* - v / a``, ``v`` the cruise speed; not before the peak speed) to
   ``T* + t_post``; ``t_post`` is :data:`T_POST_S` or less, so that
   a *late dwell* of at least :data:`LATE_MIN_S` remains before the arm
   leaves again (:data:`LEAVE_MARGIN_S` before the last row inside the rest);
3. the end point ``p_end`` is the mean of the late dwell, the reading's drift
   rate along the travel its least-squares slope (the creep has died out by
   then: ``exp(-T_POST_S / 0.15 s)``);
4. the position along the travel is ``x = -|p - p_end|`` (``+`` past the end) further than
   :data:`PROJECT_MM` from the end and ``(p - p_end) . u`` within it, ``u``
   the direction of arrival (from the sample :data:`DIRECTION_MM` out to
   ``p_end``): a joint move's curved path is measured by its chord far out,
   where lateral noise does not matter, and by its tangent near the end,
   where the sign (overshoot) does.

Windows are stacked in arrays ``(moves, samples)`` padded with NaN. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import DataError, InsufficientDataError

#: the deceleration phase: speed below this fraction of the move's peak, from the last sample above it on (a loop
#: that rings after the acceleration's end lifts the peak and dips below the fraction during the cruise: test seed
#: 288640465, a loop of 8.7 Hz, damping 0.21, peak 246 mm/s at a cruise of 211, a dip to 197 took the whole cruise
#: into the deceleration's parabola and put the command's end past the next move's start)
DECEL_SPEED_FRACTION = 0.8
#: chord beyond which the position along the travel is the chord, mm
PROJECT_MM = 1.0
#: the direction of arrival is taken from the sample this far out, mm
DIRECTION_MM = 3.0
#: the window starts this long before the deceleration sets in (at the cruise, after the peak speed), s
T_CRUISE_S = 0.1
#: ... and ends this long after it, s (at most)
T_POST_S = 1.0
#: shortest window after the command's end a move needs to be used, s
MIN_POST_S = 0.25
#: shortest late dwell (after the window, before leaving), s
LATE_MIN_S = 0.2
#: the late dwell ends this long before the last row inside the rest, s
LEAVE_MARGIN_S = 0.15
#: a rest further than this from every commanded pose is not one of the program's, mm
POSE_MATCH_MM = 5.0
#: fewest samples of the deceleration parabola
MIN_DECEL_SAMPLES = 8


@dataclass
class Windows:
    """The approach windows of the usable moves (``M`` moves, ``L`` samples at most)."""

    t_s: np.ndarray          # (M, L) sample times, NaN padded
    x_mm: np.ndarray         # (M, L) position along the travel, target at 0, NaN padded
    a0_mm_s2: np.ndarray     # (M,) deceleration of the parabola
    T0_s: np.ndarray         # (M,) the command's end by the parabola's vertex
    v_mm_s: np.ndarray       # (M,) peak speed before the deceleration
    D_mm: np.ndarray         # (M,) the move's length (rest to rest)
    t_leave_s: np.ndarray    # (M,) the last sample inside the start rest
    drift_mm_s: np.ndarray   # (M,) the late dwell's slope along the travel
    t_late_s: np.ndarray     # (M,) mean time of the late dwell
    late_s: np.ndarray       # (M,) duration of the late dwell
    drift_change_mm_s2: np.ndarray  # (M,) change of the drift rate since the previous move's late dwell
    p_end_mm: np.ndarray     # (M, 3)
    u: np.ndarray            # (M, 3) direction of arrival
    from_pose: list
    to_pose: list
    move_index: np.ndarray   # (M,) index of the move in the stream's moves
    skipped: list            # (move index, reason) of moves not used
    noise_mm: float          # noise per axis per sample (white part)
    rate_hz: float

    @property
    def n(self) -> int:
        return int(self.t_s.shape[0])

    def select(self, idx) -> "Windows":
        idx = np.asarray(idx, dtype=int)
        pick = lambda v: [v[i] for i in idx]  # noqa: E731
        return Windows(self.t_s[idx], self.x_mm[idx], self.a0_mm_s2[idx], self.T0_s[idx], self.v_mm_s[idx], self.D_mm[idx], self.t_leave_s[idx],
                       self.drift_mm_s[idx], self.t_late_s[idx], self.late_s[idx], self.drift_change_mm_s2[idx], self.p_end_mm[idx], self.u[idx],
                       pick(self.from_pose), pick(self.to_pose), self.move_index[idx], self.skipped, self.noise_mm,
                       self.rate_hz)


def _decel_fit(t, d):
    """Parabola ``-d = c0 + c1 t + c2 t^2``: ``(a, T*)`` or None."""
    tc = t - t.mean()
    A = np.stack([np.ones_like(tc), tc, tc * tc], axis=1)
    c, *_ = np.linalg.lstsq(A, -d, rcond=None)
    if not c[2] < 0:
        return None
    return float(-2.0 * c[2]), float(t.mean() - c[1] / (2.0 * c[2]))


def _match_poses(centres, poses_mm, names):
    out = []
    for k, c in enumerate(centres):
        dist = np.linalg.norm(poses_mm - c, axis=1)
        j = int(np.argmin(dist))
        if dist[j] > POSE_MATCH_MM:
            raise DataError(f"the stream rests at {np.round(c, 3).tolist()} mm, {dist[j]:.1f} mm from the nearest "
                            f"pose of the poses file ({names[j]}); more than {POSE_MATCH_MM:g} mm: another frame, "
                            "another program?")
        out.append(names[j])
    return out


def _rows_between(t, lo: float, hi: float, ok, ascending: bool) -> np.ndarray:
    """The rows with ``lo <= t <= hi`` and ``ok``, ascending; by bisection when ``t`` is sorted (a scan of the
    whole stream per move made the cutting quadratic: an hour at 1 kHz has a thousand moves)."""
    if not ascending:
        return np.flatnonzero((t >= lo) & (t <= hi) & ok)
    rows = np.arange(np.searchsorted(t, lo, side="left"), np.searchsorted(t, hi, side="right"))
    return rows[ok[rows]]


def cut_windows(t_s, xyz_mm, poses_mm, names, valid=None) -> Windows:
    """The approach windows of a stream (see the module's docstring)."""
    from station.analysis.iso9283.motion_clock import find_moves

    t = np.asarray(t_s, dtype=float)
    xyz = np.asarray(xyz_mm, dtype=float)
    ok = np.ones(t.size, bool) if valid is None else np.asarray(valid, bool)
    ok &= np.all(np.isfinite(xyz), axis=1)
    mv = find_moves(xyz, ok)
    if mv.leave_row.size == 0:
        raise InsufficientDataError("the stream holds no move between two rests")
    rate = 1.0 / float(np.median(np.diff(t)))
    pose_of = _match_poses(mv.centres_mm, np.asarray(poses_mm, dtype=float), list(names))
    ascending = bool(np.all(t[1:] >= t[:-1]))  # False with a NaN time
    rows_t, rows_x, info, skipped = [], [], [], []
    n = t.size
    for k in range(mv.leave_row.size):
        i0, i1 = int(mv.leave_row[k]), int(mv.arrive_row[k])
        nxt = int(mv.leave_row[k + 1]) if k + 1 < mv.leave_row.size else n - 1
        c = mv.centres_mm[mv.to_rest[k]]
        seg = np.arange(i0, i1 + 1)
        seg = seg[ok[seg]]
        if seg.size < MIN_DECEL_SAMPLES + 2:
            skipped.append((k, "too few samples in the move"))
            continue
        d = np.linalg.norm(xyz[seg] - c, axis=1)
        sp = np.abs(np.gradient(d, t[seg]))
        ipk = int(np.argmax(sp))
        last_fast = int(np.flatnonzero(sp > DECEL_SPEED_FRACTION * sp[ipk])[-1])  # ipk or after it
        sel = np.flatnonzero((np.arange(seg.size) > last_fast) & (d > PROJECT_MM))
        if sel.size < MIN_DECEL_SAMPLES:
            skipped.append((k, "no deceleration phase to fit (too few samples beyond 1 mm from the rest)"))
            continue
        sel = np.arange(sel[0], sel[-1] + 1)
        fit = _decel_fit(t[seg[sel]], d[sel])
        if fit is None:
            skipped.append((k, "the approach does not decelerate"))
            continue
        a0, T0 = fit
        t_out = t[nxt] - LEAVE_MARGIN_S
        post = min(T_POST_S, t_out - LATE_MIN_S - T0)
        if post < MIN_POST_S:
            skipped.append((k, f"the dwell is too short: {max(t_out + LEAVE_MARGIN_S - T0, 0):.2f} s after the "
                               f"command's end, the diagnosis needs {MIN_POST_S + LATE_MIN_S + LEAVE_MARGIN_S:.2f} s"))
            continue
        # the cruise speed (the median of the samples within 10 % of the peak: a ringing mode lifts the peak)
        # and where the deceleration set in, had it no jerk limit
        v_pk = float(np.median(sp[sp >= 0.9 * sp[ipk]]))
        t_start = max(T0 - v_pk / a0 - T_CRUISE_S, float(t[seg[ipk]]))
        late = _rows_between(t, T0 + post, t_out, ok, ascending)
        if late.size < 5:
            skipped.append((k, "too few valid samples in the late dwell"))
            continue
        p_end = xyz[late].mean(axis=0)
        w = _rows_between(t, t_start, T0 + post, ok, ascending)
        d_w = np.linalg.norm(xyz[w] - p_end, axis=1)
        out = np.flatnonzero((d_w >= DIRECTION_MM) & (t[w] < T0))
        if not out.size:
            skipped.append((k, f"the window holds no sample {DIRECTION_MM:g} mm from the rest"))
            continue
        u = p_end - xyz[w[out[-1]]]
        u /= np.linalg.norm(u)
        along = (xyz[w] - p_end) @ u
        x = np.where(d_w > PROJECT_MM, np.where(along > 0.0, d_w, -d_w), along)  # past the end: an overshoot
        tl = t[late]
        tm = tl.mean()
        # the late dwell's drift velocity (3-D: the previous rest's is compared with it, whatever the directions)
        slope3 = (tl - tm) @ (xyz[late] - p_end) / max(float(np.sum((tl - tm) ** 2)), 1e-30)
        slope = float(slope3 @ u)
        rows_t.append(t[w])
        rows_x.append(x)
        info.append((a0, T0, float(t[i0]), slope, float(tm), p_end, u, pose_of[mv.from_rest[k]],
                     pose_of[mv.to_rest[k]], k, float(tl[-1] - tl[0]), v_pk,
                     float(np.linalg.norm(c - mv.centres_mm[mv.from_rest[k]])), slope3))
    if not info:
        why = "; ".join(f"move {k + 1}: {r}" for k, r in skipped[:3])
        raise InsufficientDataError(f"no move of the stream can be diagnosed ({why})")
    L = max(r.size for r in rows_t)
    T = np.full((len(info), L), np.nan)
    X = np.full((len(info), L), np.nan)
    for j, (tt, xx) in enumerate(zip(rows_t, rows_x)):
        T[j, :tt.size], X[j, :xx.size] = tt, xx
    col = lambda i: np.array([row[i] for row in info])  # noqa: E731
    # the reading's drift is the tracker's, the same at every pose: the drift velocity measured at the previous
    # rest (the move before, when it was usable) and at this one give its change over the move, taken along this
    # move's travel (the two velocities as vectors: the previous move ran along another direction)
    change = np.zeros(len(info))
    k_of = {int(r[9]): j for j, r in enumerate(info)}
    for j, r in enumerate(info):
        prev = k_of.get(int(r[9]) - 1)
        if prev is not None and r[4] > info[prev][4]:
            change[j] = float((r[13] - info[prev][13]) @ r[6]) / (r[4] - info[prev][4])
    return Windows(T, X, col(0), col(1), col(11), col(12), col(2), col(3), col(4), col(10), change, np.array([r[5] for r in info]),
                   np.array([r[6] for r in info]), [r[7] for r in info], [r[8] for r in info],
                   col(9).astype(int), skipped, mv.noise_mm / math.sqrt(3.0), rate)


def decimated(w: Windows, max_rate_hz: float) -> Windows:
    """The windows with every k-th sample, k the least that brings the rate to ``max_rate_hz`` or below (for fits)."""
    k = max(1, int(math.ceil(w.rate_hz / max_rate_hz - 1e-9)))
    if k == 1:
        return w
    return Windows(w.t_s[:, ::k], w.x_mm[:, ::k], w.a0_mm_s2, w.T0_s, w.v_mm_s, w.D_mm, w.t_leave_s, w.drift_mm_s, w.t_late_s, w.late_s, w.drift_change_mm_s2,
                   w.p_end_mm, w.u, w.from_pose, w.to_pose, w.move_index, w.skipped, w.noise_mm, w.rate_hz / k)
