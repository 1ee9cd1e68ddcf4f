"""Motion programs of the station's procedures, as dialect-neutral models.

* :func:`iso_pose_program` -- ISO 9283 pose cycle of seed 000 sec. 3.1.3:
  wait at P1, then visit P2, P3, P4, P5, P1 with a fine stop and a dwell
  (0.5 s) at each, ``n`` cycles, at a fraction of the rated speed; used for
  AP, RP (eq. (1)-(2)), overshoot and settling (eq. (5)-(6)) and distance
  accuracy (eq. (8)-(9)).
* :func:`vap_program` -- multi-directional pose accuracy (sec. 3.3,
  eq. (7)): each pose approached along three mutually orthogonal directions
  parallel to the base axes, a fine stop and a dwell after each approach.
* :func:`calibration_program` -- a list of joint configurations (seed 002
  calibration poses) visited with a dwell for the measurement.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from station.errors import ConfigError
from station.models import kinematics
from station.programs.program import (
    CartesianTarget,
    CycleMark,
    Dwell,
    JointTarget,
    Loop,
    Move,
    Program,
    check_name,
    check_number,
    check_text,
    quat_from_matrix,
)

#: time in which the rated TCP speed is reached at 100 % acceleration, s;
#: defines the rated TCP acceleration where the robot data give none
RATED_ACCEL_TIME_S = 0.5

#: default tool orientation: tool z axis pointing down (-z of the base), tool x along base +x
TOOL_DOWN = np.diag([1.0, -1.0, -1.0])

_DIRECTIONS = {"+x": (0, 1.0), "-x": (0, -1.0), "+y": (1, 1.0), "-y": (1, -1.0), "+z": (2, 1.0), "-z": (2, -1.0)}


def rated_tcp_accel_mm_s2(robot) -> float:
    """Rated TCP acceleration: the robot's own figure, else rated speed / 0.5 s."""
    own = getattr(robot, "max_tcp_accel_mm_s2", None)
    if own:
        return float(own)
    return float(robot.max_tcp_speed_mm_s) / RATED_ACCEL_TIME_S


def home_orientation(robot) -> tuple[float, float, float, float]:
    """Tool orientation (unit quaternion w, x, y, z) at the robot's home pose."""
    t = kinematics.fk(robot.dh_nominal, robot.home_q_rad)
    return quat_from_matrix(t[:3, :3])


def _orientation(robot, orientation) -> tuple[float, float, float, float]:
    if orientation is None:
        return quat_from_matrix(TOOL_DOWN)
    arr = np.asarray(orientation, dtype=float)
    if arr.shape == (3, 3):
        return quat_from_matrix(arr)
    if arr.shape == (4,):
        return tuple(float(v) for v in arr)  # validated by CartesianTarget
    raise ConfigError(f"orientation must be a 3x3 rotation matrix or a quaternion (w, x, y, z), got shape {arr.shape}")


def _poses(poses: Mapping[str, Sequence[float]], quat, what: str) -> list[CartesianTarget]:
    if not isinstance(poses, Mapping) or not poses:
        raise ConfigError(f"{what}: poses must be a non-empty mapping name -> (x, y, z) mm")
    return [CartesianTarget(check_name(n, f"{what} pose"), tuple(p), quat, label=f"{what} {n}") for n, p in poses.items()]


def _program(robot, name, statements, *, accel_frac, title) -> Program:
    return Program(
        name=check_name(name, "program"),
        robot_name=robot.name,
        rated_tcp_speed_mm_s=float(robot.max_tcp_speed_mm_s),
        statements=tuple(statements),
        accel_frac=accel_frac,
        title=check_text(title, "program title"),
        rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(robot),
    )


def iso_pose_program(
    robot,
    poses: Mapping[str, Sequence[float]],
    *,
    cycles: int = 30,
    dwell_s: float = 0.5,
    speed_frac: float = 1.0,
    accel_frac: float = 1.0,
    approach_speed_frac: float = 0.2,
    interpolation: str = "linear",
    orientation=None,
    name: str = "ISO_POSE",
    title: str = "ISO 9283 pose cycle",
) -> Program:
    """ISO 9283 pose cycle (seed 000 sec. 3.1.3).

    Parameters
    ----------
    robot : RobotSpec
    poses : mapping of str to (3,) float
        Commanded positions in cycle order, the first one being P1 (where the
        cycle starts and ends), e.g. ``{"P1": ..., "P2": ..., ..., "P5": ...}``.
    cycles : int
        Number of cycles ``n`` (ISO: 30).
    dwell_s : float
        Stop at each pose, s (seed: 0.5 s).
    speed_frac, accel_frac : float
        Fraction of the rated speed and acceleration (seed: 100 %).
    approach_speed_frac : float
        Speed of the first joint move from wherever the robot stands to P1.
    interpolation : {"linear", "joint"}
        Motion between the poses.
    orientation : (3, 3) or (4,) array_like, optional
        Tool orientation at every pose; default :data:`TOOL_DOWN` (a tool
        pointing down keeps the wrist away from its singularity across a
        cube in front of the arm; the gate refuses paths that cross it).
    name, title : str
        Program identifier and free-text title.

    Returns
    -------
    Program
        ``MoveJ P1; Dwell; Loop(cycles) {P2, P3, ..., P1 each with a dwell; CycleMark}``.
    """
    quat = _orientation(robot, orientation)
    targets = _poses(poses, quat, "ISO")
    if len(targets) < 2:
        raise ConfigError("ISO pose cycle needs at least two poses")
    dwell = Dwell(check_number(dwell_s, "dwell_s", lo=0.0, hi=60.0))
    body: list = []
    for t in targets[1:] + targets[:1]:
        body += [Move(t, interpolation, speed_frac), dwell]
    body.append(CycleMark())
    statements = [Move(targets[0], "joint", min(approach_speed_frac, speed_frac)), dwell, Loop(cycles, tuple(body))]
    return _program(robot, name, statements, accel_frac=accel_frac, title=title)


def approach_target(pose: CartesianTarget, direction: str, distance_mm: float) -> CartesianTarget:
    """Pre-point from which ``pose`` is approached along ``direction`` ("+x", "-z", ...)."""
    if direction not in _DIRECTIONS:
        raise ConfigError(f"approach direction {direction!r} is not one of {', '.join(_DIRECTIONS)}")
    axis, sign = _DIRECTIONS[direction]
    xyz = list(pose.xyz_mm)
    xyz[axis] -= sign * distance_mm
    suffix = ("a" + direction[1]) + ("n" if sign < 0 else "")
    return CartesianTarget(
        check_name(f"{pose.name}_{suffix}", "approach target"),
        tuple(xyz),
        pose.quat_wxyz,
        label=f"approach {pose.name} along {direction}",
    )


def vap_program(
    robot,
    poses: Mapping[str, Sequence[float]],
    *,
    cycles: int = 30,
    dwell_s: float = 0.5,
    speed_frac: float = 1.0,
    accel_frac: float = 1.0,
    approach_mm: float = 100.0,
    directions: Sequence[str] = ("+x", "+y", "+z"),
    approach_speed_frac: float = 0.2,
    pre_dwell_s: float = 0.2,
    orientation=None,
    name: str = "ISO_VAP",
    title: str = "ISO 9283 multi-directional pose accuracy",
) -> Program:
    """Three-direction approaches for vAP (seed 000 sec. 3.3, eq. (7)).

    Each cycle visits every pose three times: a linear move to the pre-point
    ``pose - approach_mm * d`` (a fine stop and ``pre_dwell_s`` there, so each
    approach starts from rest and its direction is defined by the pre-point)
    and a linear move along ``d`` onto the pose, then a fine stop and a dwell;
    ``d`` runs over ``directions`` (three
    mutually orthogonal base axes, signs chosen so the pre-points stay in the
    test cube).

    Returns
    -------
    Program
        :func:`~station.programs.program.expected_stops` reports, for each stop,
        the pre-point it came from (``approach_from``), i.e. the direction.
    """
    dirs = tuple(directions)
    if len(dirs) != 3 or len({d.lstrip("+-") for d in dirs if isinstance(d, str)}) != 3:
        raise ConfigError(f"directions must name three different axes, e.g. ('+x', '+y', '+z'), got {dirs!r}")
    dist = check_number(approach_mm, "approach_mm", lo=1.0, hi=1000.0)
    quat = _orientation(robot, orientation)  # default TOOL_DOWN, as iso_pose_program
    targets = _poses(poses, quat, "vAP")
    dwell = Dwell(check_number(dwell_s, "dwell_s", lo=0.0, hi=60.0))
    pre_dwell = Dwell(check_number(pre_dwell_s, "pre_dwell_s", lo=0.0, hi=60.0))
    body: list = []
    for t in targets:
        for d in dirs:
            pre = [Move(approach_target(t, d, dist), "linear", speed_frac)] + ([pre_dwell] if pre_dwell_s > 0 else [])
            body += pre + [Move(t, "linear", speed_frac), dwell]
    body.append(CycleMark())
    first = approach_target(targets[0], dirs[0], dist)
    statements = [Move(first, "joint", min(approach_speed_frac, speed_frac)), Loop(cycles, tuple(body))]
    return _program(robot, name, statements, accel_frac=accel_frac, title=title)


def calibration_program(
    robot,
    q_deg,
    *,
    dwell_s: float = 1.0,
    speed_frac: float = 0.2,
    accel_frac: float = 0.5,
    name: str = "CALIB",
    title: str = "kinematic calibration poses",
) -> Program:
    """Visit joint configurations ``q_deg`` (N, 6) with a fine stop and a dwell each.

    The targets are named ``Q0001`` ... in list order, so a measurement of
    stop ``k`` belongs to row ``k`` of ``q_deg``.
    """
    q = np.asarray(q_deg, dtype=float)
    if q.ndim != 2 or q.shape[1] != 6 or q.shape[0] == 0:
        raise ConfigError(f"q_deg must have shape (N, 6) with N >= 1, got {q.shape}")
    if q.shape[0] > 9999:
        raise ConfigError(f"q_deg has {q.shape[0]} poses, at most 9999 fit a program")
    dwell = Dwell(check_number(dwell_s, "dwell_s", lo=0.0, hi=600.0))
    statements: list = []
    for i, row in enumerate(q):
        statements += [Move(JointTarget(f"Q{i + 1:04d}", tuple(row), label=f"calibration pose {i + 1}"), "joint", speed_frac), dwell]
    return _program(robot, name, statements, accel_frac=accel_frac, title=title)
