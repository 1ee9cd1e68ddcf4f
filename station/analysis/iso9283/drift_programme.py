"""The drift programme of ISO 9283 (drift of pose characteristics over a span from a cold start).

The pose test's AP (seed 000 eq. (1)) and RP (eq. (2)) are measured at every
visit ``v`` of a long programme (e.g. every 10 minutes over 8 h, the arm
started cold), each visit being a few pose cycles. ISO 9283 states the drift
of each pose characteristic as the difference between its value at the first
visit and at the last::

    dAP = | AP(t_1) - AP(t_n) |        dRP = | RP(t_1) - RP(t_n) |

with AP and RP of each visit by eqs. (1) and (2); with a 6-DoF target the
orientation's the same way per angle (ISO 9283 drift of pose characteristics
for the orientation)::

    dAPa = | APa(t_1) - APa(t_n) |     dRPa = | RPa(t_1) - RPa(t_n) |   (so b, c)

with APa the mean of the stops' angle a less the commanded one and RPa = 3 S_a
(:mod:`station.analysis.iso9283.orientation`). Beside them this module
gives AP(t) and RP(t) of every visit with their expanded uncertainty, and the
shift, the distance between the first and the last visit's barycentres (the
arm's own displacement, of which dAP sees only the part along the pose's
error).

Pure functions: the attained positions of each visit in, figures out
(:func:`drift_figures`); the stream analysis that finds the attained positions
is :func:`station.analysis.iso9283.characteristics.analyze_iso9283`, the
uncertainties are :func:`station.analysis.uncertainty.pose_uncertainty` and
:func:`~station.analysis.uncertainty.drift_uncertainty` (the frame's error
common to the two visits).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from station.analysis.iso9283.characteristics import OrientationAR, _wrap
from station.analysis.iso9283.uncertainty import orientation_uncertainty
from station.analysis.uncertainty import Budget, angle_drift_uncertainty, drift_uncertainty, pose_uncertainty
from station.errors import DataError, InsufficientDataError
from station.numeric import finite_or_none

__all__ = ["VisitPose", "PoseDrift", "visit_pose", "pose_drift", "drift_figures"]


@dataclass(frozen=True)
class VisitPose:
    """AP and RP of one pose at one visit (mm), with U (k = 2; None where too few stops)."""

    visit: int
    pose: str
    t_since_start_s: float  # mean time of the visit's attained stops at the pose since the programme's start
    attained_mm: np.ndarray  # (n, 3), base frame
    AP_mm: float
    RP_mm: float | None
    U_AP_mm: float | None
    U_RP_mm: float | None
    #: (n, 3) the stops' angles a, b, c less the commanded ones, deg (a 6-DoF target; else None)
    angles_deg: np.ndarray | None = None
    #: ``{"APa_deg": ..., "RPa_deg": ..., "U_APa_deg": ..., ...}`` of the angles (None without them)
    orientation: dict | None = None

    @property
    def n(self) -> int:
        return int(self.attained_mm.shape[0])

    def to_dict(self) -> dict:
        r = finite_or_none
        return {"visit": self.visit, "pose": self.pose, "t_since_start_s": round(self.t_since_start_s, 3),
                "n": self.n, "AP_mm": r(self.AP_mm, 6), "U_AP_mm": r(self.U_AP_mm, 6), "RP_mm": r(self.RP_mm, 6),
                "U_RP_mm": r(self.U_RP_mm, 6),
                "barycentre_mm": [round(float(v), 6) for v in self.attained_mm.mean(axis=0)],
                **{k: r(v, 7) for k, v in (self.orientation or {}).items()}}


@dataclass(frozen=True)
class PoseDrift:
    """dAP and dRP of one pose between its first and its last visit (mm), U with k = 2."""

    pose: str
    first_visit: int
    last_visit: int
    span_s: float  # time between the two visits
    dAP_mm: float
    dRP_mm: float | None
    U_dAP_mm: float | None
    U_dRP_mm: float | None
    shift_mm: float  # distance between the two visits' barycentres
    #: ``{"dAPa_deg": ..., "dRPa_deg": ..., "U_dAPa_deg": ..., ...}`` of a 6-DoF target's angles (else None)
    orientation: dict | None = None

    def to_dict(self) -> dict:
        r = finite_or_none
        return {"pose": self.pose, "first_visit": self.first_visit, "last_visit": self.last_visit,
                "span_s": round(self.span_s, 3), "dAP_mm": r(self.dAP_mm, 6), "U_dAP_mm": r(self.U_dAP_mm, 6),
                "dRP_mm": r(self.dRP_mm, 6), "U_dRP_mm": r(self.U_dRP_mm, 6), "shift_mm": r(self.shift_mm, 6),
                **{k: r(v, 7) for k, v in (self.orientation or {}).items()}}


#: the orientation figures of a visit and of a drift, per angle (keys of ``orientation``)
ANGLE_KEYS = tuple(f"{kind}{ax}_deg" for kind in ("AP", "RP") for ax in "abc")
DRIFT_ANGLE_KEYS = tuple(f"d{k}" for k in ANGLE_KEYS)


def _ap_rp(x: np.ndarray, c: np.ndarray) -> tuple[float, float | None]:
    """Eq. (1) and eq. (2) of the stops ``x`` (n, 3) at the commanded position ``c``."""
    xb = x.mean(axis=0)
    ap = float(np.linalg.norm(xb - c))
    if x.shape[0] < 2:
        return ap, None
    l = np.linalg.norm(x - xb, axis=1)
    return ap, float(l.mean() + 3.0 * l.std(ddof=1))


def visit_pose(visit: int, pose: str, attained_mm, attained_t_s, commanded_mm, t_start_s: float,
               budget: Budget, abc_rad=None, commanded_abc_rad=None) -> VisitPose:
    """AP (eq. (1)) and RP (eq. (2)) of one pose at one visit, with their U under ``budget``; with the stops'
    angles ``abc_rad`` (n, 3) and the commanded ones ``commanded_abc_rad`` (3,) (a 6-DoF target, base frame)
    the orientation's AP and RP per angle too."""
    x = np.asarray(attained_mm, dtype=float).reshape(-1, 3)
    if not x.shape[0]:
        raise InsufficientDataError(f"visit {visit}: no attained stop at {pose}")
    c = np.asarray(commanded_mm, dtype=float)
    ap, rp = _ap_rp(x, c)
    pu = pose_uncertainty(x, c, budget, pose, AP_mm=ap, RP_mm=rp)
    U = {k: fu.U for k, fu in pu.items()}
    t = float(np.mean(np.asarray(attained_t_s, dtype=float))) - float(t_start_s)
    dev, ori = None, None
    if abc_rad is not None and commanded_abc_rad is not None:
        dev, ori = _visit_orientation(visit, pose, abc_rad, commanded_abc_rad, x.shape[0], budget)
    return VisitPose(visit, pose, t, x, ap, rp, U.get("AP_mm"), U.get("RP_mm") if rp is not None else None,
                     dev, ori)


def _visit_orientation(visit: int, pose: str, abc_rad, commanded_abc_rad, n: int, budget: Budget):
    """The stops' angle deviations (n, 3), deg, and the orientation figures of one visit of a pose."""
    a = np.asarray(abc_rad, dtype=float).reshape(-1, 3)
    cmd = np.asarray(commanded_abc_rad, dtype=float).reshape(3)
    if a.shape[0] != n or not np.all(np.isfinite(a)):
        raise DataError(f"visit {visit}: {pose} has {a.shape[0]} finite orientation(s) for {n} attained stop(s)")
    dev = _wrap(a - cmd)
    if n < 2:
        return np.degrees(dev), None
    S = dev.std(axis=0, ddof=1)
    m = dev.mean(axis=0)
    o = OrientationAR(m, 3.0 * S, _wrap(cmd + m), S, n, np.arange(n))
    fu = orientation_uncertainty(o, budget, pose)
    out = {}
    for j, ax in enumerate("abc"):
        out[f"AP{ax}_deg"] = float(np.degrees(m[j]))
        out[f"RP{ax}_deg"] = float(np.degrees(3.0 * S[j]))
    for k in ANGLE_KEYS:
        out[f"U_{k}"] = fu[k].U if k in fu else None
    return np.degrees(dev), out


def pose_drift(first: VisitPose, last: VisitPose, commanded_mm, budget: Budget) -> PoseDrift:
    """dAP = |AP(t_1) - AP(t_n)| and dRP = |RP(t_1) - RP(t_n)| of one pose (ISO 9283 drift of pose
    characteristics, AP and RP by seed 000 eqs. (1) and (2)); U from the two visits' stops, the frame's error
    common to both."""
    dAP = abs(first.AP_mm - last.AP_mm)
    dRP = None if first.RP_mm is None or last.RP_mm is None else abs(first.RP_mm - last.RP_mm)
    fu = drift_uncertainty([first.attained_mm, last.attained_mm], np.asarray(commanded_mm, dtype=float), dAP,
                           dRP if dRP is not None else math.nan, budget, first.pose)
    U_dAP = fu["dAP_mm"].U if "dAP_mm" in fu else None
    U_dRP = fu["dRP_mm"].U if "dRP_mm" in fu and dRP is not None else None
    shift = float(np.linalg.norm(last.attained_mm.mean(axis=0) - first.attained_mm.mean(axis=0)))
    ori = None
    if first.orientation is not None and last.orientation is not None:
        ori = {}
        for k in ANGLE_KEYS:  # |figure(t_n) - figure(t_1)|: dAPa, dRPa, ...
            ori[f"d{k}"] = abs(last.orientation[k] - first.orientation[k])
        fa = angle_drift_uncertainty(first.angles_deg, last.angles_deg, budget, first.pose)
        for k in DRIFT_ANGLE_KEYS:
            ori[f"U_{k}"] = fa[k].U if k in fa else None
    return PoseDrift(first.pose, first.visit, last.visit, last.t_since_start_s - first.t_since_start_s, dAP, dRP,
                     U_dAP, U_dRP, shift, ori)


def drift_figures(visits: Sequence[Mapping[str, tuple]], commanded_mm: Mapping[str, Sequence],
                  t_start_s: float, budget: Budget, commanded_abc_rad: Mapping[str, Sequence] | None = None
                  ) -> tuple[list[VisitPose], dict[str, PoseDrift], list[str]]:
    """Every visit's AP/RP per pose and every pose's drift.

    Parameters
    ----------
    visits : sequence of mappings
        Per visit (in order, visit 1 first), ``{pose: (attained_mm (n, 3), attained_t_s (n,))}`` in the base
        frame, or ``(attained_mm, attained_t_s, abc_rad (n, 3))`` with the stops' angles a, b, c of a 6-DoF
        target (base frame); a pose a visit did not attain is left out of its mapping.
    commanded_mm : mapping
        ``{pose: (3,)}``.
    t_start_s : float
        The programme's start (device time of the cold start), s.
    budget : Budget
        The uncertainty's inputs.
    commanded_abc_rad : mapping, optional
        ``{pose: (3,)}`` the commanded angles a, b, c, rad: with the stops' angles, the orientation figures
        and their drift (dAPa ... dRPc).

    Returns
    -------
    (visit poses, {pose: PoseDrift}, warnings)
        A pose attained at fewer than two visits has no drift (a warning says so).
    """
    rows: list[VisitPose] = []
    by_pose: dict[str, list[VisitPose]] = {p: [] for p in commanded_mm}
    warnings: list[str] = []
    for v, visit in enumerate(visits, start=1):
        for pose in commanded_mm:
            if pose not in visit or not len(visit[pose][0]):
                warnings.append(f"visit {v}: {pose} not attained")
                continue
            entry = visit[pose]
            abc = entry[2] if len(entry) > 2 else None
            cabc = None if commanded_abc_rad is None else commanded_abc_rad.get(pose)
            vp = visit_pose(v, pose, entry[0], entry[1], commanded_mm[pose], t_start_s, budget, abc, cabc)
            rows.append(vp)
            by_pose[pose].append(vp)
    drifts = {}
    for pose, vps in by_pose.items():
        if len(vps) < 2:
            warnings.append(f"{pose}: attained at {len(vps)} visit(s), two needed for its drift")
            continue
        drifts[pose] = pose_drift(vps[0], vps[-1], commanded_mm[pose], budget)
    return rows, drifts, warnings
