"""Tool orientation from a 6-DoF target's quaternions, as the angles a, b, c of ISO 9283 (pure functions).

The orientation figures (:mod:`station.analysis.iso9283.characteristics`,
``OrientationAR``) take the angles ``(a, b, c)`` of ``R = Rz(c) Ry(b) Rx(a)``
(rotations about the x, y, z axes of the robot base frame, the convention of
:func:`station.analysis.iso9283.stop_list.rotation_abc`), per sample. Seed
000 sec. 3.1 says ISO 9283 states pose accuracy and repeatability for the
orientation as well as the position, and gives the position's formulas only
(eqs. (1)-(2)); the orientation's are the standard's own, on the same
pattern per angle: ``AP_a = a_bar - a_c`` and ``RP_a = +/- 3 S_a`` with
``S_a`` the sample standard deviation of the attained ``a_j`` (so for b, c).
"""

from __future__ import annotations

import numpy as np

from station.errors import DataError


def quat_to_matrices(quat_wxyz) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of unit quaternions (N, 4), scalar first."""
    q = np.asarray(quat_wxyz, dtype=float).reshape(-1, 4)
    norm = np.linalg.norm(q, axis=1)
    if not np.all(np.abs(norm - 1.0) <= 1e-6):
        i = int(np.flatnonzero(~(np.abs(norm - 1.0) <= 1e-6))[0])
        raise DataError(f"orientation sample {i}: quaternion of norm {norm[i]:.9g} is not a unit quaternion")
    w, x, y, z = (q / norm[:, None]).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def abc_of_matrices(R) -> np.ndarray:
    """Angles ``(a, b, c)`` (N, 3), rad, of rotation matrices (N, 3, 3) with ``R = Rz(c) Ry(b) Rx(a)``."""
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    a = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    b = np.arcsin(np.clip(-R[:, 2, 0], -1.0, 1.0))
    c = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return np.column_stack([a, b, c])


def abc_in_base(quat_wxyz_tracker, R_registration) -> np.ndarray:
    """The tool's angles ``(a, b, c)`` (N, 3), rad, in the robot base frame, from the target's quaternions in
    the tracker frame and the registration ``p_tracker = R p_base + t``: ``R_base = R^T R_tracker``."""
    Rt = quat_to_matrices(quat_wxyz_tracker)
    Rr = np.asarray(R_registration, dtype=float)
    return abc_of_matrices(Rr.T[None, :, :] @ Rt)
