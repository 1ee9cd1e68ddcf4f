"""ISO 9283 7.8, exchangeability: how far apart robots of one type put the same commanded pose.

Several robots of one model, on the same mounting, run the same test
programme (the same poses of the same cube, the same payload, speed and
dwell); each robot's attained positions at a pose have a barycentre
(seed 000 eq. (1)'s ``x_bar, y_bar, z_bar``, in that robot's base frame).
Exchangeability at a pose is the largest distance between the barycentres
of two of the robots; the figure states it per pose and the largest over
the poses (:data:`EXCHANGEABILITY`)::

    E_j = max_{a, b} | G_a,j - G_b,j |        mm, G the barycentre of robot a at pose j
    E   = max_j E_j

Uncertainty: each barycentre carries its standard uncertainty per
coordinate (the scatter of its attained positions over the square root of
their number, and the registration of its base frame at the pose); the
extreme pair's distance has ``u(E_j)^2 = u_a^2 + u_b^2`` along the line
between them, ``U = 2 u`` (k = 2); ``U_scatter`` is the same with the
attained positions' scatter alone (what remains once the base frames are
taken as given).

:func:`conditions_problems` says why runs cannot be compared (different
poses, payload, speed, dwell, cycles, model, registration method); pure
functions, arrays in.

Frame: each robot's barycentres are in the base frame its own run
registered (by default from its joint 1 and 2 axes). The standard compares
robots exchanged on one mounting, measured in the mounting's frame; a
robot's own registration absorbs part of what sets it apart (its joint 1
and 2 zero offsets, its base row), so the figure from stored runs is the
exchangeability in the robots' registered frames, which differs from
the one in the mounting's, either way (by 10-50 % in the simulated fleets
of ``tests/store/test_exchangeability.py``, which prints both).
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
    """One robot's run: its barycentre and standard uncertainty (per coordinate) at each pose, mm: in all
    (``u_mm``) and the scatter's share alone (``u_scatter_mm``; None: not told apart)."""

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

    def to_dict(self) -> dict:
        return {"figure": EXCHANGEABILITY.key, "exchangeability_mm": self.exchangeability_mm, "U_mm": self.U_mm,
                "pose": self.pose, "per_pose": self.per_pose, "robots": list(self.robots)}


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


__all__ = ["EXCHANGEABILITY", "SAME_PROGRAMME", "RobotPoses", "Exchangeability", "conditions_problems",
           "exchangeability"]
