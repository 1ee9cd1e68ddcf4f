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

#: largest coordinate a fit takes, mm (as :data:`station.readers.text.MAX_ABS_MM`: 1 km; beyond, its sums overflow
#: long before and no instrument measures there)
MAX_ABS_MM = 1.0e6


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
        if arr.size and np.abs(arr).max() > MAX_ABS_MM:
            k = int(np.argmax(np.abs(arr).max(axis=1)))
            raise DataError(f"{name} point {k + 1}: {float(np.abs(arr[k]).max()):.6g} mm is beyond {MAX_ABS_MM:g} mm, "
                            "more than any instrument measures")
    if a.shape != b.shape:
        raise DataError(f"p_base_mm {a.shape} and p_tracker_mm {b.shape} must have the same shape")
    if a.shape[0] < 3:
        raise InsufficientDataError(f"registration needs at least 3 points, got {a.shape[0]}")
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    A, B = a - ca, b - cb
    try:
        s = np.linalg.svd(A, compute_uv=False)
        if s[1] < 1e-6 * max(s[0], 1e-12):
            raise InsufficientDataError("registration points are collinear: the rotation is not determined")
        U, _, Vt = np.linalg.svd(A.T @ B)
    except np.linalg.LinAlgError:
        raise InsufficientDataError("registration points give no rotation (the SVD did not converge)") from None
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    t = cb - R @ ca
    res = np.linalg.norm(a @ R.T + t - b, axis=1)
    return Registration(R=R, t_mm=t, residuals_mm=res, rms_mm=float(np.sqrt(np.mean(res**2))), n=int(a.shape[0]))


#: a fit rms above this many times the points' 3-D noise (sqrt(3) x per-axis) means the pairs do not match
RMS_NOISE_FACTOR = 10.0


def registration_from_transform(R, t_mm) -> Registration:
    """A :class:`Registration` from a given transform ``p_tracker = R @ p_base + t_mm`` (no fit, no residuals).

    Raises DataError when ``R`` is not a proper rotation (orthonormal to 1e-6, determinant +1).
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t_mm, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise DataError(f"R must be a finite 3x3 array, got shape {R.shape}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise DataError(f"t_mm must be 3 finite numbers, got shape {t.shape}")
    off = float(np.abs(R.T @ R - np.eye(3)).max())
    if off > 1e-6:
        raise DataError(f"R is not a rotation: R^T R differs from the identity by {off:.3g}")
    if np.linalg.det(R) < 0:
        raise DataError("R is a reflection (determinant -1), not a rotation")
    return Registration(R=R, t_mm=t, residuals_mm=np.zeros(0), rms_mm=0.0, n=0)


def rms_allowance_mm(noise_mm: float, robot_error_mm: float | None = None) -> float:
    """Largest registration fit rms that matched point pairs explain, mm.

    The residual of a right fit is the noise of its points: the tracker's
    (``noise_mm`` per axis, so ``sqrt(3) noise_mm`` in 3-D) and, when the
    base-frame points are positions the robot was commanded to, the robot's
    own error there (``robot_error_mm``, e.g. its AP limit). A fit rms more
    than :data:`RMS_NOISE_FACTOR` times the tracker's 3-D noise, and above the
    robot's error, comes from mismatched pairs (order, units, frames).
    """
    if not (np.isfinite(noise_mm) and noise_mm >= 0):
        raise DataError(f"noise_mm must be finite and >= 0, got {noise_mm!r}")
    allow = RMS_NOISE_FACTOR * float(np.sqrt(3.0)) * float(noise_mm)
    if robot_error_mm is not None:
        allow = max(allow, float(robot_error_mm))
    return allow


@dataclass(frozen=True)
class Circle3D:
    """A circle in space: ``centre_mm`` (3,), unit ``normal`` (3,), ``radius_mm``, ``rms_mm`` of the fit."""

    centre_mm: np.ndarray
    normal: np.ndarray
    radius_mm: float
    rms_mm: float


def fit_circle(points_mm) -> Circle3D:
    """Least-squares circle through points on an arc (the path of a point turning about one axis).

    The plane is the SVD best fit; the circle in it the algebraic (Kasa) fit.
    The normal points along the rotation of the points' order (right-hand rule),
    so a joint turned through increasing angles gives its axis direction.
    """
    p = np.asarray(points_mm, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise DataError(f"points_mm must be a finite (N, 3) array, got shape {p.shape}")
    if p.shape[0] < 4:
        raise InsufficientDataError(f"a circle fit needs at least 4 points, got {p.shape[0]}")
    c0 = p.mean(axis=0)
    _, s, Vt = np.linalg.svd(p - c0)
    if s[1] < 1e-6 * s[0]:
        raise InsufficientDataError("the points are collinear: no circle (did the joint turn?)")
    e1, e2, n = Vt[0], Vt[1], Vt[2]
    uv = np.column_stack([(p - c0) @ e1, (p - c0) @ e2])
    A = np.column_stack([2 * uv, np.ones(len(uv))])
    sol, *_ = np.linalg.lstsq(A, (uv**2).sum(axis=1), rcond=None)
    cu, cv = sol[0], sol[1]
    r = float(np.sqrt(sol[2] + cu**2 + cv**2))
    centre = c0 + cu * e1 + cv * e2
    turn = np.cross(p[0] - centre, p[-1] - centre)
    if float(turn @ n) < 0:
        n = -n
    d_plane = (p - centre) @ n
    d_radial = np.linalg.norm((p - centre) - np.outer(d_plane, n), axis=1) - r
    rms = float(np.sqrt(np.mean(d_plane**2 + d_radial**2)))
    return Circle3D(centre, n, r, rms)


def register_by_axes(dh_nominal, q1_rad, p1_tracker_mm, q2_rad, p2_tracker_mm) -> Registration:
    """Robot base frame in the tracker frame from the circles of joints 1 and 2.

    The tool point is measured while joint 1 alone turns (``q1_rad`` (N1, 6),
    points ``p1_tracker_mm``) and while joint 2 alone turns (``q2_rad``,
    ``p2_tracker_mm``). The measured circles give the two axes in the tracker
    frame; the nominal model gives the same circles in the base frame. The
    rotation takes the nominal axis directions onto the measured ones; the
    base origin is placed so that the measured joint-1 axis is the nominal
    one (across it) and the measured joint-2 axis has its nominal height
    (along it). This is the usual way to tie an instrument to a robot's base
    (ISO/TR 13309) and, unlike a best fit over test poses, it does not absorb
    the errors of the links beyond joint 2 into the frame — those stay in AP.

    Returns
    -------
    Registration
        ``residuals_mm`` are the two circles' fit residuals (N1 + N2).
    """
    from station.models.kinematics import tool_position

    meas1, meas2 = fit_circle(p1_tracker_mm), fit_circle(p2_tracker_mm)
    nom1 = fit_circle(tool_position(dh_nominal, np.asarray(q1_rad, dtype=float)))
    nom2 = fit_circle(tool_position(dh_nominal, np.asarray(q2_rad, dtype=float)))
    if abs(float(nom1.normal @ nom2.normal)) > 0.99:
        raise InsufficientDataError("joints 1 and 2 are (nearly) parallel in these poses: the frame is not determined")
    a = np.array([nom1.normal, nom2.normal, np.cross(nom1.normal, nom2.normal)])
    b = np.array([meas1.normal, meas2.normal, np.cross(meas1.normal, meas2.normal)])
    U, _, Vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    z = meas1.normal
    t1 = meas1.centre_mm - R @ nom1.centre_mm
    t2 = meas2.centre_mm - R @ nom2.centre_mm
    t = (t1 - (t1 @ z) * z) + (t2 @ z) * z
    p1 = np.asarray(p1_tracker_mm, dtype=float)
    p2 = np.asarray(p2_tracker_mm, dtype=float)
    res = []
    for c, p in ((meas1, p1), (meas2, p2)):
        dpl = (p - c.centre_mm) @ c.normal
        drad = np.linalg.norm((p - c.centre_mm) - np.outer(dpl, c.normal), axis=1) - c.radius_mm
        res.append(np.sqrt(dpl**2 + drad**2))
    res = np.concatenate(res)
    return Registration(R=R, t_mm=t, residuals_mm=res, rms_mm=float(np.sqrt(np.mean(res**2))), n=int(res.size))
