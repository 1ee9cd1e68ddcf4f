"""Cornering round-off error CR and cornering overshoot CO (ISO 9283 clause 8.4) at a rectangle's corners.

At a corner point C between edge 1 (direction t1) and edge 2 (direction t2):

* CR_j = the least distance from C to the attained path of cycle j (the
  polyline through its samples, so the sampling does not add to it);
* CO_j = the largest deviation of the attained path, after the corner, from
  the commanded edge 2, outward (along n = t1 - (t1.t2) t2, normalised: the
  side the robot overshoots to), over the first half of edge 2; 0 when it
  stays inside. The samples are not smoothed (a local fit across a rounded
  corner bends the path outward): the push of the tracker's noise on the
  maximum is taken back by simulation-extrapolation
  (:func:`~station.analysis.path.mc.from_draws`).

CR and CO are the largest over the corners and cycles; each corner's values are
kept. The start corner (where a cycle starts and ends) is not one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.analysis.path.mc import DEFAULT_TRIALS, from_draws
from station.analysis.path.noise import PathNoise
from station.errors import DataError

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
    t_s: np.ndarray | None = None  # (w,) the samples' times (a wander is drawn along them)


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


def cornering(windows: list[CornerWindow]) -> Cornering:
    cr = np.array([_polyline_distance(w.xyz_mm, w.point_mm) for w in windows])
    co = np.array([float(_outward(w.xyz_mm, w)) for w in windows])
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


def cornering_uncertainty(windows: list[CornerWindow], noise_sd_mm, res: Cornering, subject: str, *,
                          trials: int = DEFAULT_TRIALS, seed: int = 0, k: float = 2.0) -> dict:
    """u, U of CR and CO: each corner's samples re-measured with the instrument noise (3-D), once and twice.

    ``noise_sd_mm``: a white sd or a :class:`~station.analysis.path.noise.PathNoise` (white and a wander, drawn
    along the windows' sample times ``t_s``, which a wander needs). Only what can make the largest
    is drawn: the corners within 8 noise sd of the largest CR_j (CO_j), and for CO the samples within 8 sd of
    each one's largest outward deviation.
    """
    pn = PathNoise.of(noise_sd_mm)
    rng = np.random.default_rng([seed, 44, 84])
    reach = 8.0 * pn.total_mm
    pick_cr = np.flatnonzero(res.CR_jc_mm >= res.CR_mm - reach - res.h_jc_mm.max())
    pick_co = np.flatnonzero(res.CO_jc_mm >= res.CO_mm - reach)
    cr = np.full((2, trials, pick_cr.size), -np.inf)
    co = np.zeros((2, trials, pick_co.size))

    if pn.has_wander and any(w.t_s is None for w in windows):
        raise DataError("a noise with a wander needs the corner windows' sample times (t_s)")

    def twice(shape, t):
        d = pn.draw(rng, (2, trials), np.zeros(shape[0]) if t is None else t, shape[1])
        d[1] += d[0]  # twice the noise: the first draw plus a fresh one
        return d

    for c, i in enumerate(pick_cr):  # loop over candidate corners
        w = windows[i]
        j = int(np.argmin(np.linalg.norm(w.xyz_mm - w.point_mm, axis=1)))
        near = w.xyz_mm[max(j - 25, 0):j + 26]
        tn = None if w.t_s is None else w.t_s[max(j - 25, 0):j + 26]
        cr[:, :, c] = _polyline_distance(near[None, None] + twice(near.shape, tn), w.point_mm)
    for c, i in enumerate(pick_co):  # loop over candidate corners
        w = windows[i]
        n = w.t1 - np.dot(w.t1, w.t2) * w.t2
        q = (w.xyz_mm - w.point_mm) @ w.t2
        out = np.where((q > 0) & (q <= 0.5 * w.edge2_mm), (w.xyz_mm - w.point_mm) @ (n / np.linalg.norm(n)),
                       -np.inf)
        idx = np.flatnonzero(out >= out.max() - reach)
        if idx.size == 0:
            continue
        seg = w.xyz_mm[idx]
        co[:, :, c] = _outward(seg[None, None] + twice(seg.shape, None if w.t_s is None else w.t_s[idx]), w)
    n = len(windows)
    h = {"sampling (the path between samples at the corner)": float(res.h_jc_mm[int(np.argmax(res.CR_jc_mm))])
         / np.sqrt(3.0)}
    crd, cod = cr.max(axis=2), co.max(axis=2) if pick_co.size else np.zeros((2, trials))
    return {"CR_mm": from_draws("CR_mm", subject, res.CR_mm, crd[0], k=k, extra=h, n=n, seed=seed),
            "CO_mm": from_draws("CO_mm", subject, res.CO_mm, cod[0], k=k, n=n, seed=seed, draws2=cod[1],
                                extrapolate="sd")}
