"""What a path's report plots, per cycle (pure): the deviation from the commanded path and the speed along it.

:func:`cycle_profiles` takes the stream and the cycles :func:`station.analysis.path.analysis.analyze_path` found
(its ``detail["cycle_rows"]``) and gives, per cycle, the arc length of each sample's foot on the commanded
path (ISO 9283 clause 8.2's normal planes, continuously), its distance from the path (mm) and the tool's speed
(mm/s, the analysis's own filter of clause 8.5, :func:`station.analysis.path.velocity.speed`). The speed is
left out (None) for a cycle whose clock does not advance regularly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.analysis.path.commanded import PathSpec, Reorientation
from station.analysis.path.passes import project
from station.analysis.path.velocity import speed

#: a cycle's sampling interval may wander this fraction from its median before its speed is left out
DT_TOLERANCE = 0.25


@dataclass(frozen=True)
class CycleProfile:
    cycle: int
    s_mm: np.ndarray  # arc length of each sample's foot on the commanded path
    deviation_mm: np.ndarray  # distance of each sample from the commanded path
    speed_mm_s: np.ndarray | None  # the tool's speed at each sample; None where the clock is irregular
    xyz_mm: np.ndarray  # the cycle's samples (n, 3)


def cycle_profiles(spec: PathSpec, t_s, xyz_mm, cycle_rows, noise_sd_mm: float = 0.0) -> list[CycleProfile]:
    """One :class:`CycleProfile` per ``(i0, i1)`` of ``cycle_rows`` (inclusive rows of ``t_s``, ``xyz_mm``)."""
    if isinstance(spec.geometry, Reorientation):
        raise ValueError(f"path {spec.name!r}: a reorientation has no position profile along it")
    t = np.asarray(t_s, dtype=float)
    xyz = np.asarray(xyz_mm, dtype=float)
    out = []
    for k, (i0, i1) in enumerate(cycle_rows, start=1):  # loop over cycles
        p, tt = xyz[i0:i1 + 1], t[i0:i1 + 1]
        s, off = project(spec.geometry, p)
        v = None
        if tt.size >= 5:
            dt = np.diff(tt)
            med = float(np.median(dt))
            if med > 0 and float(np.max(np.abs(dt - med))) <= DT_TOLERANCE * med:
                v = speed(p, med, noise_sd_mm)
        out.append(CycleProfile(k, s, off, v, p))
    return out


def plane_axes(commanded_mm, measured_mm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(origin, e1, e2)`` of the view of a path: the commanded points' mean and their plane (two principal
    directions); for a straight path, its direction and the measured points' main offset across it (the plane
    the deviation shows in)."""
    c = np.asarray(commanded_mm, dtype=float)
    origin = c.mean(axis=0)
    _, sv, vt = np.linalg.svd(c - origin, full_matrices=False)
    e1 = vt[0]
    if sv[1] > 1e-9 * sv[0]:
        return origin, e1, vt[1]
    d = np.asarray(measured_mm, dtype=float) - origin
    across = d - np.outer(d @ e1, e1)
    _, _, vt2 = np.linalg.svd(across, full_matrices=False)  # uncentred: the mean offset counts
    e2 = vt2[0] - (vt2[0] @ e1) * e1
    return origin, e1, e2 / np.linalg.norm(e2)
