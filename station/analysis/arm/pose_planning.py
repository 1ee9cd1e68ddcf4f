"""Where an arm calibration measures: candidate poses, and an order the safety gate passes.

The geometry behind a calibration plan (:mod:`procedures.arm_calibration`):
candidate tool poses spread over the gate's box (tracker) or inside a fixed
scanner's field, solved by the nominal inverse kinematics and kept when
admissible (:func:`station.analysis.pose_selection.admissible`), and the
nearest-first order in joint space with every joint path checked by the gate.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from station.analysis.arm.pose_selection import admissible
from station.errors import ConfigError, SafetyError
from station.models import kinematics as kin
from station.models.robots import RobotSpec
from station.programs.builders import TOOL_DOWN
from station.safety import SafetyGate

__all__ = ["PRE_DEG", "candidate_poses", "scanner_frame", "in_scanner_field", "scanner_candidate_poses",
           "order_poses", "along_chain"]

#: every pose is approached with each joint moving in + for its last degrees
PRE_DEG = 2.0


def candidate_poses(robot: RobotSpec, gate: SafetyGate, n: int, rng: np.random.Generator, *, tilt_deg: float,
                    instrument_mm=None, half_angle_deg: float = 30.0) -> np.ndarray:
    """Admissible candidate joint vectors (C, 6): tool points in the gate's box, tool tilted <= ``tilt_deg``."""
    lo, hi = gate.box_min, gate.box_max
    margin = 0.05 * (hi - lo)
    p = rng.uniform(lo + margin, hi - margin, (n, 3))
    # tilt about a random horizontal axis, any turn about the tool axis within +-90 deg
    axis = rng.normal(size=(n, 3))
    axis[:, 2] = 0.0
    axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    tilt = np.radians(tilt_deg) * np.sqrt(rng.uniform(0.0, 1.0, n))
    yaw = rng.uniform(-np.pi / 2, np.pi / 2, n)
    R = (Rotation.from_rotvec(axis * tilt[:, None]) * Rotation.from_matrix(TOOL_DOWN)
         * Rotation.from_rotvec(np.column_stack([np.zeros(n), np.zeros(n), yaw]))).as_matrix()
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    sol = kin.ik(robot.dh_nominal, T, q0=np.tile(robot.home_q_rad, (n, 1)), joint_limits_rad=gate.joint_limits_rad,
                 n_restarts=4, seed=int(rng.integers(2**31)))
    q = sol.q_rad[sol.success]
    ok = admissible(robot.dh_nominal, q, joint_limits_rad=gate.joint_limits_rad, box_min_mm=lo, box_max_mm=hi,
                    instrument_mm=instrument_mm, half_angle_deg=half_angle_deg)
    return q[ok]


def scanner_frame(eye_mm, look_at_mm) -> np.ndarray:
    """Approximate scanner pose (4, 4) in the base frame: eye at ``eye_mm``, optical axis ``+z`` at ``look_at_mm``."""
    eye = np.asarray(eye_mm, float)
    z = np.asarray(look_at_mm, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, eye
    return T


def in_scanner_field(T_scanner: np.ndarray, p_mm: np.ndarray, *, fov_mm: float, working_distance_mm: float,
                     depth_range_mm, margin_mm: float) -> np.ndarray:
    """(N,) bool: base-frame points ``margin_mm`` inside the scanner's viewing frustum."""
    s = (np.asarray(p_mm, float) - T_scanner[:3, 3]) @ T_scanner[:3, :3]
    tan_half = 0.5 * fov_mm / working_distance_mm
    lim = tan_half * s[:, 2] - margin_mm
    return ((s[:, 2] >= depth_range_mm[0] + margin_mm) & (s[:, 2] <= depth_range_mm[1] - margin_mm)
            & (np.abs(s[:, 0]) <= lim) & (np.abs(s[:, 1]) <= lim))


def scanner_candidate_poses(robot: RobotSpec, gate: SafetyGate, n: int, rng: np.random.Generator, *, eye_mm,
                            look_at_mm, fov_mm: float = 450.0, working_distance_mm: float = 700.0,
                            depth_range_mm=(450.0, 1100.0), half_angle_deg: float = 30.0,
                            margin_mm: float = 60.0) -> np.ndarray:
    """Admissible candidate joint vectors (C, 6) for the scanner: the jig corner (the TCP) in its field.

    Tool points are drawn in the scanner's frustum (depths within 0.3 field
    widths of the working distance, ``margin_mm`` inside every side: the jig
    reaches that far behind its corner); the tool z axis (the jig's view
    axis, :mod:`station.models.jig`) points at the scanner's eye within
    0.8 ``half_angle_deg``, turned about itself by up to +-90 deg from the
    home orientation. Solved by the nominal inverse kinematics near home and
    kept when the gate's box and joint limits allow them and the corner faces
    the eye within ``half_angle_deg``.
    """
    S = scanner_frame(eye_mm, look_at_mm)
    eye = S[:3, 3]
    tan_half = 0.5 * fov_mm / working_distance_mm
    z_lo = max(depth_range_mm[0] + margin_mm, working_distance_mm - 0.3 * fov_mm)
    z_hi = min(depth_range_mm[1] - margin_mm, working_distance_mm + 0.3 * fov_mm)
    if z_hi <= z_lo:
        raise ConfigError("arm_calibration: the scanner's depth range leaves no room for the jig "
                          f"({depth_range_mm} with a {margin_mm:g} mm margin)")
    zs = rng.uniform(z_lo, z_hi, n)
    half = np.maximum(tan_half * zs - margin_mm, 0.0)
    ps = np.column_stack([rng.uniform(-1, 1, n) * half, rng.uniform(-1, 1, n) * half, zs])
    p = ps @ S[:3, :3].T + eye
    # tool z at the eye: the home tool frame turned the shortest way, then rolled and tilted
    u = eye - p
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    R_home = kin.fk(robot.dh_nominal, robot.home_q_rad)[:3, :3]
    z_home = R_home[:, 2]
    axis = np.cross(z_home, u)
    s_ang = np.linalg.norm(axis, axis=1)
    ang = np.arctan2(s_ang, u @ z_home)
    rv = axis / np.maximum(s_ang, 1e-12)[:, None] * ang[:, None]
    roll = rng.uniform(-np.pi / 2, np.pi / 2, n)
    tilt_axis = rng.normal(size=(n, 3))
    tilt_axis -= np.einsum("ij,ij->i", tilt_axis, u)[:, None] * u
    tilt_axis /= np.maximum(np.linalg.norm(tilt_axis, axis=1, keepdims=True), 1e-12)
    tilt = np.radians(0.8 * half_angle_deg) * np.sqrt(rng.uniform(0.0, 1.0, n))
    R = (Rotation.from_rotvec(tilt_axis * tilt[:, None]) * Rotation.from_rotvec(rv)
         * Rotation.from_matrix(np.tile(R_home, (n, 1, 1)))
         * Rotation.from_rotvec(np.column_stack([np.zeros(n), np.zeros(n), roll]))).as_matrix()
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = p
    sol = kin.ik(robot.dh_nominal, T, q0=np.tile(robot.home_q_rad, (n, 1)), joint_limits_rad=gate.joint_limits_rad,
                 n_restarts=4, seed=int(rng.integers(2**31)))
    q = sol.q_rad[sol.success]
    ok = admissible(robot.dh_nominal, q, joint_limits_rad=gate.joint_limits_rad, box_min_mm=gate.box_min,
                    box_max_mm=gate.box_max, instrument_mm=eye, half_angle_deg=half_angle_deg)
    ok &= in_scanner_field(S, kin.tool_position(robot.dh_nominal, q), fov_mm=fov_mm,
                           working_distance_mm=working_distance_mm, depth_range_mm=depth_range_mm,
                           margin_mm=0.5 * margin_mm)
    return q[ok]


def _path_ok(gate: SafetyGate, q_a: np.ndarray, q_b: np.ndarray) -> bool:
    try:
        gate.check_joint_path(q_a, q_b - np.radians(PRE_DEG), "path")
        gate.check_joint_path(q_b - np.radians(PRE_DEG), q_b, "path")
        gate.check_joint_target(q_b - np.radians(PRE_DEG), "pre-position")
    except SafetyError:
        return False
    return True


def order_poses(gate: SafetyGate, q_start: np.ndarray, q: np.ndarray) -> tuple[list[int], list[int]]:
    """Nearest-first order in joint space with every path passed by the gate; (order, poses left out)."""
    left = list(range(q.shape[0]))
    order: list[int] = []
    dropped: list[int] = []
    cur = q_start
    while left:
        d = np.max(np.abs(q[left] - cur), axis=1)
        for j in np.argsort(d):
            k = left[int(j)]
            if _path_ok(gate, cur, q[k]):
                order.append(k)
                left.remove(k)
                cur = q[k]
                break
        else:
            # no pose is reachable from here along a safe joint path: leave the nearest out
            dropped.append(left.pop(int(np.argmin(d))))
    return order, dropped


def along_chain(waypoints: np.ndarray, q_now: np.ndarray, goal: int, tol: float) -> np.ndarray | None:
    """The way to waypoint ``goal`` of a chain of joint-interpolated moves, along the chain itself.

    A plan's path ``W[0] -> W[1] -> ... -> W[M-1]`` (each move linear in
    joint space) was checked move by move. An arm left somewhere on it (a
    run stopped inside a batch; an arm at home, where the path begins) is
    taken to ``W[goal]`` over those moves only, back or forward, so that no
    joint path the plan did not check is driven.

    Parameters
    ----------
    waypoints : array_like, shape (M, 6)
        The chain, in the order it is driven (rad, or any unit shared with ``q_now`` and ``tol``).
    q_now : array_like, shape (6,)
        Where the arm stands.
    goal : int
        The waypoint to reach (0 <= goal < M).
    tol : float
        How far (largest joint difference) from the chain the arm may stand and still be on it.

    Returns
    -------
    ndarray, shape (K, 6), or None
        The waypoints to drive through, in order, ending at ``W[goal]``: from
        the move nearest to the arm (the earlier of two it is equally near:
        it stands at a waypoint), that move's end towards the goal first,
        without a leading waypoint the arm already stands at; empty when it
        stands at ``W[goal]``; None when it is on no move of the chain.
    """
    w = np.asarray(waypoints, dtype=float).reshape(-1, 6)
    q = np.asarray(q_now, dtype=float).reshape(6)
    if not 0 <= goal < len(w):
        raise ValueError(f"goal {goal} is no waypoint of a chain of {len(w)}")
    if np.max(np.abs(q - w[goal])) <= tol:
        return w[:0]
    d = np.diff(w, axis=0)  # the moves
    dd = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", q - w[:-1], d) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    dist = np.max(np.abs(w[:-1] + s[:, None] * d - q), axis=1)  # to the nearest point of each move
    if not len(dist) or dist.min() > tol:
        return None
    j = int(np.flatnonzero(dist <= dist.min() + 1e-9)[0])  # the nearest; of equals (a waypoint), the earlier
    way = w[j + 1:goal + 1] if j < goal else w[goal:j + 1][::-1]
    return way[1:] if np.max(np.abs(q - way[0])) <= tol else way
