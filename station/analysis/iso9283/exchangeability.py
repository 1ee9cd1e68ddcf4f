"""ISO 9283 7.8, exchangeability: how far apart robots of one type put the same commanded pose.

Several robots of one model, on the same mounting, run the same test
programme (the same poses of the same cube, the same payload, speed and
dwell); each robot's attained positions at a pose have a barycentre
(seed 000 eq. (1)'s ``x_bar, y_bar, z_bar``, in the mounting's frame).
Exchangeability at a pose is the largest distance between the barycentres
of two of the robots; the figure states it per pose and the largest over
the poses (:data:`EXCHANGEABILITY`)::

    E_j = max_{a, b} | G_a,j - G_b,j |        mm, G the barycentre of robot a at pose j
    E   = max_j E_j

Frame: the standard compares robots exchanged on one mounting, so the
barycentres are in one frame of the mounting, the same for every robot: the
tracker's readings of each run are carried into the mounting's frame its run
stored (:class:`MountingFrame`, a frame file giving ``p_tracker = R
p_mounting + t``, typically the first robot's registered frame kept for the
others with the tracker left standing). Each robot's own registered frame
would absorb what sets it apart on the mounting (its base's offset, its
joint 1 and 2 zero offsets); in one frame that is part of the figure.
:func:`mounting_problems` refuses runs without a mounting frame, on
different mountings, in frames that are not one, or whose registered base
lies further from the mounting's frame than a robot on that mounting can
(:data:`MAX_BASE_OFFSET_MM`: the tracker moved since the frame was measured).
Distances do not depend on which frame of the mounting it is: the frame's
own error, common to the robots, does not enter the figure.

Uncertainty: each barycentre carries its standard uncertainty per
coordinate: the scatter of its attained positions over the square root of
their number, and the tracker's accuracy at the pose (``a + b R``, a k = 2
bound halved: each robot's run is its own tracker session, whose systematic
error the other sessions do not share); the extreme pair's distance has
``u(E_j)^2 = u_a^2 + u_b^2`` along the line between them, ``U = 2 u``
(k = 2); ``U_scatter`` is the same with the attained positions' scatter
alone.

:func:`conditions_problems` says why runs cannot be compared (different
poses, payload, speed, dwell, cycles, model, registration method); pure
functions, arrays in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from station import characteristics as table
from station.errors import DataError, InsufficientDataError

#: the figure (its row of the characteristics table)
EXCHANGEABILITY = table.get("exchangeability_mm", "fleet")

#: plan entries that make two runs the same test programme, with the tolerance of a number in each
SAME_PROGRAMME = {"poses_mm": 1e-6, "payload_kg": 1e-9, "speed_frac": 1e-9, "dwell_s": 1e-9, "cycles": 0.0,
                  "robot": None, "registration": None}


@dataclass(frozen=True)
class RobotPoses:
    """One robot's run: its barycentre (in the mounting's frame) and standard uncertainty (per coordinate) at each
    pose, mm: in all (``u_mm``) and the scatter's share alone (``u_scatter_mm``; None: not told apart)."""

    serial: str
    run_id: str
    barycentre_mm: Mapping[str, np.ndarray]
    u_mm: Mapping[str, float]
    u_scatter_mm: Mapping[str, float] | None = None


@dataclass(frozen=True)
class Exchangeability:
    exchangeability_mm: float
    U_mm: float
    pose: str
    per_pose: dict
    robots: tuple[str, ...]
    #: the mounting whose frame the barycentres are in
    mounting: str | None = None

    def to_dict(self) -> dict:
        return {"figure": EXCHANGEABILITY.key, "exchangeability_mm": self.exchangeability_mm, "U_mm": self.U_mm,
                "pose": self.pose, "per_pose": self.per_pose, "robots": list(self.robots), "mounting": self.mounting}


#: the largest distance, mm, at the test poses between a robot's registered base frame and the mounting's frame
#: it was measured in: a robot of one model on one mounting sits within a few millimetres (its base's offset on
#: the plate, its zero offsets); further, the tracker moved since the frame was measured, or another mounting
MAX_BASE_OFFSET_MM = 10.0
#: two runs' mounting frames are one frame when they put the test poses this close in the tracker's frame, mm
SAME_FRAME_MM = 1e-6


@dataclass(frozen=True)
class MountingFrame:
    """The mounting a run was measured on and its frame in the tracker's, ``p_tracker = R p_mounting + t_mm``;
    ``base_offset_mm``: the largest distance at the test poses between the run's registered base frame and
    this frame (how far the robot's base sits from where the frame puts it, plus the tracker's moves)."""

    name: str
    R: np.ndarray
    t_mm: np.ndarray
    base_offset_mm: float
    source: str = ""

    @classmethod
    def from_dict(cls, d: Mapping) -> "MountingFrame":
        try:
            R, t = np.asarray(d["R"], dtype=float), np.asarray(d["t_mm"], dtype=float)
            frame = cls(str(d["name"]), R, t, float(d["base_offset_mm"]), str(d.get("from", "")))
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"a stored mounting frame is incomplete or not numbers: {exc}") from None
        if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise DataError(f"a stored mounting frame needs R (3x3) and t_mm (3), finite; got {R.shape}, {t.shape}")
        return frame

    def to_dict(self) -> dict:
        return {"name": self.name, "R": self.R.tolist(), "t_mm": self.t_mm.tolist(),
                "base_offset_mm": self.base_offset_mm, "from": self.source}

    def to_tracker(self, p_mm) -> np.ndarray:
        return np.asarray(p_mm, dtype=float) @ self.R.T + self.t_mm

    def from_tracker(self, p_tracker_mm) -> np.ndarray:
        """Tracker coordinates (..., 3) in the mounting's frame, mm."""
        return (np.asarray(p_tracker_mm, dtype=float) - self.t_mm) @ self.R


def base_offset_mm(frame_R, frame_t_mm, reg_R, reg_t_mm, poses_mm) -> float:
    """The largest distance, mm, between where a registered base frame (``p_tracker = reg_R p + reg_t``) and a
    mounting frame put the test poses ``poses_mm`` (P, 3)."""
    P = np.asarray(poses_mm, dtype=float).reshape(-1, 3)
    in_tracker = P @ np.asarray(reg_R, dtype=float).T + np.asarray(reg_t_mm, dtype=float)
    in_mounting = (in_tracker - np.asarray(frame_t_mm, dtype=float)) @ np.asarray(frame_R, dtype=float)
    return float(np.max(np.linalg.norm(in_mounting - P, axis=1)))


def mounting_problems(frames: Mapping[str, MountingFrame | None], poses_mm) -> list[str]:
    """Why the runs (``robot -> its run's mounting frame``, None: measured without one) are not on one mounting
    in one frame; empty when they are. Each reason names the robots."""
    missing = [who for who, f in frames.items() if f is None]
    if missing:
        return [f"measured without a mounting frame: {', '.join(missing)} (robots.<r>.mounting in the station "
                "config; the exchangeability of robots each in its own registered frame is not the standard's)"]
    problems = []
    names: dict[str, list[str]] = {}
    for who, f in frames.items():
        names.setdefault(f.name, []).append(who)
    if len(names) > 1:
        problems.append("measured on different mountings: " + "; ".join(
            f"{name} ({', '.join(whos)})" for name, whos in names.items()))
    P = np.asarray(poses_mm, dtype=float).reshape(-1, 3)
    (ref_who, ref), *rest = frames.items()
    for who, f in rest:
        d = float(np.max(np.linalg.norm(f.to_tracker(P) - ref.to_tracker(P), axis=1)))
        if d > SAME_FRAME_MM:
            problems.append(f"not one mounting frame: {who}'s puts the test poses up to {d:.4g} mm from "
                            f"{ref_who}'s (another frame file, or the frame measured again)")
    far = [f"{who} {f.base_offset_mm:.4g} mm" for who, f in frames.items() if f.base_offset_mm > MAX_BASE_OFFSET_MM]
    if far:
        problems.append(f"registered base further than {MAX_BASE_OFFSET_MM:g} mm from the mounting's frame at the "
                        f"test poses: {', '.join(far)} (the tracker moved since the frame was measured, or the "
                        "robot is not on this mounting)")
    return problems


def conditions_problems(plans: Mapping[str, Mapping]) -> list[str]:
    """Why the runs (``serial -> stored plan``) are not one test programme on robots of one model; empty
    when they are. Each reason names the entry and the robots that differ."""
    problems = []
    items = list(plans.items())
    if len(items) < 2:
        return [f"exchangeability needs runs of at least 2 robots, got {len(items)}"]
    ref_serial, ref = items[0]
    for key, tol in SAME_PROGRAMME.items():
        for serial, plan in items[1:]:
            a, b = ref.get(key), plan.get(key)
            if not _same(a, b, tol):
                problems.append(f"{key} differs: {ref_serial} {_show(a)}, {serial} {_show(b)}")
                break
    return problems


def _same(a, b, tol) -> bool:
    if tol is None or isinstance(a, str) or isinstance(b, str):
        return a == b
    if isinstance(a, Mapping) or isinstance(b, Mapping):
        if not (isinstance(a, Mapping) and isinstance(b, Mapping)) or sorted(a) != sorted(b):
            return False
        return all(_same(a[k], b[k], tol) for k in a)
    try:
        x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    except (TypeError, ValueError):
        return a == b
    return x.shape == y.shape and bool(np.all(np.abs(x - y) <= tol))


def _show(v) -> str:
    text = str(v)
    return text if len(text) <= 60 else text[:57] + "..."


def exchangeability(robots: list[RobotPoses]) -> Exchangeability:
    """E per pose and overall from each robot's barycentres (the same poses for every robot)."""
    if len(robots) < 2:
        raise InsufficientDataError(f"exchangeability needs at least 2 robots, got {len(robots)}")
    poses = list(robots[0].barycentre_mm)
    for r in robots[1:]:
        if sorted(r.barycentre_mm) != sorted(poses):
            raise DataError(f"robot {r.serial} has poses {sorted(r.barycentre_mm)}, robot {robots[0].serial} "
                            f"{sorted(poses)}")
    per_pose = {}
    for pose in poses:
        G = np.array([np.asarray(r.barycentre_mm[pose], dtype=float).reshape(3) for r in robots])
        u = np.array([float(r.u_mm[pose]) for r in robots])
        if not (np.all(np.isfinite(G)) and np.all(np.isfinite(u)) and np.all(u >= 0)):
            raise DataError(f"pose {pose}: a barycentre or its uncertainty is not finite")
        D = np.linalg.norm(G[:, None, :] - G[None, :, :], axis=2)
        a, b = np.unravel_index(int(np.argmax(D)), D.shape)
        uc = math.hypot(u[a], u[b])
        per_pose[pose] = {"exchangeability_mm": float(D[a, b]), "U_mm": 2.0 * uc,
                          "between": [robots[a].serial, robots[b].serial]}
        if all(r.u_scatter_mm is not None for r in (robots[a], robots[b])):
            per_pose[pose]["U_scatter_mm"] = 2.0 * math.hypot(robots[a].u_scatter_mm[pose],
                                                              robots[b].u_scatter_mm[pose])
    worst = max(per_pose, key=lambda p: per_pose[p]["exchangeability_mm"])
    return Exchangeability(per_pose[worst]["exchangeability_mm"], per_pose[worst]["U_mm"], worst, per_pose,
                           tuple(r.serial for r in robots))


__all__ = ["EXCHANGEABILITY", "SAME_PROGRAMME", "MAX_BASE_OFFSET_MM", "SAME_FRAME_MM", "MountingFrame",
           "RobotPoses", "Exchangeability", "base_offset_mm", "mounting_problems", "conditions_problems",
           "exchangeability"]
