"""The safety gate: nothing reaches a robot before it passes here.

Every target, speed and program is checked against the robot's nominal
model and the station's configured limits *before* a program is uploaded or a
command is sent, by the controller driver, the UR driver and the controller
fake alike:

* every Cartesian target is reachable: inverse kinematics with the nominal
  model (:func:`station.models.kinematics.ik`), solved from the previous
  target's joints (the controller's "closest configuration" rule), must
  converge inside the joint limits;
* every joint target and every IK solution lies inside the joint limits
  (the robot's, tightened by the configured ``joint_limits_deg``);
* every target and every point of the path between targets lies in the
  configured workspace box (joint moves: the TCP path of the joint
  interpolation is sampled; linear moves: the segment is inside because the
  box is convex, and sampled points along it, every ``path_step_mm`` of
  its line and every :data:`PATH_STEP_DEG` of its turn (a move that only
  turns the tool about its held point is sampled along the turn), must be
  reachable without a branch change; circular
  moves: sampled points of the arc must be inside the box and reachable; a
  corner zone only rounds a corner inside the convex hull of its segments);
* speeds and accelerations are under the caps: the speed fraction, the
  linear TCP speed, the estimated peak TCP speed of a joint move (cruise
  joint velocities of the synchronised profile through the Jacobian along the
  path), the acceleration fraction and a linear move's programmed turn
  (``ori_speed_deg_s``, under ``max_speed_frac`` of the rated turn,
  :func:`~station.programs.program.rated_ori_speed_deg_s`).

API (all raise :class:`~station.errors.SafetyError`, never move anything)::

    gate = SafetyGate(robot, SafetyLimits(workspace_min_mm=..., workspace_max_mm=...,
                                          max_tcp_speed_mm_s=...))
    gate.check_program(rendered_or_program, q_start=q_now)   # whole program
    gate.check_joint_target(q_rad, "label") -> q               # one target
    gate.check_cartesian_target(xyz_or_T, "label", q_seed) -> q
    gate.check_joint_motion(q_now, q_or_T, "movej", speed_frac=0.2) -> q
    gate.check_linear_motion(q_now, xyz_or_T, "movel", speed_mm_s=250) -> q
    gate.check_speed("label", speed_frac=, accel_frac=, tcp_speed_mm_s=,
                     joint_speed_rad_s=, joint_accel_rad_s2=)

A refusal is a :class:`~station.errors.SafetyError` whose message names the
program line (when known), the instruction and the target, e.g.
``line 23: linear move to P4 ('ISO P4'): position [500, 1200, 700] mm is
outside the workspace box z [800, 2000] mm``.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from scipy.spatial.transform import Rotation, Slerp

from station.errors import ConfigError, DataError, SafetyError
from station.models import cartesian_path, kinematics
from station.programs.program import (
    CycleMark,
    Dwell,
    JointTarget,
    Loop,
    Move,
    Program,
    RenderedProgram,
    rated_ori_speed_deg_s,
)

_AXES = "xyz"
#: a linear move's turn is checked every this many degrees (and its line every ``path_step_mm``)
PATH_STEP_DEG = 2.0


class SafetyLimits(BaseModel):
    """Configured safety limits of one robot cell.

    Attributes
    ----------
    workspace_min_mm, workspace_max_mm : (3,) float
        Axis-aligned box (robot base frame) that the TCP must never leave.
    max_tcp_speed_mm_s : float
        Cap on the TCP speed (linear moves, and the estimated peak of joint moves).
    max_speed_frac : float
        Cap on the speed as a fraction of the rated speed, (0, 1].
    max_accel_frac : float
        Cap on the acceleration as a fraction of the rated one, (0, 1].
    joint_limits_deg : (6, 2) float, optional
        Tighter ``[min, max]`` per joint; may only narrow the robot's limits.
    ik_tol_mm : float
        Position error below which a target counts as reached by the IK.
    path_step_mm : float
        Spacing of the points checked along a path.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    workspace_min_mm: tuple[float, float, float]
    workspace_max_mm: tuple[float, float, float]
    max_tcp_speed_mm_s: float = Field(gt=0, allow_inf_nan=False)
    max_speed_frac: float = Field(1.0, gt=0, le=1, allow_inf_nan=False)
    max_accel_frac: float = Field(1.0, gt=0, le=1, allow_inf_nan=False)
    joint_limits_deg: tuple[tuple[float, float], ...] | None = None
    ik_tol_mm: float = Field(0.01, gt=0, le=10, allow_inf_nan=False)
    path_step_mm: float = Field(25.0, gt=0, le=1000, allow_inf_nan=False)

    @field_validator("workspace_min_mm", "workspace_max_mm")
    @classmethod
    def _finite(cls, v):
        if not all(math.isfinite(x) for x in v):
            raise ValueError("must be finite")
        return v

    @model_validator(mode="after")
    def _check(self) -> "SafetyLimits":
        for i in range(3):
            if not self.workspace_min_mm[i] < self.workspace_max_mm[i]:
                raise ValueError(
                    f"workspace {_AXES[i]}: min {self.workspace_min_mm[i]} must be < max {self.workspace_max_mm[i]}"
                )
        if self.joint_limits_deg is not None:
            if len(self.joint_limits_deg) != 6:
                raise ValueError(f"joint_limits_deg needs 6 [min, max] pairs, got {len(self.joint_limits_deg)}")
            for j, (lo, hi) in enumerate(self.joint_limits_deg):
                if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                    raise ValueError(f"joint_limits_deg[{j}]: need finite min < max, got [{lo}, {hi}]")
        return self


@dataclass(frozen=True)
class GateReport:
    """What a program that passed the gate will do (nominal model).

    Attributes
    ----------
    q_rad : ndarray, shape (M, 6)
        Joint solution of every move in execution order of the first pass
        (loop bodies once), starting pose excluded.
    tcp_mm : ndarray, shape (M, 3)
        Nominal TCP position of each of those moves.
    peak_tcp_speed_mm_s : float
        Highest TCP speed the program commands (estimated for joint moves).
    """

    q_rad: np.ndarray
    tcp_mm: np.ndarray
    peak_tcp_speed_mm_s: float


#: inverse kinematics the gates have solved, by their exact inputs (most recent last). A station checks
#: the same programs again and again (every cycle's upload, from the same reported joints) and
#: :func:`~station.models.kinematics.ik` is deterministic, so an answer is reused bit for bit.
_IK_MEMO: OrderedDict = OrderedDict()
_IK_MEMO_SIZE = 2048
_IK_MEMO_LOCK = threading.Lock()


def _ik(dh, target, q0, limits, **kw) -> kinematics.IKResult:
    """:func:`~station.models.kinematics.ik` through the memo (the caller gets its own arrays)."""
    parts = [np.ascontiguousarray(a, dtype=float) for a in (dh, target, q0, limits)]
    key = (tuple((a.shape, a.tobytes()) for a in parts), tuple(sorted(kw.items())))
    with _IK_MEMO_LOCK:
        res = _IK_MEMO.get(key)
        if res is not None:
            _IK_MEMO.move_to_end(key)
    if res is None:
        res = kinematics.ik(*parts, **kw)
        with _IK_MEMO_LOCK:
            _IK_MEMO[key] = res
            while len(_IK_MEMO) > _IK_MEMO_SIZE:
                _IK_MEMO.popitem(last=False)
    return dataclasses.replace(res, **{f.name: getattr(res, f.name).copy() for f in dataclasses.fields(res)
                                       if isinstance(getattr(res, f.name), np.ndarray)})


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:.6g}" for x in np.asarray(v, dtype=float).ravel()) + "]"


class SafetyGate:
    """Checks targets, speeds and programs for one robot against limits.

    Parameters
    ----------
    robot : RobotSpec
        The arm (nominal kinematics, joint limits, rated speeds).
    limits : SafetyLimits
        The cell's configured limits.
    """

    def __init__(self, robot, limits: SafetyLimits) -> None:
        if not isinstance(limits, SafetyLimits):
            raise ConfigError(f"limits must be SafetyLimits, got {type(limits).__name__}")
        self.robot = robot
        self.limits = limits
        lim = np.array(robot.joint_limits_rad, dtype=float)
        if limits.joint_limits_deg is not None:
            cfg = np.radians(np.array(limits.joint_limits_deg, dtype=float))
            for j in range(6):
                if cfg[j, 0] < lim[j, 0] - 1e-9 or cfg[j, 1] > lim[j, 1] + 1e-9:
                    raise ConfigError(
                        f"joint_limits_deg[{j}] {_fmt(np.degrees(cfg[j]))} deg reaches beyond the robot's "
                        f"{_fmt(np.degrees(lim[j]))} deg (configured limits may only tighten)"
                    )
            lim = cfg
        self.joint_limits_rad = lim
        self.box_min = np.array(limits.workspace_min_mm, dtype=float)
        self.box_max = np.array(limits.workspace_max_mm, dtype=float)
        self.max_tcp_speed_mm_s = min(float(limits.max_tcp_speed_mm_s), float(robot.max_tcp_speed_mm_s))

    # ------------------------------------------------------------------ basic checks
    def _outside_box(self, p: np.ndarray) -> np.ndarray:
        """(N,) bool: point outside the workspace box."""
        return np.any((p < self.box_min) | (p > self.box_max), axis=-1)

    def _box_message(self, p: np.ndarray) -> str:
        bad = [
            f"{_AXES[i]} [{self.box_min[i]:g}, {self.box_max[i]:g}]"
            for i in range(3)
            if not self.box_min[i] <= p[i] <= self.box_max[i]
        ]
        return f"position {_fmt(p)} mm is outside the workspace box " + ", ".join(bad) + " mm"

    def check_position(self, xyz_mm, label: str) -> np.ndarray:
        """Refuse a TCP position outside the workspace box."""
        p = self._vector(xyz_mm, 3, label, "position")
        if self._outside_box(p[None])[0]:
            raise SafetyError(f"{label}: {self._box_message(p)}")
        return p

    @staticmethod
    def _vector(x, n: int, label: str, what: str) -> np.ndarray:
        try:
            a = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise SafetyError(f"{label}: {what} is not numeric") from None
        if a.shape != (n,):
            raise SafetyError(f"{label}: {what} must have shape ({n},), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise SafetyError(f"{label}: {what} {_fmt(a)} is not finite")
        return a

    def _check_limits(self, q: np.ndarray, label: str) -> None:
        lo, hi = self.joint_limits_rad[:, 0], self.joint_limits_rad[:, 1]
        bad = np.nonzero((q < lo - 1e-9) | (q > hi + 1e-9))[0]
        if bad.size:
            j = int(bad[0])
            raise SafetyError(
                f"{label}: joint {j + 1} at {np.degrees(q[j]):.4g} deg is outside its limits "
                f"[{np.degrees(lo[j]):.4g}, {np.degrees(hi[j]):.4g}] deg"
            )

    def check_joint_target(self, q_rad, label: str) -> np.ndarray:
        """Check a joint target; return it as a (6,) array (rad).

        Raises
        ------
        SafetyError
            Not 6 finite numbers, a joint outside the limits, or a TCP
            position outside the workspace box (nominal model).
        """
        q = self._vector(q_rad, 6, label, "joint target")
        self._check_limits(q, label)
        p = kinematics.tool_position(self.robot.dh_nominal, q)
        if self._outside_box(p[None])[0]:
            raise SafetyError(f"{label}: joint target {_fmt(np.degrees(q))} deg puts the TCP at {self._box_message(p)}")
        return q

    def check_cartesian_target(self, target, label: str, q_seed=None) -> np.ndarray:
        """Check a Cartesian target (``(3,)`` mm or ``(4, 4)`` pose); return its joints.

        The inverse kinematics (nominal model) starts from ``q_seed`` (the
        previous joints; default the robot's home) so the solution stays on
        that configuration branch, as a controller does.

        Raises
        ------
        SafetyError
            Outside the workspace box, or not reachable inside the joint
            limits (the IK residual is named).
        """
        try:
            t = np.asarray(target, dtype=float)
        except (TypeError, ValueError):
            raise SafetyError(f"{label}: target is not numeric") from None
        if t.shape == (4, 4):
            p = t[:3, 3]
        elif t.shape == (3,):
            p = t
        else:
            raise SafetyError(f"{label}: target must be (3,) mm or a (4, 4) pose, got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise SafetyError(f"{label}: target is not finite")
        self.check_position(p, label)
        seed = self.robot.home_q_rad if q_seed is None else self._vector(q_seed, 6, label, "q_seed")
        try:
            res = _ik(self.robot.dh_nominal, t, seed, self.joint_limits_rad, tol_mm=self.limits.ik_tol_mm * 0.1)
        except DataError as exc:
            raise SafetyError(f"{label}: {exc}") from exc
        q = res.q_rad[0]
        if not bool(res.success[0]) or res.residual_mm[0] > self.limits.ik_tol_mm:
            extra = "" if res.residual_deg is None else f", {res.residual_deg[0]:.3g} deg"
            raise SafetyError(
                f"{label}: target at {_fmt(p)} mm is not reachable inside the joint limits "
                f"(IK residual {res.residual_mm[0]:.3g} mm{extra})"
            )
        self._check_limits(q, label)
        return q

    def check_speed(
        self,
        label: str,
        *,
        speed_frac: float | None = None,
        accel_frac: float | None = None,
        tcp_speed_mm_s: float | None = None,
        joint_speed_rad_s=None,
        joint_accel_rad_s2=None,
    ) -> None:
        """Refuse a speed or acceleration over its cap.

        Parameters
        ----------
        label : str
            Names the command in the error.
        speed_frac, accel_frac : float, optional
            Fractions of the rated speed / acceleration.
        tcp_speed_mm_s : float, optional
            Cartesian TCP speed.
        joint_speed_rad_s, joint_accel_rad_s2 : float or (6,) array_like, optional
            Joint speed / acceleration (a scalar, e.g. URScript ``movej``'s
            leading-axis ``v``/``a``, is held against the slowest joint).
            The cap is ``max_speed_frac`` (``max_accel_frac``) times the
            robot's joint limits.
        """
        for what, value, lim, cap in (
            ("joint speed", joint_speed_rad_s, self.robot.joint_speed_limits_rad_s, self.limits.max_speed_frac),
            ("joint acceleration", joint_accel_rad_s2, self.robot.joint_accel_limits_rad_s2, self.limits.max_accel_frac),
        ):
            if value is None:
                continue
            try:
                v = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise SafetyError(f"{label}: {what} {value!r} is not numeric") from None
            caps = cap * np.asarray(lim, dtype=float)
            if v.ndim == 0:
                v, caps = v.reshape(1), caps.min(keepdims=True)
            if v.shape != caps.shape or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise SafetyError(f"{label}: {what} must be finite, >= 0, a scalar or 6 values; got {value!r}")
            over = np.nonzero(v > caps * (1 + 1e-9))[0]
            if over.size:
                j = int(over[0])
                axis = f" of joint {j + 1}" if v.size == 6 else ""
                raise SafetyError(
                    f"{label}: {what}{axis} {np.degrees(v[j]):.4g} deg/s{'^2' if 'acc' in what else ''} exceeds the cap "
                    f"{np.degrees(caps[j]):.4g}"
                )
        checks = (
            ("speed", speed_frac, self.limits.max_speed_frac, ""),
            ("acceleration", accel_frac, self.limits.max_accel_frac, ""),
            ("TCP speed", tcp_speed_mm_s, self.max_tcp_speed_mm_s, " mm/s"),
        )
        for what, value, cap, unit in checks:
            if value is None:
                continue
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise SafetyError(f"{label}: {what} {value!r} is not a number") from None
            if not math.isfinite(v) or v <= 0:
                raise SafetyError(f"{label}: {what} {value!r} must be a positive finite number")
            if v > cap * (1 + 1e-9):
                if unit:
                    raise SafetyError(f"{label}: {what} {v:.6g}{unit} exceeds the cap {cap:.6g}{unit}")
                raise SafetyError(f"{label}: {what} {100 * v:.4g} % exceeds the cap {100 * cap:.4g} %")

    # ------------------------------------------------------------------ paths
    def joint_move_peak_tcp_speed(self, q_a, q_b, speed_frac: float) -> float:
        """Estimated peak TCP speed (mm/s) of a synchronised joint move.

        The joints move together so the slowest one sets the time; at cruise
        joint ``j`` turns at ``dq_j / max_k(|dq_k| / (f v_k))`` (``f`` the
        speed fraction, ``v_k`` the limits); the TCP speed is the linear
        Jacobian times that, taken at the sampled path points.
        """
        qa, qb = np.asarray(q_a, float), np.asarray(q_b, float)
        dq = qb - qa
        if not np.any(dq):
            return 0.0
        vmax = speed_frac * np.asarray(self.robot.joint_speed_limits_rad_s, float)
        t_cruise = np.max(np.abs(dq) / vmax)
        qdot = dq / t_cruise
        s = np.linspace(0.0, 1.0, self._joint_samples(dq))
        qs = qa + s[:, None] * dq
        jv = kinematics.joint_jacobian(self.robot.dh_nominal, qs)[:, :3, :]
        return float(np.max(np.linalg.norm(jv @ qdot, axis=1)))

    @staticmethod
    def _joint_samples(dq: np.ndarray) -> int:
        return int(np.clip(np.ceil(np.degrees(np.max(np.abs(dq))) / 0.5), 2, 2000))

    def check_joint_path(self, q_a, q_b, label: str) -> None:
        """TCP path of a joint-interpolated move stays inside the box."""
        qa, qb = np.asarray(q_a, float), np.asarray(q_b, float)
        s = np.linspace(0.0, 1.0, self._joint_samples(qb - qa))
        qs = qa + s[:, None] * (qb - qa)
        p = kinematics.tool_position(self.robot.dh_nominal, qs)
        out = np.nonzero(self._outside_box(p))[0]
        if out.size:
            i = int(out[0])
            raise SafetyError(
                f"{label}: the joint-interpolated path leaves the workspace at {100 * s[i]:.0f} % of the move: "
                f"{self._box_message(p[i])}"
            )

    def check_linear_path(self, pose_a: np.ndarray, pose_b: np.ndarray, q_a, q_b, label: str) -> None:
        """Points along a straight move are reachable without a branch change.

        Like the controller's interpolator, the IK at each sampled point starts
        from the joint-space interpolation of the end joints; a point that does
        not converge, or a joint jumping more than 0.5 rad between neighbouring
        points (a singularity or configuration change), refuses the move.
        """
        pa, pb = pose_a[:3, 3], pose_b[:3, 3]
        turn_deg = math.degrees(float((Rotation.from_matrix(pose_b[:3, :3]) * Rotation.from_matrix(pose_a[:3, :3]).inv())
                                      .magnitude()))
        n = int(np.clip(max(np.ceil(np.linalg.norm(pb - pa) / self.limits.path_step_mm), np.ceil(turn_deg / PATH_STEP_DEG)),
                        1, 500)) + 1
        if n <= 2:
            return
        s = np.linspace(0.0, 1.0, n)
        self._check_sampled_path(pose_a, pose_b, pa + s[:, None] * (pb - pa), q_a, q_b, label,
                                 "straight" if np.linalg.norm(pb - pa) > 0 else "turn's", s=s)

    def check_arc_path(self, pose_a: np.ndarray, via_mm, pose_b: np.ndarray, q_a, q_b, label: str) -> None:
        """Points along a circular move (from ``pose_a`` through ``via_mm`` to ``pose_b``) are inside the box
        and reachable without a branch change (as :meth:`check_linear_path`)."""
        try:
            _, r, _, _ = cartesian_path.circle_through(pose_a[:3, 3], via_mm, pose_b[:3, 3])
        except DataError as exc:
            raise SafetyError(f"{label}: {exc}") from None
        n = int(np.clip(np.ceil(2 * np.pi * r / self.limits.path_step_mm), 8, 1000)) + 1
        pts = cartesian_path.arc_points(pose_a[:3, 3], via_mm, pose_b[:3, 3], n)
        out = np.nonzero(self._outside_box(pts))[0]
        if out.size:
            raise SafetyError(f"{label}: the arc leaves the workspace: {self._box_message(pts[int(out[0])])}")
        self._check_sampled_path(pose_a, pose_b, pts, q_a, q_b, label, "circular")

    def _check_sampled_path(self, pose_a, pose_b, pts, q_a, q_b, label: str, what: str, s=None) -> None:
        """IK at the inner points ``pts[1:-1]`` (orientation slerped), seeded from the joint interpolation;
        ``s`` (n,): their fractions of the move (default: of the length along ``pts``)."""
        qa, qb = np.asarray(q_a, float), np.asarray(q_b, float)
        if s is None:
            cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
            s = cum / cum[-1]
        s = np.asarray(s, float)[1:-1]
        rots = Rotation.from_matrix(np.stack([pose_a[:3, :3], pose_b[:3, :3]]))
        poses = np.repeat(np.eye(4)[None], s.size, axis=0)
        poses[:, :3, :3] = Slerp([0.0, 1.0], rots)(s).as_matrix()
        poses[:, :3, 3] = pts[1:-1]
        seeds = qa + s[:, None] * (qb - qa)
        res = _ik(
            self.robot.dh_nominal, poses, seeds, self.joint_limits_rad, tol_mm=self.limits.ik_tol_mm * 0.1, n_restarts=0
        )
        bad = np.nonzero(~res.success | (res.residual_mm > self.limits.ik_tol_mm))[0]
        if bad.size:
            i = int(bad[0])
            raise SafetyError(
                f"{label}: the {what} path is not reachable at {100 * s[i]:.0f} % of the move, "
                f"{_fmt(poses[i, :3, 3])} mm (IK residual {res.residual_mm[i]:.3g} mm)"
            )
        q_all = np.concatenate([qa[None], res.q_rad, qb[None]])
        jumps = np.abs(np.diff(q_all, axis=0))
        if np.any(jumps > 0.5):
            k, j = np.unravel_index(int(np.argmax(jumps)), jumps.shape)
            where = poses[min(k, s.size - 1), :3, 3]
            raise SafetyError(
                f"{label}: the {what} path crosses a singularity or configuration change near "
                f"{_fmt(where)} mm (joint {j + 1} jumps {np.degrees(jumps[k, j]):.1f} deg)"
            )

    # ------------------------------------------------------------------ programs
    @staticmethod
    def describe(ins, where: str | None = None) -> str:
        """``"line 23: linear move to P2 ('ISO P2')"``."""
        line = getattr(ins, "source_line", None)
        head = f"line {line}" if line is not None else (where or "instruction")
        if isinstance(ins, Move):
            kind = f"{ins.interpolation} move"
            lab = f" ({ins.target.label!r})" if ins.target.label else ""
            return f"{head}: {kind} to {ins.target.name}{lab}"
        return f"{head}: {type(ins).__name__.lower()}"

    def check_joint_motion(self, q_from, target, label: str, *, speed_frac: float, accel_frac: float | None = None) -> np.ndarray:
        """Check a joint-interpolated move from joints ``q_from``; return the target joints.

        ``target`` is a joint vector (6,) rad, or a Cartesian (3,) mm / (4, 4)
        pose solved from ``q_from``. Checks the target, the TCP path, the speed
        fraction, the estimated peak TCP speed and the acceleration fraction.
        """
        qa = self._vector(q_from, 6, label, "start joints")
        t = np.asarray(target, dtype=float)
        q = self.check_joint_target(t, label) if t.shape == (6,) else self.check_cartesian_target(t, label, q_seed=qa)
        self.check_speed(label, speed_frac=speed_frac, accel_frac=accel_frac)
        self._check_joint_motion_path(qa, q, speed_frac, label)
        return q

    def check_linear_motion(self, q_from, target, label: str, *, speed_mm_s: float, accel_frac: float | None = None) -> np.ndarray:
        """Check a straight TCP move from joints ``q_from`` to a (3,) mm or (4, 4) target; return its joints."""
        qa = self._vector(q_from, 6, label, "start joints")
        t = np.asarray(target, dtype=float)
        pose_a = kinematics.fk(self.robot.dh_nominal, qa)
        if t.shape == (3,):
            pose_b = pose_a.copy()
            pose_b[:3, 3] = t
        else:
            pose_b = t
        q = self.check_cartesian_target(pose_b, label, q_seed=qa)
        self.check_speed(label, tcp_speed_mm_s=speed_mm_s, accel_frac=accel_frac)
        self.check_linear_path(pose_a, pose_b, qa, q, label)
        return q

    def _check_joint_motion_path(self, qa, q, speed_frac: float, label: str) -> float:
        self.check_joint_path(qa, q, label)
        v = self.joint_move_peak_tcp_speed(qa, q, speed_frac)
        if v > self.max_tcp_speed_mm_s:
            limit = speed_frac * self.max_tcp_speed_mm_s / v
            raise SafetyError(
                f"{label}: estimated peak TCP speed {v:.0f} mm/s of this joint move exceeds the cap "
                f"{self.max_tcp_speed_mm_s:.0f} mm/s (speed at most {100 * limit:.3g} % here)"
            )
        return v

    def check_move(self, ins: Move, q_prev: np.ndarray, program: Program | None = None, where: str | None = None):
        """Check one move from joints ``q_prev``; return ``(q, peak_tcp_speed_mm_s)``."""
        label = self.describe(ins, where)
        rated = program.rated_tcp_speed_mm_s if program is not None else float(self.robot.max_tcp_speed_mm_s)
        self.check_speed(label, speed_frac=ins.speed_frac)
        t = ins.target
        if isinstance(t, JointTarget):
            q = self.check_joint_target(t.q_rad, label)
        else:
            q = self.check_cartesian_target(t.pose, label, q_seed=q_prev)
        if ins.interpolation != "joint":
            v = ins.speed_frac * rated
            self.check_speed(label, tcp_speed_mm_s=v)
            if ins.ori_speed_deg_s is not None:
                cap = self.limits.max_speed_frac * rated_ori_speed_deg_s(self.robot)
                if ins.ori_speed_deg_s > cap * (1 + 1e-9):
                    raise SafetyError(f"{label}: the tool's turn {ins.ori_speed_deg_s:.6g} deg/s exceeds the cap "
                                      f"{cap:.6g} deg/s")
            pose_a = kinematics.fk(self.robot.dh_nominal, q_prev)
            if ins.interpolation == "circular":
                self.check_position(ins.via.xyz_mm, f"{label} circle point {ins.via.name}")
                self.check_arc_path(pose_a, np.asarray(ins.via.xyz_mm), t.pose, q_prev, q, label)
            else:
                self.check_linear_path(pose_a, t.pose, q_prev, q, label)
        else:
            v = self._check_joint_motion_path(q_prev, q, ins.speed_frac, label)
        return q, v

    def check_program(self, program, q_start=None) -> GateReport:
        """Check every move of a program (or a rendered program) in order.

        Parameters
        ----------
        program : Program or RenderedProgram
            A rendered program carries the line numbers of its main file.
        q_start : array_like, shape (6,), optional
            The robot's joints when the program starts (default: home).

        Returns
        -------
        GateReport

        Raises
        ------
        SafetyError
            Naming the line (or instruction number), the move and its target.
        """
        if isinstance(program, RenderedProgram):
            program = program.program
        if not isinstance(program, Program):
            raise SafetyError(f"check_program needs a Program, got {type(program).__name__}")
        if program.robot_name != self.robot.name:
            raise SafetyError(
                f"program {program.name} was made for robot {program.robot_name!r}, this gate guards {self.robot.name!r}"
            )
        if program.rated_tcp_speed_mm_s > float(self.robot.max_tcp_speed_mm_s) * (1 + 1e-9):
            raise SafetyError(
                f"program {program.name}: rated TCP speed {program.rated_tcp_speed_mm_s:g} mm/s is above "
                f"the robot's {float(self.robot.max_tcp_speed_mm_s):g} mm/s"
            )
        self.check_speed(f"program {program.name}", accel_frac=program.accel_frac)
        q = self.robot.home_q_rad if q_start is None else self.check_joint_target(q_start, "start pose")
        q = np.array(q, dtype=float)
        qs: list[np.ndarray] = []
        peak = 0.0

        def run(ins, where: str, record: bool) -> None:
            nonlocal q, peak
            if isinstance(ins, Move):
                q_new, v = self.check_move(ins, q, program, where=where)
                peak = max(peak, v)
                if record:
                    qs.append(q_new)
                q = q_new
            elif not isinstance(ins, (Dwell, CycleMark)):
                raise SafetyError(f"{self.describe(ins, where)}: unknown instruction")

        for i, s in enumerate(program.statements):
            if isinstance(s, Loop):
                for k, b in enumerate(s.body):
                    run(b, f"statement {i + 1}.{k + 1}", True)
                if s.count > 1:  # second pass: from the body's end back to its start
                    for k, b in enumerate(s.body):
                        run(b, f"statement {i + 1}.{k + 1}", False)
            else:
                run(s, f"statement {i + 1}", True)
        q_arr = np.array(qs).reshape(-1, 6)
        tcp = kinematics.tool_position(self.robot.dh_nominal, q_arr) if len(q_arr) else np.zeros((0, 3))
        return GateReport(q_rad=q_arr, tcp_mm=tcp, peak_tcp_speed_mm_s=peak)


def default_limits(robot, margin_mm: float = 0.0) -> SafetyLimits:
    """Permissive limits from the robot alone: a box around the reach, rated caps.

    The box is centred on the base and ``reach + margin`` wide in x and y,
    ``[-reach, reach]`` in z; for a cell, configure the real box instead.
    """
    dh = np.asarray(robot.dh_nominal, float)
    reach = float(np.sum(np.abs(dh[:, 0])) + np.sum(np.abs(dh[:, 2]))) + margin_mm
    return SafetyLimits(
        workspace_min_mm=(-reach, -reach, -reach),
        workspace_max_mm=(reach, reach, reach),
        max_tcp_speed_mm_s=float(robot.max_tcp_speed_mm_s),
    )
