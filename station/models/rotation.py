"""Rotation vectors and UR poses, as URScript moves and RTDE samples carry them.

One implementation for the UR driver (:mod:`drivers.ur`, the pose of a URScript
move, the TCP pose of a sample) and the UR fake (:mod:`fakes.ur`, every RTDE
sample's TCP pose and angular speed, the target of a move): a UR pose is
``[x, y, z, rx, ry, rz]`` in metres and a rotation vector (rad); the station's
homogeneous transforms are in mm.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rotvec_of", "rotvec_to_matrix", "matrix_to_rotvec", "ur_pose_to_T", "T_to_ur_pose"]


def _rotvec_scale(angle):
    """``angle / sin(angle / 2)``, by its series below 1e-3 rad (scalar or array)."""
    if np.ndim(angle) == 0:
        if angle > 1e-3:
            return angle / math.sin(0.5 * angle)
        a2 = angle * angle
        return 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
    small = angle <= 1e-3
    out = np.empty_like(angle)
    out[~small] = angle[~small] / np.sin(0.5 * angle[~small])
    a2 = angle[small] ** 2
    out[small] = 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
    return out


def _quaternion_terms(r00, r01, r02, r10, r11, r12, r20, r21, r22, k):
    """Unnormalised quaternion ``(x, y, z, w)`` of a rotation matrix from its ``k``-th largest term
    (Shepperd: 0-2 a diagonal term, 3 the trace), element-wise."""
    tr = r00 + r11 + r22
    rows = ((1.0 + r00 - r11 - r22, r01 + r10, r02 + r20, r21 - r12),
            (r01 + r10, 1.0 + r11 - r00 - r22, r12 + r21, r02 - r20),
            (r02 + r20, r12 + r21, 1.0 + r22 - r00 - r11, r10 - r01),
            (r21 - r12, r02 - r20, r10 - r01, 1.0 + tr))
    return rows[k] if isinstance(k, int) else rows


def rotvec_of(R) -> np.ndarray:
    """Rotation vectors (N, 3) of rotation matrices (N, 3, 3), angle in [0, pi].

    Through the unit quaternion taken from whichever of ``1 + trace`` and the
    diagonal terms is largest (Shepperd's choice: no division by a small
    number), with ``w >= 0``; the vector is ``angle / sin(angle / 2)`` times
    the quaternion's vector part. The UR fake's RTDE stream calls this for every
    batch of samples (mostly one or two): a few rows go through plain floats
    (a scipy ``Rotation`` per batch cost 100 us), many through arrays.
    """
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    if len(R) <= 8:
        out = []
        for m in R.reshape(-1, 9).tolist():
            d = (m[0], m[4], m[8], m[0] + m[4] + m[8])
            x, y, z, w = _quaternion_terms(*m, max(range(4), key=d.__getitem__))
            if w < 0:
                x, y, z, w = -x, -y, -z, -w
            s = math.sqrt(x * x + y * y + z * z)
            angle = 2.0 * math.atan2(s, w)
            f = _rotvec_scale(angle) / math.sqrt(s * s + w * w)
            out.append((f * x, f * y, f * z))
        return np.array(out, dtype=float).reshape(-1, 3)
    m = R.reshape(-1, 9).T
    k = np.argmax(np.stack([m[0], m[4], m[8], m[0] + m[4] + m[8]]), axis=0)
    cand = np.array(_quaternion_terms(*m, None))  # (4 choices, 4 terms, N)
    q = cand[k, :, np.arange(len(R))]  # (N, 4)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    s = np.linalg.norm(q[:, :3], axis=1)
    return _rotvec_scale(2.0 * np.arctan2(s, q[:, 3]))[:, None] * q[:, :3]


def rotvec_to_matrix(rv) -> np.ndarray:
    """Rotation vectors (..., 3) -> rotation matrices (..., 3, 3) (Rodrigues).

    One vector goes through plain floats (an identification turns one per step: the array path costs
    about 100 us of small operations), the same formula term by term.
    """
    rv = np.asarray(rv, dtype=float)
    if rv.shape == (3,):
        return _rotvec_to_matrix_one(*rv.tolist())
    theta = np.linalg.norm(rv, axis=-1)[..., None, None]
    k = np.where(theta[..., 0] > 1e-12, rv / np.where(theta[..., 0] > 1e-12, theta[..., 0], 1.0), 0.0)
    K = np.zeros(rv.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def _rotvec_to_matrix_one(x: float, y: float, z: float) -> np.ndarray:
    theta = math.sqrt(x * x + y * y + z * z)
    if theta <= 1e-12:   # (NaN goes on, and gives NaN as the array path does)
        return np.eye(3)
    kx, ky, kz = x / theta, y / theta, z / theta
    K = ((0.0, -kz, ky), (kz, 0.0, -kx), (-ky, kx, 0.0))
    s, c = math.sin(theta), 1 - math.cos(theta)
    return np.array([[(1.0 if i == j else 0.0) + s * K[i][j]
                      + c * (K[i][0] * K[0][j] + K[i][1] * K[1][j] + K[i][2] * K[2][j])
                      for j in range(3)] for i in range(3)])


def matrix_to_rotvec(R) -> np.ndarray:
    """Rotation matrix (3, 3) -> rotation vector (3,), robust near 0 and pi (through the quaternion)."""
    return rotvec_of(np.asarray(R, dtype=float).reshape(1, 3, 3))[0]


def ur_pose_to_T(pose) -> np.ndarray:
    """UR pose(s) ``[x, y, z, rx, ry, rz]`` (m, rotation vector) -> (..., 4, 4) in mm."""
    p = np.asarray(pose, dtype=float)
    T = np.zeros(p.shape[:-1] + (4, 4))
    T[..., :3, :3] = rotvec_to_matrix(p[..., 3:])
    T[..., :3, 3] = 1000.0 * p[..., :3]
    T[..., 3, 3] = 1.0
    return T


def T_to_ur_pose(T) -> np.ndarray:
    """Transforms (N, 4, 4) in mm -> UR poses (N, 6) (m, rotation vector)."""
    T = np.asarray(T, dtype=float).reshape(-1, 4, 4)
    out = np.empty((len(T), 6))
    out[:, :3] = T[:, :3, 3] / 1000.0
    out[:, 3:] = rotvec_of(T[:, :3, :3])
    return out
