"""Rigid registration of the instrument frame to the robot base frame.

ISO 9283 characteristics are stated in the robot's base frame, while a laser
tracker measures in its own. The station measures the tool point at a set of
registration poses spread over the test cube and finds the rigid transform
``p_tracker = R @ p_base + t`` that best fits the commanded (nominal)
positions, in the least-squares sense (the SVD solution of the orthogonal
Procrustes problem, with the determinant fixed to +1 so it is a rotation,
not a reflection).

What the fit absorbs: any rigid part (a common offset and a small rotation)
of the robot's own positioning errors at the registration poses. AP is then
the accuracy relative to the best-fit base frame — the usual practice when the
base frame is not measured mechanically. The report says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.errors import DataError, InsufficientDataError


@dataclass(frozen=True)
class Registration:
    """``p_tracker = R @ p_base + t``.

    Attributes
    ----------
    R : ndarray, shape (3, 3)
    t_mm : ndarray, shape (3,)
    residuals_mm : ndarray, shape (N,)
        Distance between measured and transformed commanded points.
    rms_mm : float
    n : int
    """

    R: np.ndarray
    t_mm: np.ndarray
    residuals_mm: np.ndarray
    rms_mm: float
    n: int

    @property
    def T(self) -> np.ndarray:
        """4x4 homogeneous transform base -> tracker."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t_mm
        return T

    def to_tracker(self, p_base_mm) -> np.ndarray:
        p = np.asarray(p_base_mm, dtype=float)
        return p @ self.R.T + self.t_mm

    def to_base(self, p_tracker_mm) -> np.ndarray:
        p = np.asarray(p_tracker_mm, dtype=float)
        return (p - self.t_mm) @ self.R


def fit_rigid(p_base_mm, p_tracker_mm) -> Registration:
    """Least-squares rigid transform from base-frame points to tracker-frame points.

    Parameters
    ----------
    p_base_mm : array_like, shape (N, 3)
        Commanded (nominal) tool positions in the robot base frame.
    p_tracker_mm : array_like, shape (N, 3)
        The same points measured by the tracker.

    Returns
    -------
    Registration

    Raises
    ------
    DataError
        Shapes differ or values are not finite.
    InsufficientDataError
        Fewer than 3 points, or the points are (nearly) collinear so the
        rotation is not determined.
    """
    a = np.asarray(p_base_mm, dtype=float)
    b = np.asarray(p_tracker_mm, dtype=float)
    for name, arr in (("p_base_mm", a), ("p_tracker_mm", b)):
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise DataError(f"{name} must have shape (N, 3), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise DataError(f"{name} contains NaN or infinite values")
    if a.shape != b.shape:
        raise DataError(f"p_base_mm {a.shape} and p_tracker_mm {b.shape} must have the same shape")
    if a.shape[0] < 3:
        raise InsufficientDataError(f"registration needs at least 3 points, got {a.shape[0]}")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    A, B = a - ca, b - cb
    s = np.linalg.svd(A, compute_uv=False)
    if s[1] < 1e-6 * max(s[0], 1e-12):
        raise InsufficientDataError("registration points are collinear: the rotation is not determined")
    U, _, Vt = np.linalg.svd(A.T @ B)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    t = cb - R @ ca
    res = np.linalg.norm(a @ R.T + t - b, axis=1)
    return Registration(R=R, t_mm=t, residuals_mm=res, rms_mm=float(np.sqrt(np.mean(res**2))), n=int(a.shape[0]))
