"""Cornering round-off error CR and cornering overshoot CO (ISO 9283 clause 8.4) at a rectangle's corners.

At a corner point C between edge 1 (direction t1) and edge 2 (direction t2):

* CR_j = the least distance from C to the attained path of cycle j (the
  polyline through its samples, so the sampling does not add to it);
* CO_j = the largest deviation of the attained path, after the corner, from
  the commanded edge 2, outward (along n = t1 - (t1.t2) t2, normalised: the
  side the robot overshoots to), over the first half of edge 2; 0 when it
  stays inside. The positions are first smoothed by a short local quadratic
  (:data:`SMOOTH_S`) so the tracker's noise does not make the maximum.

CR and CO are the largest over the corners and cycles; each corner's values are
kept. The start corner (where a cycle starts and ends) is not one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import savgol_filter

from station.analysis.path.mc import DEFAULT_TRIALS, from_draws

#: time span of the local quadratic smoothing the positions for CO, s
SMOOTH_S = 0.01


@dataclass(frozen=True)
class CornerWindow:
    """One corner in one cycle: the samples around it (rows of the stream) and the corner's geometry."""

    corner: int
    cycle: int
    xyz_mm: np.ndarray  # (w, 3) samples from half edge 1 before to half edge 2 after
    point_mm: np.ndarray
    t1: np.ndarray
    t2: np.ndarray
    edge2_mm: float
    smooth: int = 5


@dataclass(frozen=True)
class Cornering:
    CR_mm: float
    CO_mm: float
    CR_jc_mm: np.ndarray  # (windows,)
    CO_jc_mm: np.ndarray
    #: largest error the sampling can make in each CR_j (the path between two samples is not seen), mm
    h_jc_mm: np.ndarray
    corners: list = field(default_factory=list)  # (corner, cycle) per window


def _polyline_distance(p, c):
    """Least distance from point c to the polyline through the rows of p (..., w, 3)."""
    a, b = p[..., :-1, :], p[..., 1:, :]
    ab = b - a
    w = np.clip(np.einsum("...k,...k->...", c - a, ab) / np.maximum(np.einsum("...k,...k->...", ab, ab), 1e-300),
                0.0, 1.0)
    return np.linalg.norm(a + w[..., None] * ab - c, axis=-1).min(axis=-1)


def _outward(p, win: CornerWindow):
    n = win.t1 - np.dot(win.t1, win.t2) * win.t2
    n /= np.linalg.norm(n)
    d = p - win.point_mm
    q = d @ win.t2
    out = d @ n
    after = (q > 0) & (q <= 0.5 * win.edge2_mm)
    return np.where(after, out, -np.inf).max(axis=-1).clip(min=0.0)


def _smooth(p, w: int):
    if p.shape[-2] < w:
        return p
    return savgol_filter(p, w, 2, axis=-2, mode="interp")


def cornering(windows: list[CornerWindow]) -> Cornering:
    cr = np.array([_polyline_distance(w.xyz_mm, w.point_mm) for w in windows])
    co = np.array([float(_outward(_smooth(w.xyz_mm, w.smooth), w)) for w in windows])
    h = np.array([_sampling_bound(w, c) for w, c in zip(windows, cr)])
    return Cornering(float(cr.max()), float(co.max()), cr, co, h, [(w.corner, w.cycle) for w in windows])


def _sampling_bound(w: CornerWindow, cr: float) -> float:
    """How far the polyline through the samples can pass from the path between them at the corner.

    Two samples d/2 either side of a sharp corner turning by phi: their chord passes (d/2) sin(phi/2) inside
    the corner; a path rounded with radius rho: d^2 / (8 rho), rho = CR / (1/cos(phi/2) - 1), when rho >= 2 d.
    """
    j = int(np.argmin(np.linalg.norm(w.xyz_mm - w.point_mm, axis=1)))
    seg = np.linalg.norm(np.diff(w.xyz_mm[max(j - 3, 0):j + 4], axis=0), axis=1)
    d = float(np.median(seg)) if seg.size else 0.0
    phi = float(np.arccos(np.clip(np.dot(w.t1, w.t2), -1.0, 1.0)))
    apex = 0.5 * d * np.sin(0.5 * phi)
    c = 1.0 / np.cos(0.5 * phi) - 1.0
    rho = cr / c if c > 1e-12 else np.inf
    if rho < 2.0 * d:  # the rounding is not resolved by the samples: the chord may cut the corner
        return float(apex)
    return float(min(apex, d * d / (8.0 * rho)))


def cornering_uncertainty(windows: list[CornerWindow], noise_sd_mm: float, res: Cornering, subject: str, *,
                          trials: int = DEFAULT_TRIALS, seed: int = 0, k: float = 2.0) -> dict:
    """u, U of CR and CO: each corner's samples re-measured with the instrument noise (3-D)."""
    rng = np.random.default_rng([seed, 44, 84])
    cr = np.empty((trials, len(windows)))
    co = np.empty((trials, len(windows)))
    for i, w in enumerate(windows):  # loop over corners x cycles
        j = int(np.argmin(np.linalg.norm(w.xyz_mm - w.point_mm, axis=1)))
        near = w.xyz_mm[max(j - 25, 0):j + 26]
        cr[:, i] = _polyline_distance(near[None] + rng.standard_normal((trials, *near.shape)) * noise_sd_mm,
                                      w.point_mm)
        q = (w.xyz_mm - w.point_mm) @ w.t2
        idx = np.flatnonzero((q > 0) & (q <= 0.5 * w.edge2_mm))
        if idx.size == 0:
            co[:, i] = 0.0
            continue
        a, b = max(idx[0] - w.smooth, 0), min(idx[-1] + w.smooth + 1, w.xyz_mm.shape[0])
        seg = w.xyz_mm[a:b]
        pert = _smooth(seg[None] + rng.standard_normal((trials, *seg.shape)) * noise_sd_mm, w.smooth)
        co[:, i] = _outward(pert, w)
    n = len(windows)
    h = {"sampling (the path between samples at the corner)": float(res.h_jc_mm[int(np.argmax(res.CR_jc_mm))])
         / np.sqrt(3.0)}
    return {"CR_mm": from_draws("CR_mm", subject, res.CR_mm, cr.max(axis=1), k=k, extra=h, n=n, seed=seed),
            "CO_mm": from_draws("CO_mm", subject, res.CO_mm, co.max(axis=1), k=k, n=n, seed=seed, debias=True,
                                note="corrected for the push of the tracker's noise on the maximum")}
