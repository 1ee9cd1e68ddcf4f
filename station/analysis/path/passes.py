"""Where a stream follows a commanded path: each sample's arc length along it, and the cycles (passes).

:func:`project` gives every sample its arc length ``s`` along the path (the
foot of its normal plane) and its distance from the path. :func:`find_passes`
cuts the stream into forward passes from the first normal plane to the last:
samples must be valid, consecutive and within the path's tube; a pass that
starts and does not reach its last plane (the beam broke, the sample left the
tube, the robot turned back) is not a cycle and is reported with its reason.
A closed path (full circle, rectangle) is unwrapped: each turn is a cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.analysis.path.commanded import Arc, Line, Rectangle, Reorientation, Weaving


@dataclass(frozen=True)
class Pass:
    """One cycle: rows ``i0..i1`` (inclusive) of the stream and their arc lengths (this cycle's planes at theirs)."""

    cycle: int
    i0: int
    i1: int
    s_mm: np.ndarray

    @property
    def rows(self) -> slice:
        return slice(self.i0, self.i1 + 1)


@dataclass(frozen=True)
class Broken:
    """A pass that started and is no cycle: where, and why."""

    i0: int
    i1: int
    s_mm: float
    reason: str

    def to_dict(self) -> dict:
        return {"rows": [int(self.i0), int(self.i1)], "s_mm": round(float(self.s_mm), 3), "reason": self.reason}


def project(geometry, xyz_mm, abc_deg=None) -> tuple[np.ndarray, np.ndarray]:
    """``(s (N,), off (N,))``: arc length of each sample's foot on the path and its distance from it.

    For a :class:`Reorientation`, ``s`` is the angle turned (needs ``abc_deg``) and ``off`` the distance from
    the held point. A closed path gives ``s`` in [0, length).
    """
    p = np.asarray(xyz_mm, dtype=float)
    if isinstance(geometry, Reorientation):
        if abc_deg is None:
            from station.errors import DataError

            raise DataError("a reorientation path needs the stream's orientation (columns a, b, c)")
        return geometry.progress_deg(abc_deg), np.linalg.norm(p - geometry.point_mm, axis=1)
    if isinstance(geometry, (Line, Weaving)):
        line = geometry.base if isinstance(geometry, Weaving) else geometry
        t = line.tangent_at(0.0)[0]
        d = p - line.start_mm
        s = d @ t
        return s, np.linalg.norm(d - s[:, None] * t, axis=1)
    if isinstance(geometry, Arc):
        d = p - geometry.centre_mm
        x, y = d @ geometry._e1, d @ geometry._e2
        phi = np.arctan2(y, x) % (2 * np.pi)
        if not geometry.full:  # beyond the arc's end: nearer its start or its end
            phi = np.where(phi > 0.5 * (geometry._sweep + 2 * np.pi), phi - 2 * np.pi, phi)
        zc = d @ np.cross(geometry._e1, geometry._e2)
        off = np.hypot(np.hypot(x, y) - geometry.radius_mm, zc)
        return geometry.radius_mm * phi, off
    if isinstance(geometry, Rectangle):  # the nearest of the four edges
        c = np.asarray(geometry.corners_mm, dtype=float)
        best_off = np.full(p.shape[0], np.inf)
        s = np.zeros(p.shape[0])
        for k in range(4):  # loop over edges
            a, e = c[k], c[(k + 1) % 4] - c[k]
            Le = float(np.linalg.norm(e))
            q = np.clip((p - a) @ (e / Le), 0.0, Le)
            o = np.linalg.norm(p - a - q[:, None] * (e / Le), axis=1)
            better = o < best_off
            best_off[better] = o[better]
            s[better] = geometry.corner_s_mm[k] + q[better]
        return s % geometry.length_mm, best_off
    raise TypeError(f"unknown path geometry {type(geometry).__name__}")


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive ``(a, b)`` of each run of True."""
    d = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def _why_ended(b: int, valid, off, tube_mm, n: int) -> str:
    if b + 1 >= n:
        return "the stream ended"
    if not valid[b + 1]:
        j = b + 1
        while j < n and not valid[j]:
            j += 1
        return f"the beam broke (rows {b + 1}-{j - 1} flagged invalid)"
    return f"the samples left the path's tube ({off[b + 1]:.3f} mm > {tube_mm:g} mm)"


def find_passes(s, off, valid, *, length: float, closed: bool, s_lo: float, s_hi: float, tube_mm: float,
                in_window=None) -> tuple[list[Pass], list[Broken]]:
    """The forward passes from arc length ``s_lo`` to ``s_hi`` (the first and last planes), and the broken ones.

    ``s``, ``off`` (N,): from :func:`project`; ``valid`` (N,) bool; ``in_window`` (N,) bool or None: the rows
    that belong to this path. A pass runs from the sample before ``s`` first reaches ``s_lo`` to the first
    sample at or beyond ``s_hi``.
    """
    s = np.asarray(s, dtype=float)
    n = s.size
    ok = np.asarray(valid, bool) & np.isfinite(s) & (np.asarray(off) <= tube_mm)
    if in_window is not None:
        ok &= np.asarray(in_window, bool)
    passes: list[Pass] = []
    broken: list[Broken] = []
    for a, b in _runs(ok):  # loop over runs of good samples
        su = s[a:b + 1].copy()
        if closed:
            jumps = np.diff(su)
            su[1:] -= length * np.cumsum(np.round(jumps / length))
        pieces = [(0, su.size - 1)]
        if not closed:  # a new piece where the path is entered again from below s_lo
            below = su < s_lo
            starts = np.flatnonzero(below[:-1] & ~below[1:])
            cuts = sorted(set([0, *starts.tolist()]))
            pieces = [(c, (cuts[i + 1] if i + 1 < len(cuts) else su.size) - 1) for i, c in enumerate(cuts)]
        for pa, pb in pieces:  # loop over pieces
            seg = su[pa:pb + 1]
            mx = np.maximum.accumulate(seg)
            offsets = [0.0]
            if closed:
                k0 = int(np.floor((seg[0] - s_lo) / length)) + 1 if seg[0] > s_lo else 0
                k1 = int(np.floor((mx[-1] - s_lo) / length))
                offsets = [k * length for k in range(k0, k1 + 1)]
            for o in offsets:  # loop over the turns in this piece
                j_lo = int(np.searchsorted(mx, o + s_lo, side="left"))
                if j_lo == 0 or j_lo >= seg.size:
                    continue  # entered already beyond the first plane, or never reached it
                j_hi = int(np.searchsorted(mx, o + s_hi, side="left"))
                if j_hi >= seg.size:
                    end = a + pb
                    why = (_why_ended(end, valid, off, tube_mm, n) if pb == su.size - 1 else
                           f"the robot turned back at s = {mx[-1] - o:.2f} mm")
                    broken.append(Broken(a + pa + j_lo - 1, end, float(mx[-1] - o), why))
                    continue
                i0, i1 = a + pa + j_lo - 1, a + pa + j_hi
                passes.append(Pass(len(passes), i0, i1, su[pa + j_lo - 1:pa + j_hi + 1] - o))
    passes.sort(key=lambda p: p.i0)
    return [Pass(k, p.i0, p.i1, p.s_mm) for k, p in enumerate(passes)], broken


def crossings(xyz_mm, passes: list[Pass], plane_s) -> np.ndarray:
    """(K, m, 3): each pass's crossing of each normal plane (linear interpolation between the samples either
    side of the first reach of the plane's arc length)."""
    xyz = np.asarray(xyz_mm, dtype=float)
    sp = np.asarray(plane_s, dtype=float)
    out = np.full((len(passes), sp.size, 3), np.nan)
    for k, ps in enumerate(passes):  # loop over cycles
        mx = np.maximum.accumulate(ps.s_mm)
        j1 = np.clip(np.searchsorted(mx, sp, side="left"), 1, mx.size - 1)
        j0 = j1 - 1
        s0, s1 = ps.s_mm[j0], ps.s_mm[j1]
        w = np.clip(np.where(s1 > s0, (sp - s0) / np.where(s1 > s0, s1 - s0, 1.0), 0.0), 0.0, 1.0)
        p = xyz[ps.i0:ps.i1 + 1]
        out[k] = p[j0] + w[:, None] * (p[j1] - p[j0])
    return out
