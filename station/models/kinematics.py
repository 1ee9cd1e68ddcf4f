"""Arm kinematics: DH + Hayati parallel-axis model of seed 002 section 3.1.

A kinematic model is a float array ``dh`` of shape ``(7, 5)`` (or ``(N, 7, 5)``
for per-sample parameters): rows are joints 1..6 then the TCP row, columns
``[a_mm, alpha_rad, d_mm, theta_offset_rad, beta_rad]`` (seed 002 Table 2
order). Joint ``i``'s angle adds to row ``i``'s ``theta``; the TCP row has no
joint. Each row gives the link transform of seed 002 eq. (3)::

    T_i = Rz(theta_i) . Tz(d_i) . Tx(a_i) . Rx(alpha_i) . Ry(beta_i)

and the tool pose is their product, eq. (5). The position Jacobian with
respect to all 35 parameters is eq. (7)-(8); it is evaluated in closed form
(each partial derivative ``F_{i-1} . dT_i/dgamma . S_i`` is a translation or a
rotation about an axis of an intermediate frame, so its position column is a
unit vector or a cross product), which is exact, not an approximation.

Everything is vectorised over the N poses; the only Python loops run over the
7 link rows (and, in :func:`ik`, over iterations and restarts).

Units inside: mm and rad. :func:`dh_from_degrees` converts a table written
like seed Table 2 (angles in degrees).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from station.errors import ConfigError, DataError
from station.numeric import finite_number

__all__ = [
    "N_JOINTS",
    "N_ROWS",
    "N_PARAMS",
    "PARAM_NAMES",
    "IKResult",
    "validate_dh",
    "validate_joint_limits",
    "dh_from_degrees",
    "dh_to_degrees",
    "link_transforms",
    "frames",
    "fk",
    "tool_position",
    "param_jacobian",
    "param_jacobian_from_frames",
    "fk_and_param_jacobian",
    "joint_jacobian",
    "pose_error",
    "ik",
]

N_JOINTS = 6
N_ROWS = 7
N_PARAMS = 5 * N_ROWS
_COLS = ("a", "alpha", "d", "theta", "beta")
_ROW_NAMES = ("1", "2", "3", "4", "5", "6", "TCP")
#: Names of the 35 parameters in the order of :func:`param_jacobian` columns
#: (row-major over ``dh``: ``a1, alpha1, d1, theta1, beta1, a2, ..., beta_TCP``).
PARAM_NAMES = tuple(f"{c}{r}" for r in _ROW_NAMES for c in _COLS)


# --------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------
def _as_float_array(x, name: str, error=DataError) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise error(f"`{name}` must be a numeric array: {exc}") from exc
    return arr


def _require_finite(arr: np.ndarray, name: str, error=DataError) -> None:
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))
        raise error(
            f"`{name}` contains {len(bad)} non-finite value(s) (NaN/inf), "
            f"first at index {tuple(int(i) for i in bad[0])}"
        )


def validate_dh(dh, name: str = "dh", error=DataError) -> np.ndarray:
    """Return ``dh`` as a float array of shape ``(7, 5)`` or ``(N, 7, 5)``.

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
        DH + Hayati table, columns ``[a_mm, alpha_rad, d_mm, theta_offset_rad,
        beta_rad]`` (seed 002 Table 2 order), rows joints 1..6 then TCP.
    name : str
        Name used in error messages.
    error : type
        Exception class raised (``DataError`` for function arguments,
        ``ConfigError`` for configuration).

    Raises
    ------
    DataError or ConfigError
        Wrong shape, non-numeric or non-finite entries; the message names
        ``name``.
    """
    arr = _as_float_array(dh, name, error)
    if arr.ndim not in (2, 3) or arr.shape[-2:] != (N_ROWS, 5):
        raise error(
            f"`{name}` must have shape (7, 5) or (N, 7, 5) "
            f"(rows joints 1..6 + TCP; columns a_mm, alpha_rad, d_mm, "
            f"theta_offset_rad, beta_rad), got {arr.shape}"
        )
    _require_finite(arr, name, error)
    return arr


def _validate_q(q, name: str = "q_rad") -> np.ndarray:
    arr = _as_float_array(q, name)
    if arr.ndim not in (1, 2) or arr.shape[-1] != N_JOINTS:
        raise DataError(f"`{name}` must have shape (6,) or (N, 6), got {arr.shape}")
    _require_finite(arr, name)
    return arr


def validate_joint_limits(limits, name: str = "joint_limits_rad", error=DataError) -> np.ndarray:
    """Return joint limits as a float ``(6, 2)`` array ``[min, max]`` per joint.

    Raises
    ------
    DataError or ConfigError
        Wrong shape, non-finite values or ``min > max`` (the joint is named).
    """
    arr = _as_float_array(limits, name, error)
    if arr.shape != (N_JOINTS, 2):
        raise error(f"`{name}` must have shape (6, 2) [min, max] per joint, got {arr.shape}")
    _require_finite(arr, name, error)
    bad = np.nonzero(arr[:, 0] > arr[:, 1])[0]
    if bad.size:
        j = int(bad[0])
        raise error(
            f"`{name}` joint {j + 1}: min {arr[j, 0]!r} > max {arr[j, 1]!r}"
        )
    return arr


def _prepare(dh, q_rad):
    """Validate and broadcast ``dh`` and ``q_rad``.

    Returns ``(dh, q2, single)`` with ``q2`` of shape ``(N, 6)``; ``dh`` is
    ``(7, 5)`` or ``(N, 7, 5)``; ``single`` says the caller gave one pose
    (``q`` of shape (6,) and ``dh`` of shape (7, 5)) and expects no N axis.
    """
    dh = validate_dh(dh)
    q = _validate_q(q_rad)
    single = q.ndim == 1 and dh.ndim == 2
    if dh.ndim == 3:
        n = dh.shape[0]
        if q.ndim == 2 and q.shape[0] != n:
            raise DataError(
                f"`q_rad` has {q.shape[0]} rows but per-sample `dh` has {n}"
            )
        q = np.broadcast_to(q, (n, N_JOINTS))
    elif q.ndim == 1:
        q = q[None, :]
    return dh, q, single


# --------------------------------------------------------------------------
# unit conversion
# --------------------------------------------------------------------------
def dh_from_degrees(table, name: str = "dh_table") -> np.ndarray:
    """Convert a DH table written in degrees into the internal mm/rad array.

    Parameters
    ----------
    table : array_like, shape (7, 5)
        Columns ``[a_mm, alpha_deg, d_mm, theta_offset_deg, beta_deg]`` as in
        seed 002 Table 2 / Table 3 (the joint variable itself omitted: write
        ``theta_2 - 90`` as ``-90``).
    name : str
        Name used in error messages.

    Returns
    -------
    dh : ndarray, shape (7, 5)
        ``[a_mm, alpha_rad, d_mm, theta_offset_rad, beta_rad]``.

    Raises
    ------
    ConfigError
        Wrong shape or non-finite entries.
    """
    arr = validate_dh(table, name=name, error=ConfigError)
    if arr.ndim != 2:
        raise ConfigError(f"`{name}` must have shape (7, 5), got {arr.shape}")
    out = arr.copy()
    out[:, [1, 3, 4]] = np.deg2rad(out[:, [1, 3, 4]])
    return out


def dh_to_degrees(dh) -> np.ndarray:
    """Inverse of :func:`dh_from_degrees` (for files and reports)."""
    arr = validate_dh(dh).copy()
    arr[..., [1, 3, 4]] = np.rad2deg(arr[..., [1, 3, 4]])
    return arr


# --------------------------------------------------------------------------
# forward kinematics
# --------------------------------------------------------------------------
def _link_transforms(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Seed 002 eq. (3) for every row; ``dh`` validated, ``q`` (N, 6)."""
    n = q.shape[0]
    a = dh[..., 0]
    al = dh[..., 1]
    d = dh[..., 2]
    be = dh[..., 4]
    th = dh[..., 3] + np.concatenate([q, np.zeros((n, 1))], axis=1)  # (N, 7)
    ct, st = np.cos(th), np.sin(th)
    ca, sa = np.cos(al), np.sin(al)
    cb, sb = np.cos(be), np.sin(be)
    T = np.zeros((n, N_ROWS, 4, 4))
    T[..., 0, 0] = ct * cb - st * sa * sb
    T[..., 0, 1] = -st * ca
    T[..., 0, 2] = ct * sb + st * sa * cb
    T[..., 0, 3] = a * ct
    T[..., 1, 0] = st * cb + ct * sa * sb
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = st * sb - ct * sa * cb
    T[..., 1, 3] = a * st
    T[..., 2, 0] = -ca * sb
    T[..., 2, 1] = sa
    T[..., 2, 2] = ca * cb
    T[..., 2, 3] = d
    T[..., 3, 3] = 1.0
    return T


def _frames(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Cumulative frames ``F[:, k] = T_1 ... T_k`` (k = 0..7), shape (N, 8, 4, 4)."""
    A = _link_transforms(dh, q)
    n = q.shape[0]
    F = np.empty((n, N_ROWS + 1, 4, 4))
    F[:, 0] = np.eye(4)
    F[:, 1] = A[:, 0]
    for k in range(1, N_ROWS):
        np.matmul(F[:, k], A[:, k], out=F[:, k + 1])
    return F


def link_transforms(dh, q_rad) -> np.ndarray:
    """Individual link transforms ``{i-1}_i T`` of seed 002 eq. (3).

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
    q_rad : array_like, shape (6,) or (N, 6)

    Returns
    -------
    T : ndarray, shape (N, 7, 4, 4) (or (7, 4, 4) for a single pose)
    """
    dh, q, single = _prepare(dh, q_rad)
    T = _link_transforms(dh, q)
    return T[0] if single else T


def frames(dh, q_rad) -> np.ndarray:
    """Base-frame poses of every DH frame, ``0_k T`` for k = 0 (base) .. 7 (TCP).

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
    q_rad : array_like, shape (6,) or (N, 6)

    Returns
    -------
    F : ndarray, shape (N, 8, 4, 4) (or (8, 4, 4) for a single pose)
        ``F[:, 0]`` is the identity, ``F[:, k]`` the frame after link row k,
        ``F[:, 7]`` the TCP (seed 002 eq. (5)).
    """
    dh, q, single = _prepare(dh, q_rad)
    F = _frames(dh, q)
    return F[0] if single else F


def fk(dh, q_rad) -> np.ndarray:
    """Forward kinematics, seed 002 eq. (5): ``0_TCP T = 0_1T ... 6_TCP T``.

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
        DH + Hayati table ``[a_mm, alpha_rad, d_mm, theta_offset_rad, beta_rad]``.
    q_rad : array_like, shape (N, 6) or (6,)
        Joint angles. A single pose ``(6,)`` with a ``(7, 5)`` table returns
        a single ``(4, 4)`` matrix.

    Returns
    -------
    T : ndarray, shape (N, 4, 4)
        Tool pose in the base frame (mm).

    Raises
    ------
    DataError
        Wrong shapes or non-finite values (the argument is named).
    """
    dh, q, single = _prepare(dh, q_rad)
    F = _frames(dh, q)
    T = np.ascontiguousarray(F[:, -1])
    return T[0] if single else T


def tool_position(dh, q_rad) -> np.ndarray:
    """TCP position ``0_TCP P`` of seed 002 eq. (5), mm.

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
    q_rad : array_like, shape (N, 6) or (6,)

    Returns
    -------
    p : ndarray, shape (N, 3) (or (3,) for a single pose)
    """
    T = fk(dh, q_rad)
    return np.ascontiguousarray(T[..., :3, 3])


# --------------------------------------------------------------------------
# Jacobians
# --------------------------------------------------------------------------
def _param_jacobian_from_frames(dh: np.ndarray, q: np.ndarray, F: np.ndarray) -> np.ndarray:
    n = q.shape[0]
    th = dh[..., 3] + np.concatenate([q, np.zeros((n, 1))], axis=1)
    ct, st = np.cos(th), np.sin(th)                                       # (N, 7)
    al = np.broadcast_to(dh[..., 1], (n, N_ROWS))
    ca, sa = np.cos(al), np.sin(al)
    # coordinates first (3, N, 7): each product below runs over one coordinate's rows at a time
    Fr = F.transpose(2, 3, 0, 1)                                          # (4, 4, N, 8) view
    x_prev, y_prev, z_prev = Fr[:3, 0, :, :N_ROWS], Fr[:3, 1, :, :N_ROWS], Fr[:3, 2, :, :N_ROWS]
    o = Fr[:3, 3]                                                         # (3, N, 8) frame origins
    p = o[:, :, N_ROWS:]                                                  # tool position
    # frame after Rz(theta): its x axis carries a, its y axis (after
    # Rx(alpha)) is the Hayati beta axis; alpha and beta rotate about o_i.
    x_m = ct * x_prev + st * y_prev
    y_m = ct * y_prev - st * x_prev
    y_b = ca * y_m + sa * z_prev
    r_prev = p - o[:, :, :N_ROWS]
    r_i = p - o[:, :, 1:]
    J = np.empty((3, n, N_ROWS, 5))
    J[..., 0] = x_m                        # d p / d a_i
    _cross_first(x_m, r_i, J[..., 1])      # d p / d alpha_i
    J[..., 2] = z_prev                     # d p / d d_i
    _cross_first(z_prev, r_prev, J[..., 3])  # d p / d theta_i
    _cross_first(y_b, r_i, J[..., 4])      # d p / d beta_i
    # column 5*i + k of the result is row i, parameter k
    return np.ascontiguousarray(J.reshape(3, n, N_PARAMS).transpose(1, 0, 2))


def _cross_first(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """Cross product over the first axis (3) into ``out``."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


def param_jacobian(dh, q_rad) -> np.ndarray:
    """Position Jacobian w.r.t. the 35 kinematic parameters, seed 002 eq. (7)-(8).

    Column ``5*i + k`` is ``d p_TCP / d dh[i, k]`` with ``k`` in
    ``[a, alpha, d, theta, beta]`` and ``i`` the row (joints 1..6, TCP), i.e.
    the order of ``dh.ravel()`` and of seed 002's ``Delta X``. Each column is
    the translation part of ``0_{i-1}T . dT_i/dgamma_i . i_TCP T`` (eq. (7)),
    evaluated in closed form.

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
    q_rad : array_like, shape (N, 6) or (6,)

    Returns
    -------
    J : ndarray, shape (N, 3, 35) (or (3, 35) for a single pose)
        mm per mm for ``a, d``; mm per rad for ``alpha, theta, beta``.
    """
    dh, q, single = _prepare(dh, q_rad)
    F = _frames(dh, q)
    J = _param_jacobian_from_frames(dh, q, F)
    return J[0] if single else J


def param_jacobian_from_frames(dh, q_rad, F: np.ndarray) -> np.ndarray:
    """:func:`param_jacobian` from the frames :func:`frames` already gave for the same ``dh`` and ``q_rad``
    (N, 8, 4, 4): a residual and its Jacobian share one forward pass."""
    dh, q, _ = _prepare(dh, q_rad)
    return _param_jacobian_from_frames(dh, q, F)


def fk_and_param_jacobian(dh, q_rad):
    """Tool poses and the parameter Jacobian in one pass (shares the frames).

    Returns
    -------
    T : ndarray, shape (N, 4, 4)
    J : ndarray, shape (N, 3, 35)
        As :func:`fk` and :func:`param_jacobian` (seed 002 eq. (5), (7)-(8)).
    """
    dh, q, single = _prepare(dh, q_rad)
    F = _frames(dh, q)
    J = _param_jacobian_from_frames(dh, q, F)
    T = np.ascontiguousarray(F[:, -1])
    return (T[0], J[0]) if single else (T, J)


def _joint_jacobian_from_frames(F: np.ndarray) -> np.ndarray:
    n = F.shape[0]
    p = F[:, -1, :3, 3]
    z = F[:, :N_JOINTS, :3, 2]  # (N, 6, 3) joint axes z_{i-1}
    o = F[:, :N_JOINTS, :3, 3]
    J = np.empty((n, 6, N_JOINTS))
    J[:, :3, :] = np.cross(z, p[:, None, :] - o).transpose(0, 2, 1)
    J[:, 3:, :] = z.transpose(0, 2, 1)
    return J


def joint_jacobian(dh, q_rad) -> np.ndarray:
    """Geometric Jacobian of the TCP w.r.t. the six joint angles.

    Joint ``i`` turns about ``z_{i-1}`` through ``o_{i-1}`` (the theta of row
    ``i`` in seed 002 eq. (3)), so column ``i`` is
    ``[z_{i-1} x (p - o_{i-1}); z_{i-1}]``; the linear part equals the theta
    columns of :func:`param_jacobian`.

    Parameters
    ----------
    dh : array_like, shape (7, 5) or (N, 7, 5)
    q_rad : array_like, shape (N, 6) or (6,)

    Returns
    -------
    J : ndarray, shape (N, 6, 6) (or (6, 6) for a single pose)
        Rows 0-2 linear velocity (mm/rad), rows 3-5 angular velocity (rad/rad),
        both in the base frame.
    """
    dh, q, single = _prepare(dh, q_rad)
    J = _joint_jacobian_from_frames(_frames(dh, q))
    return J[0] if single else J


# --------------------------------------------------------------------------
# inverse kinematics
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class IKResult:
    """Result of :func:`ik` (not converging is a status, not an exception).

    Attributes
    ----------
    q_rad : ndarray, shape (N, 6)
        Best joint angles found (inside the joint limits) for every target.
    success : ndarray of bool, shape (N,)
        Residuals below the tolerances.
    residual_mm : ndarray, shape (N,)
        Position error ``|p_target - p(q)|``.
    residual_deg : ndarray, shape (N,) or None
        Orientation error angle for pose targets; ``None`` for positions.
    iterations : ndarray of int, shape (N,)
        Solver iterations spent on each target (all restarts).
    attempts : ndarray of int, shape (N,)
        Starting points tried (1 = the given seed sufficed; random restarts
        run four at a time).
    """

    q_rad: np.ndarray
    success: np.ndarray
    residual_mm: np.ndarray
    residual_deg: np.ndarray | None
    iterations: np.ndarray
    attempts: np.ndarray

    @property
    def all_success(self) -> bool:
        """True when every target converged."""
        return bool(np.all(self.success))


def _validate_target(target):
    arr = _as_float_array(target, "target")
    if arr.shape[-2:] == (4, 4) and arr.ndim in (2, 3):
        single = arr.ndim == 2
        arr = arr.reshape(-1, 4, 4)
        _require_finite(arr, "target")
        R = arr[:, :3, :3]
        orth = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2)) if len(arr) else np.zeros(0)
        det = np.linalg.det(R) if len(arr) else np.zeros(0)
        bad = np.nonzero((orth > 1e-5) | (det < 0) | (np.abs(arr[:, 3] - [0, 0, 0, 1]).max(axis=1) > 0))[0]
        if bad.size:
            raise DataError(
                f"`target` pose {int(bad[0])} is not a homogeneous transform with a "
                f"proper rotation (orthonormality error {orth[bad[0]]:.2e}, det {det[bad[0]]:.6f})"
            )
        return arr, single, True
    if arr.shape[-1:] == (3,) and arr.ndim in (1, 2):
        single = arr.ndim == 1
        arr = arr.reshape(-1, 3)
        _require_finite(arr, "target")
        return arr, single, False
    raise DataError(f"`target` must have shape (N, 3) positions or (N, 4, 4) poses, got {arr.shape}")


def pose_error(T_target: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position and orientation error between poses (both (N, 4, 4)).

    Returns
    -------
    dp_mm : ndarray, shape (N, 3)
        ``p_target - p``.
    dphi_rad : ndarray, shape (N, 3)
        Rotation vector of ``R_target . R^T`` (base frame).
    """
    dp = T_target[:, :3, 3] - T[:, :3, 3]
    if len(T) == 0:
        return dp, np.zeros((0, 3))
    dR = np.einsum("nij,nkj->nik", T_target[:, :3, :3], T[:, :3, :3])
    dphi = Rotation.from_matrix(dR).as_rotvec()
    return dp, dphi


#: consecutive iterations with < 1 % cost reduction before an attempt is
#: abandoned (a local minimum); the target then gets a fresh random start.
_STALL_ITERS = 12
#: random starts tried side by side per unsolved target and round.
_RESTARTS_PER_ROUND = 4
_TWO_PI = 2.0 * np.pi


def _into_limits(q: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Bring angles into ``[lo, hi]``: wrap by 2 pi when that lands inside
    (joints with a range beyond one turn), clip otherwise."""
    up = np.ceil((lo - q) / _TWO_PI)  # turns to add to reach lo
    q_wrapped = q + _TWO_PI * np.maximum(up, 0.0)
    down = np.ceil((q - hi) / _TWO_PI)
    q_wrapped = q_wrapped - _TWO_PI * np.maximum(down, 0.0)
    ok = (q_wrapped >= lo) & (q_wrapped <= hi)
    outside = (q < lo) | (q > hi)
    return np.where(outside & ok, q_wrapped, np.clip(q, lo, hi))


def _dls_step(J, e, q, lam, lo, hi):
    """One damped least-squares step ``(J^T J + lam D) dq = J^T e`` for every
    row, with joints pinned at a limit (and pushed outwards) frozen and the
    step solved again for the others; the result is brought into the limits."""
    eye = np.eye(N_JOINTS)
    JtJ = np.einsum("nki,nkj->nij", J, J)
    g = np.einsum("nki,nk->ni", J, e)
    diag = np.einsum("nii->ni", JtJ)
    D = diag + 1e-9 * diag.max(axis=1, keepdims=True) + 1e-12
    A = JtJ + lam[:, None, None] * (D[:, :, None] * eye)
    dq = np.linalg.solve(A, g[..., None])[..., 0]
    at_lo = (q <= lo) & (dq < 0)
    at_hi = (q >= hi) & (dq > 0)
    pinned = at_lo | at_hi
    rows = np.nonzero(pinned.any(axis=1))[0]
    if rows.size:
        keep = ~pinned[rows]
        mask = keep[:, :, None] & keep[:, None, :]
        A2 = np.where(mask, A[rows], 0.0) + (~keep)[:, :, None] * eye
        g2 = np.where(keep, g[rows], 0.0)
        dq[rows] = np.linalg.solve(A2, g2[..., None])[..., 0]
    return _into_limits(q + dq, lo, hi)


def _int_at_least(name: str, val, minimum: int) -> int:
    try:
        ok = int(val) == val
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok or isinstance(val, bool) or val < minimum:
        raise ConfigError(f"`{name}` must be an integer >= {minimum}, got {val!r}")
    return int(val)


def ik(
    dh,
    target,
    q0=None,
    joint_limits_rad=None,
    *,
    tol_mm: float = 1e-4,
    tol_deg: float = 1e-5,
    max_iter: int = 100,
    n_restarts: int = 32,
    orientation_scale_mm: float = 500.0,
    seed: int | None = 0,
) -> IKResult:
    """Numerical inverse kinematics by damped least squares (Levenberg-Marquardt).

    Vectorised over the N targets: each iteration computes FK (seed 002
    eq. (5)) and the geometric joint Jacobian for all unconverged targets at
    once and takes a damped Gauss-Newton step ``(J^T J + lambda D) dq = J^T e``
    with a per-target damping ``lambda`` that shrinks after a successful step
    and grows after a rejected one. Joint limits: a joint pinned at a limit
    and pushed outwards is frozen for that step; a step leaving the range is
    wrapped by 2 pi when that lands inside (joints turning more than once),
    clipped otherwise. An attempt that stops progressing (12 steps in a row
    with < 1 % cost reduction) is abandoned and the target starts again from
    random joint angles inside the limits (``n_restarts`` starts at most,
    four side by side per round); the best result is kept.

    Targets whose only solutions lie within a hair of a singular pose (arm
    fully stretched at the workspace boundary) converge slowly and may be
    reported as not successful; that is a status, never an exception.

    Parameters
    ----------
    dh : array_like, shape (7, 5)
        Kinematic model (a single table; use the nominal for a controller).
    target : array_like, shape (N, 3) or (N, 4, 4)
        TCP positions (mm) or full poses in the base frame. ``(3,)`` or
        ``(4, 4)`` for a single target.
    q0 : array_like, shape (6,) or (N, 6), optional
        Starting joint angles (e.g. the current pose, to stay on its branch).
        Clipped into the limits. Default: the middle of the limits.
    joint_limits_rad : array_like, shape (6, 2), optional
        ``[min, max]`` per joint. Default ``[-2 pi, 2 pi]`` for every joint.
    tol_mm, tol_deg : float
        Convergence tolerances on the position error and orientation angle.
    max_iter : int
        Iterations per attempt.
    n_restarts : int
        Random starting points (drawn uniformly inside the limits, tried
        four at a time) for targets the first attempt did not solve.
    orientation_scale_mm : float
        Length that weights orientation errors (rad) against position (mm).
    seed : int or None
        Seed of the generator for restart points (deterministic by default).

    Returns
    -------
    IKResult
        ``q_rad`` (N, 6), ``success`` (N,), ``residual_mm`` (N,),
        ``residual_deg`` (N,) for pose targets, ``iterations`` (N,),
        ``attempts`` (N,). A single target returns arrays with N = 1.

    Raises
    ------
    DataError
        Malformed ``dh``, ``target``, ``q0`` or ``joint_limits_rad``.
    ConfigError
        Non-positive tolerances, iteration counts or scale.
    """
    dh = validate_dh(dh)
    if dh.ndim != 2:
        raise DataError(f"`dh` for ik must have shape (7, 5), got {dh.shape}")
    tgt, _single, is_pose = _validate_target(target)
    n = tgt.shape[0]
    if joint_limits_rad is None:
        lim = np.tile([-2 * np.pi, 2 * np.pi], (N_JOINTS, 1))
    else:
        lim = validate_joint_limits(joint_limits_rad)
    tol_mm = finite_number(tol_mm, "tol_mm", positive=True)
    tol_deg = finite_number(tol_deg, "tol_deg", positive=True)
    orientation_scale_mm = finite_number(orientation_scale_mm, "orientation_scale_mm", positive=True)
    max_iter = _int_at_least("max_iter", max_iter, 1)
    n_restarts = _int_at_least("n_restarts", n_restarts, 0)
    lo, hi = lim[:, 0], lim[:, 1]
    if q0 is None:
        q_start = np.broadcast_to(0.5 * (lo + hi), (n, N_JOINTS)).copy()
    else:
        q0a = _validate_q(q0, "q0")
        if q0a.ndim == 2 and q0a.shape[0] != n:
            raise DataError(f"`q0` has {q0a.shape[0]} rows but `target` has {n}")
        q_start = np.clip(np.broadcast_to(q0a, (n, N_JOINTS)), lo, hi).copy()
    rng = np.random.default_rng(seed)
    tol_rad = np.deg2rad(tol_deg)
    w = 1.0 / orientation_scale_mm

    def errors(q, idx):
        T = _frames(dh, q)[:, -1]
        if is_pose:
            dp, dphi = pose_error(tgt[idx], T)
            return np.concatenate([dp, dphi / w], axis=1), dp, dphi
        dp = tgt[idx] - T[:, :3, 3]
        return dp, dp, None

    best_q = q_start.copy()
    best_cost = np.full(n, np.inf)
    best_pos = np.full(n, np.inf)
    best_rot = np.full(n, np.inf) if is_pose else None
    iterations = np.zeros(n, dtype=int)
    attempts = np.zeros(n, dtype=int)
    success = np.zeros(n, dtype=bool)

    def converged(dp, dphi):
        ok = np.linalg.norm(dp, axis=1) < tol_mm
        if is_pose:
            ok &= np.linalg.norm(dphi, axis=1) < tol_rad
        return ok

    todo = np.arange(n)
    starts_left = int(n_restarts)
    first = True
    while todo.size:
        # round 0: the given seed; later rounds: up to _RESTARTS_PER_ROUND
        # random starts per unsolved target, solved side by side.
        if first:
            idx = todo
            q = q_start[todo].copy()
        else:
            k = min(_RESTARTS_PER_ROUND, starts_left)
            if k <= 0:
                break
            starts_left -= k
            idx = np.repeat(todo, k)
            q = lo + (hi - lo) * rng.random((idx.size, N_JOINTS))
        first = False
        np.add.at(attempts, idx, 1)
        e, dp, dphi = errors(q, idx)
        cost = np.einsum("ni,ni->n", e, e)
        lam = np.full(idx.size, 1e-3)
        n_slow = np.zeros(idx.size, dtype=int)
        active = ~converged(dp, dphi)
        for _ in range(int(max_iter)):
            a = np.nonzero(active)[0]
            if a.size == 0:
                break
            np.add.at(iterations, idx[a], 1)
            Jg = _joint_jacobian_from_frames(_frames(dh, q[a]))
            J = np.concatenate([Jg[:, :3], Jg[:, 3:] / w], axis=1) if is_pose else Jg[:, :3]
            q_try = _dls_step(J, e[a], q[a], lam[a], lo, hi)
            e_try, dp_try, dphi_try = errors(q_try, idx[a])
            cost_try = np.einsum("ni,ni->n", e_try, e_try)
            cost_before = cost[a]
            better = cost_try < cost_before
            acc = a[better]
            q[acc] = q_try[better]
            e[acc] = e_try[better]
            dp[acc] = dp_try[better]
            if is_pose:
                dphi[acc] = dphi_try[better]
            cost[acc] = cost_try[better]
            lam[acc] = np.maximum(lam[acc] / 3.0, 1e-12)
            rej = a[~better]
            lam[rej] = lam[rej] * 5.0
            slow = cost_try > 0.99 * cost_before
            n_slow[a] = np.where(slow, n_slow[a] + 1, 0)
            done_now = converged(dp[a], dphi[a] if is_pose else None)
            stalled = (lam[a] > 1e8) | (n_slow[a] >= _STALL_ITERS)
            active[a[done_now | stalled]] = False
        ok = converged(dp, dphi)
        # per target, the best replica: converged first, then lowest cost
        order = np.lexsort((cost, ~ok, idx))
        first_of = np.ones(order.size, dtype=bool)
        first_of[1:] = idx[order][1:] != idx[order][:-1]
        pick = order[first_of]
        tgt_i = idx[pick]
        improve = ok[pick] | (cost[pick] < best_cost[tgt_i])
        sel, pk = tgt_i[improve], pick[improve]
        best_q[sel] = q[pk]
        best_cost[sel] = cost[pk]
        best_pos[sel] = np.linalg.norm(dp[pk], axis=1)
        if is_pose:
            best_rot[sel] = np.linalg.norm(dphi[pk], axis=1)
        success[tgt_i[ok[pick]]] = True
        todo = tgt_i[~ok[pick]]

    return IKResult(
        q_rad=best_q,
        success=success,
        residual_mm=best_pos,
        residual_deg=np.rad2deg(best_rot) if is_pose else None,
        iterations=iterations,
        attempts=attempts,
    )
