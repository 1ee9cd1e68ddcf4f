"""A diagnosed motion model's effects on a simulated arm's tool, from the arm's own moves.

A world built with a motion model (:func:`fakes.sim.world.make_world`,
``motion_model=``; written by ``station diagnose motion --model-out``) runs its
arm's axes with the model's loop, and its tracker sees the model's creep,
structural mode and reading drift (:func:`station.models.motion_effects.approach_offsets_mm`)
added to the tool's true position. Each move's effects act along its direction
of arrival: the commanded tool path's direction over its last
:data:`ARRIVAL_S` (a joint move's path is a curve: its chord may point far from
where the tool comes in from). Moves ended more than :data:`HORIZON_S` before a
sample do not touch it (a creep or a ring has died out long before).
"""

from __future__ import annotations

import numpy as np

from station.models import kinematics as kin
from station.models.motion_effects import MotionModel, approach_offsets_mm

__all__ = ["arm_motion_offsets_mm", "ARRIVAL_S", "HORIZON_S"]

#: the direction of arrival is the commanded tool path's over this last part of the move, s
ARRIVAL_S = 0.05
#: a move ended this long before a sample leaves it untouched, s
HORIZON_S = 60.0
#: the motions that move the tool (dwells, settles and stops do not start a new approach)
_MOVING = ("joint", "linear")


def arm_motion_offsets_mm(arm, t_s, model: MotionModel, seed: int) -> np.ndarray:
    """Offsets (N, 3) mm, robot base frame, of the tool at world times ``t_s`` from ``model``'s effects on the
    moves of ``arm`` (a :class:`fakes.sim.arm.SimArm`)."""
    t = np.asarray(t_s, dtype=float).reshape(-1)
    if t.size == 0:
        return np.zeros((0, 3))
    lo, hi = float(t.min()) - HORIZON_S, float(t.max())
    dh = arm.robot.dh_nominal
    moves, q_prev = [], np.asarray(arm.robot.home_q_rad, dtype=float)
    for m in arm.moves:
        q_to = np.asarray(m.q_target_rad, dtype=float)
        if m.kind in _MOVING and not m.cancelled and m.t_end > m.t_start and lo <= m.t_end and m.t_start <= hi:
            p_from, p_to = kin.fk(dh, q_prev)[:3, 3], kin.fk(dh, q_to)[:3, 3]
            D = float(np.linalg.norm(p_to - p_from))
            if D > 0.0:
                before = arm.commanded_tool_pose(max(m.t_start, m.t_end - ARRIVAL_S))[:3, 3]
                u = p_to - before
                n = float(np.linalg.norm(u))
                u = u / n if n > 1e-9 else (p_to - p_from) / D
                moves.append({"t_start_s": m.t_start, "t_end_s": m.t_end, "from_mm": p_to - D * u, "to_mm": p_to})
        q_prev = q_to
    return approach_offsets_mm(t, moves, model, seed)
