"""The orientation a simulated 6-DoF target (a Leica T-Mac on the tool) reports to the tracker.

The T-Mac's frame is taken as calibrated to the tool centre point (its
tool frame is the robot's TCP frame, as a plant sets it up), so the true
orientation it shows is the arm's true TCP rotation, seen from the tracker:
``R_tracker = R_sys . (tracker_T_base)_R . R_base_tool(t - latency)``, where
``R_sys`` is the tracker session's systematic small rotation (the one its
positions carry, :meth:`fakes.sim.tracker.TrackerModel.reading`). On top
comes the reading noise: a small rotation about the tracker's axes, each
component normal with sd :data:`T_MAC_ANGLE_SD_DEG` (the order of the T-Mac
data sheet's angular accuracy), drawn per grid index from the tracker's
seed (the same instant measured twice reads the same, however a stream is
chunked).
"""

from __future__ import annotations

import numpy as np

from station.models.rotation import rotvec_of, rotvec_to_matrix

#: sd of each of the three small noise rotations of a 6-DoF reading, deg
T_MAC_ANGLE_SD_DEG = 0.01
_BLOCK = 65536


def unit_angle_noise(seed: int, k) -> np.ndarray:
    """Standard normal (N, 3) tied to grid indices ``k`` (N,): blocks of :data:`_BLOCK` from ``(seed, 6)``."""
    k = np.asarray(k, dtype=np.int64).reshape(-1)
    out = np.empty((k.size, 3))
    blocks = np.floor_divide(k, _BLOCK)
    for b in np.unique(blocks):  # a few blocks per batch
        sel = blocks == b
        draw = np.random.default_rng([int(seed), 6, int(b) + (1 << 40)]).standard_normal((_BLOCK, 3))
        out[sel] = draw[k[sel] - int(b) * _BLOCK]
    return out


def matrices_to_quat_wxyz(R) -> np.ndarray:
    """Unit quaternions (N, 4), scalar first and >= 0, of rotation matrices (N, 3, 3) (through the rotation
    vector: ``q = (cos(theta/2), sin(theta/2) axis)``)."""
    rv = rotvec_of(np.asarray(R, dtype=float).reshape(-1, 3, 3))
    ang = np.linalg.norm(rv, axis=1)
    axis = rv / np.where(ang > 0, ang, 1.0)[:, None]
    q = np.column_stack([np.cos(ang / 2), axis * np.sin(ang / 2)[:, None]])
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def target_rotation(tracker, tool_pose_fn, t_sim, angle_sd_deg: float = T_MAC_ANGLE_SD_DEG) -> np.ndarray:
    """Rotation matrices (N, 3, 3) the target reports at world times ``t_sim`` (see the module docstring)."""
    t = np.asarray(t_sim, dtype=float).reshape(-1)
    R_bt = np.asarray(tool_pose_fn(t - tracker.latency_s), dtype=float).reshape(-1, 4, 4)[:, :3, :3]
    R_tb = tracker.tracker_T_base[:3, :3]
    R_sys = rotvec_to_matrix(tracker.systematic_rotvec_rad)
    noise = np.radians(angle_sd_deg) * unit_angle_noise(tracker.seed, tracker._grid_index(t))
    R_noise = rotvec_to_matrix(noise)
    return R_noise @ (R_sys @ R_tb) @ R_bt
