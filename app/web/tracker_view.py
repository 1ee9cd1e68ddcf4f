"""The live plot's numbers: the tracker's last seconds, from the samples the run has committed.

Pure: arrays in, a JSON-able dict out. Speed is the norm of the position's
finite differences over device time; the distance is to the nearest commanded
pose of the plan (base frame, through the run's registration
``x_tracker = R x_base + t``, as :meth:`Registration.to_base` inverts it;
none before the registration). Counters: samples received in the
step, samples the tracker flagged (status != 0), and gaps (device-time steps
longer than 1.5 nominal periods, the median step).
"""

from __future__ import annotations

import numpy as np

#: plotted points at most (the page draws polylines; more is invisible)
MAX_POINTS = 300


def tracker_window(t_s: np.ndarray, xyz_mm: np.ndarray, status: np.ndarray, *, window_s: float = 5.0,
                   poses_mm: np.ndarray | None = None, R: np.ndarray | None = None,
                   t_mm: np.ndarray | None = None) -> dict:
    """The last ``window_s`` seconds of one step's samples, decimated to at most MAX_POINTS.

    Parameters
    ----------
    t_s : (N,) device time, s; xyz_mm : (N, 3) tracker frame, mm; status : (N,) device status
    poses_mm : (P, 3) commanded poses, robot base frame, mm; R (3, 3), t_mm (3,): the registration, base -> tracker
    """
    t = np.asarray(t_s, dtype=float).ravel()
    xyz = np.asarray(xyz_mm, dtype=float).reshape(-1, 3)
    st = np.asarray(status).ravel()
    if not (len(t) == len(xyz) == len(st)):
        raise ValueError("t_s, xyz_mm and status must have the same length")
    out = {"n": int(len(t)), "flagged": int(np.count_nonzero(st)), "gaps": 0, "t": [], "speed_mm_s": [],
           "dist_mm": None, "rate_hz": None}
    if len(t) < 3:
        return out
    order = np.argsort(t, kind="stable")
    t, xyz = t[order], xyz[order]
    dt = np.diff(t)
    period = float(np.median(dt))
    if period > 0:
        out["gaps"] = int(np.count_nonzero(dt > 1.5 * period))
        out["rate_hz"] = 1.0 / period
    keep = t >= t[-1] - window_s
    t, xyz = t[keep], xyz[keep]
    if len(t) < 3:
        return out
    speed = np.linalg.norm(np.diff(xyz, axis=0), axis=1) / np.maximum(np.diff(t), 1e-9)
    tm = 0.5 * (t[1:] + t[:-1])
    dist = None
    if poses_mm is not None and R is not None and t_mm is not None and len(poses_mm):
        base = (xyz - np.asarray(t_mm, dtype=float)) @ np.asarray(R, dtype=float)
        d = np.linalg.norm(base[:, None, :] - np.asarray(poses_mm, dtype=float)[None, :, :], axis=2).min(axis=1)
        dist = 0.5 * (d[1:] + d[:-1])
    bins = min(MAX_POINTS, len(tm))
    edges = np.linspace(0, len(tm), bins + 1).astype(int)
    mean = lambda a: np.add.reduceat(a, edges[:-1]) / np.diff(edges)  # noqa: E731
    out["t"] = (mean(tm) - t[-1]).round(4).tolist()
    out["speed_mm_s"] = mean(speed).round(3).tolist()
    if dist is not None:
        out["dist_mm"] = mean(dist).round(4).tolist()
    return out
