"""What an ideal ISO 9283 run would report for an arm whose errors are known.

Given the error effects of an arm (:class:`station.models.effects.EffectSet`,
e.g. the truth of a simulated cell, or a fitted model), this predicts the
static part of the procedure's results without noise: the base frame the
axis registration would find (the same :func:`register_by_axes` on the true
tool points of the joint-1 and joint-2 sweeps, each approached from below),
the attained positions of P1..P5 reached in cycle order (backlash from the
direction of the last motion), and from them AP (seed 000 eq. (1), the
distance of the attained from the commanded position) and AD (eq. (8), the
attained minus the commanded distance of P2-P4).

What it leaves out is random or dynamic: the stop scatter (its mean over n
cycles shifts AP by about sigma / sqrt(n)), the tracker's noise and the
registration's own uncertainty from it, the servo's settling and the thermal
growth during the run (evaluated at one warm-up time). Over 50 fake cells
(5 cycles each, 250 poses) the measured AP differed from this prediction by
0.00 +/- 0.22 mm, at most 0.68 mm, about 0.6 of the run's own registration
uncertainty (0.13-0.97 mm); AD by 0.02 +/- 0.02 mm (``bench/bench_fake_truth.py``).

Used to draw simulated cells whose robot is inside or outside its
manufacturer's limits on purpose (:mod:`station.testing`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from procedures.iso9283 import IsoPlan, axis_sweep_q_deg, axis_sweeps
from station.analysis.registration import register_by_axes
from station.errors import ConfigError
from station.models import kinematics as kin
from station.models.effects import EffectContext, EffectSet
from station.programs.builders import TOOL_DOWN


@dataclass(frozen=True)
class StaticPrediction:
    """Noise-free static results of an ISO 9283 run (mm)."""

    AP_mm: dict[str, float]
    AD_mm: dict[str, float]
    attained_base_mm: dict[str, tuple[float, float, float]]

    def worst_AP_mm(self) -> float:
        return max(self.AP_mm.values())


def _true_positions(plan: IsoPlan, effects: EffectSet | None, q_rad: np.ndarray, last_dir: np.ndarray,
                    warmup_s: float) -> np.ndarray:
    robot = plan.robot
    if effects is None:
        return kin.fk(robot.dh_nominal, q_rad)[:, :3, 3]
    ctx = EffectContext(robot=robot, last_dir=last_dir, warmup_s=np.full(len(q_rad), float(warmup_s)),
                        payload_kg=plan.payload_kg)
    dh, q = effects.apply(robot.dh_nominal, q_rad, ctx)
    return kin.fk(dh, q)[:, :3, 3]


def pose_joints_rad(plan: IsoPlan) -> np.ndarray:
    """Joints of P1..P5 (nominal IK from the safety gate, each from the previous pose's branch)."""
    gate = plan.gate()
    out, prev = [], None
    for name, xyz in plan.poses_mm.items():
        T = np.eye(4)
        T[:3, :3] = TOOL_DOWN
        T[:3, 3] = xyz
        prev = gate.check_cartesian_target(T, name, q_seed=prev)
        out.append(prev)
    return np.array(out)


def arrival_directions(plan: IsoPlan, q_rad: np.ndarray, *, back_mm: float = 1.0) -> np.ndarray:
    """Sign of each joint's motion as the linear move of the cycle arrives at each pose (N, 6).

    The cycle runs P1..P5 and back to P1 in straight lines, and a joint can
    turn back part-way along a line, so the direction is taken over the last
    ``back_mm`` of the move (IK of a point that far before the pose). A joint
    that does not move on the way in keeps the direction of the move before.
    """
    gate = plan.gate()
    xyz = np.array(list(plan.poses_mm.values()), dtype=float)
    n = len(xyz)
    step = np.zeros((n, 6))
    for k in range(n):
        back = xyz[k - 1] - xyz[k]
        T = np.eye(4)
        T[:3, :3] = TOOL_DOWN
        T[:3, 3] = xyz[k] + back / np.linalg.norm(back) * back_mm
        step[k] = q_rad[k] - gate.check_cartesian_target(T, f"before {list(plan.poses_mm)[k]}", q_seed=q_rad[k])
    moving = np.abs(step) > 1e-9
    out = np.sign(step)
    for _ in range(2):  # twice round the cycle carries a direction into every pose
        for k in range(n):
            out[k] = np.where(moving[k], out[k], out[k - 1])
    return out


def predict_static(plan: IsoPlan, effects: EffectSet | None, *, warmup_s: float = 0.0) -> StaticPrediction:
    """Noise-free AP per pose and AD of P2-P4 of an arm with ``effects`` (``None``: nominal arm).

    Parameters
    ----------
    plan : IsoPlan
        The procedure's plan (poses, sweeps, payload); only ``registration == "axes"``.
    effects : EffectSet or None
        The arm's error effects.
    warmup_s : float
        Time since the arm started working, s (thermal drift).

    Raises
    ------
    ConfigError
        The plan registers by a best fit (that frame depends on the noise of all points).
    """
    if plan.registration != "axes":
        raise ConfigError("predict_static needs the axis registration (iso9283.registration = 'axes')")
    sweeps = axis_sweep_q_deg(plan)
    q_sweep = np.radians(np.array(list(sweeps.values())))
    n1 = len(axis_sweeps(plan)[0][1])
    p_sweep = _true_positions(plan, effects, q_sweep, np.ones_like(q_sweep), warmup_s)
    reg = register_by_axes(plan.robot.dh_nominal, q_sweep[:n1], p_sweep[:n1], q_sweep[n1:], p_sweep[n1:])

    names = list(plan.poses_mm)
    q = pose_joints_rad(plan)
    last_dir = arrival_directions(plan, q)
    p_true = _true_positions(plan, effects, q, last_dir, warmup_s)
    # the registration maps the (estimated) base frame into the true one: invert it
    p_base = (p_true - reg.t_mm) @ reg.R
    cmd = np.array([plan.poses_mm[n] for n in names])
    ap = np.linalg.norm(p_base - cmd, axis=1)
    ad = {}
    if "P2" in names and "P4" in names:
        i, j = names.index("P2"), names.index("P4")
        ad["P2-P4"] = float(np.linalg.norm(p_true[i] - p_true[j]) - np.linalg.norm(cmd[i] - cmd[j]))
    return StaticPrediction(
        AP_mm={n: float(v) for n, v in zip(names, ap)},
        AD_mm=ad,
        attained_base_mm={n: tuple(float(v) for v in p) for n, p in zip(names, p_base)},
    )
