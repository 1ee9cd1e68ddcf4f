"""Rotation vectors of rotation matrices, as UR poses and RTDE speeds carry them.

One implementation for the UR driver (:mod:`drivers.ur`, the pose of a URScript
move) and the UR fake (:mod:`fakes.ur`, every RTDE sample's TCP pose and angular
speed).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rotvec_of"]


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
