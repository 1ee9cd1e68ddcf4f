"""Kinematic identification of an arm (seed 002 section 3): which parameters, and their values.

Two formulations, both solved by Levenberg-Marquardt on the analytic
parameter Jacobian of :mod:`station.models.kinematics` (seed 002 eq. (7)-(8);
the absolute one from the poses-last forward pass of
:mod:`station.models.frame_pass`, in the instrument frame, summed over
blocks of poses into its normal equations and the ``R`` of its columns, so
that the 3N x 41 Jacobian is never held whole):

``distance``
    Seed 002 eq. (9)-(16): the distance between two measured tool points
    equals the distance between the modelled ones, whatever the unknown
    transform between robot and instrument. The seed linearises the squared
    distance, eq. (13)-(14), and solves the normal equations, eq. (16), with
    the first pose as the only partner. Here the residual is the distance
    itself, ``r = ||P_k - P_j||_measured - ||P_k(x) - P_j(x)||``, with the
    exact Jacobian ``u^T (J_k - J_j)`` (``u`` the unit vector from ``P_j`` to
    ``P_k``), iterated to convergence, and every pair of training poses
    contributes (not only pairs with the first pose): ``K(K-1)/2`` distances
    instead of ``K - 1`` for ``K`` training poses, which is what makes the
    identified model generalise to poses it never saw.

``absolute``
    The measured points are the modelled ones in the instrument frame,
    ``P_meas = R P(x) + t``; the base transform ``(R, t)`` (6 parameters, a
    rotation vector and a translation) is identified with the kinematics.

Both are solved by :func:`station.analysis.lm_solver.levenberg_marquardt`
(the solver the diagnosis shares): the base transform and the tool row
first, then every identifiable parameter, then the same with a weak prior at
the start (:func:`prior_sd`) so that what the poses barely see stays near it.
Changes beyond plausible bounds and near-perfect correlations are warnings
(:func:`parameter_warnings`).

Identifiability is decided before iterating, explicitly, on the model's
structure (:func:`ideal_structure`: near-zero lengths and near-right angles
snapped, so a start that is itself a calibration does not unlock pairs
that are redundant by design):

* parallel consecutive axes (``alpha`` of 0 or +-180 deg) take the Hayati
  ``beta`` in place of ``d`` (seed 002 eq. (3)); elsewhere ``beta`` is fixed;
* parameters these poses cannot see but 200 poses spread over the joint
  space would are *held* and named (refused with ``strict``): they stay in
  the fit, where the weak prior at the start holds them as far as the poses
  leave them free (a joint that moved 20 degrees still says something about
  its offsets; fixing them there made the others absorb their error, and the
  held-out sweep of that joint missed by mm).  Without the prior they are
  fixed at their start;
* the remaining columns of the column-scaled identification Jacobian are
  taken in a preferred order and a column is kept only if it is not (to a
  relative 1e-6) a combination of the ones kept before it; what is dropped
  (zero columns, and redundancies such as seed 002 Table 3's bold entries) is
  fixed at its starting value and named with the reason;
* the SVD of the scaled Jacobian of what is kept gives the rank, the
  condition number and the observability indices, and the residuals give
  the parameters' 1-sigma uncertainties (``s^2 (J^T J)^-1``).

Units: mm and rad inside (``dh`` rows ``[a, alpha, d, theta, beta]``).
"""

from __future__ import annotations

import functools
import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from station.analysis.arm.lm_solver import Normal
from station.errors import DataError, InsufficientDataError
from station.models import frame_pass
from station.models import kinematics as kin
from station.models.rotation import matrix_to_rotvec, rotvec_to_matrix

__all__ = [
    "BASE_NAMES", "Identifiability", "IdentificationResult", "analyse_identifiability", "identify",
    "distance_pairs", "rigid_fit", "model_positions",
]

#: names of the base-transform parameters of the absolute formulation
BASE_NAMES = ("base_rx", "base_ry", "base_rz", "base_tx", "base_ty", "base_tz")
#: a column is redundant when less than this fraction of it lies outside the span of the kept ones
REDUNDANCY_TOL = 1e-6
#: consecutive axes closer than this to parallel use beta in place of d
PARALLEL_TOL_RAD = math.radians(5.0)
#: a Gauss-Newton step shorter than this many standard deviations is not taken
STEP_TOL_SIGMA = 0.01
_ANGLE = np.array([False, True, False, True, True])  # alpha, theta, beta are angles


def _is_angle(index: int) -> bool:
    return bool(_ANGLE[index % 5]) if index < kin.N_PARAMS else index - kin.N_PARAMS < 3


def _name(index: int) -> str:
    return kin.PARAM_NAMES[index] if index < kin.N_PARAMS else BASE_NAMES[index - kin.N_PARAMS]


@dataclass(frozen=True)
class Identifiability:
    """Which parameters are identified, which are fixed and why, and how well the data see them.

    Attributes
    ----------
    free : ndarray of int
        Indices of the identified parameters (0..34 kinematic, 35..40 base).
    fixed : dict
        ``name -> reason`` of every parameter kept at its starting value.
    singular_values : ndarray
        Of the column-scaled Jacobian of the free parameters (descending).
    condition_number : float
    observability : dict
        ``O1`` (geometric mean of the singular values over sqrt(m), Borm-Menq),
        ``O3`` (smallest singular value), ``O4`` (noise amplification index
        ``s_min^2 / s_max``).
    """

    free: np.ndarray
    fixed: dict
    singular_values: np.ndarray
    condition_number: float
    observability: dict

    @property
    def names(self) -> list[str]:
        return [_name(i) for i in self.free]


@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of :func:`identify` (not converging is a status, not an exception)."""

    dh: np.ndarray                 # (7, 5) identified model
    base_T: np.ndarray | None      # (4, 4) instrument <- robot base (absolute method)
    identifiability: Identifiability
    sigma: dict                    # name -> 1-sigma, in file units (mm, deg)
    rmse_per_iteration: list       # training residual RMS, mm (first: the starting model)
    iterations: int
    converged: bool
    message: str
    residual_rms_mm: float
    elapsed_s: float = 0.0
    extra: dict = field(default_factory=dict)


def model_positions(dh, q_rad) -> np.ndarray:
    return kin.tool_position(dh, q_rad)


def rigid_fit(src_mm: np.ndarray, dst_mm: np.ndarray) -> np.ndarray:
    """The rigid transform ``T`` (4, 4) with ``dst ~ R src + t`` in the least-squares sense (Kabsch)."""
    a, b = np.asarray(src_mm, float), np.asarray(dst_mm, float)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    H = (a - ca).T @ (b - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cb - R @ ca
    return T


def distance_pairs(n: int, *, max_partners: int = 60, seed: int = 0) -> np.ndarray:
    """Pairs ``(j, k)`` of training poses for the distance formulation, shape (M, 2).

    Every pair for up to ``max_partners + 1`` poses; beyond that each pose is
    paired with ``max_partners`` others drawn without repetition (so the
    problem grows linearly with the number of poses).
    """
    if n < 2:
        return np.zeros((0, 2), np.int64)
    if n <= max_partners + 1:
        j, k = np.triu_indices(n, 1)
        return np.column_stack([j, k])
    rng = np.random.default_rng(seed)
    j = np.repeat(np.arange(n), max_partners)
    k = (j + 1 + np.concatenate([rng.choice(n - 1, max_partners, replace=False) for _ in range(n)])) % n
    pairs = np.sort(np.column_stack([j, k]), axis=1)
    return np.unique(pairs, axis=0)


# --------------------------------------------------------------------------
# residuals and Jacobians of the two formulations
# --------------------------------------------------------------------------
def _distance_problem(dh, q, meas, pairs):
    T, J = kin.fk_and_param_jacobian(dh, q)
    p = T[:, :3, 3]
    d_model = p[pairs[:, 1]] - p[pairs[:, 0]]
    L_model = np.linalg.norm(d_model, axis=1)
    L_meas = np.linalg.norm(meas[pairs[:, 1]] - meas[pairs[:, 0]], axis=1)
    u = d_model / np.maximum(L_model, 1e-12)[:, None]
    Jd = np.einsum("mi,mij->mj", u, J[pairs[:, 1]] - J[pairs[:, 0]])
    return L_meas - L_model, Jd


def _base_T(x_base: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(x_base[:3])
    T[:3, 3] = x_base[3:]
    return T


def _absolute_problem(dh, x_base, q, meas):
    """``(r, J)`` of the absolute formulation, the whole Jacobian (3N, 41) at once (the reference poses'
    check and the pose selection; the identification sums it over blocks, :func:`_absolute_normal`)."""
    fp = frame_pass.frame_pass(dh, q, rotvec_to_matrix(x_base[:3]))
    r = (meas - (frame_pass.tool_points(fp) + x_base[3:])).reshape(-1)
    return r, _absolute_jacobian(fp)


def _absolute_jacobian(fp: frame_pass.FramePass, out=None) -> np.ndarray:
    """``d(R p + t) / d(dh, w, t)`` (3N, 41) from the pass turned by the base rotation ``R``; ``out``: an
    (N, 3, 41) array to write into."""
    Rp = frame_pass.tool_points(fp)
    n = Rp.shape[0]
    out = np.empty((n, 3, kin.N_PARAMS + 6)) if out is None else out
    frame_pass.param_jacobian(fp, out=out[:, :, :kin.N_PARAMS])   # already in the instrument frame
    # a small rotation w applied on the left: d(R p) = w x (R p)
    Jb = out[:, :, kin.N_PARAMS:]
    Jb[:, 0, 0] = Jb[:, 1, 1] = Jb[:, 2, 2] = 0.0
    Jb[:, 0, 1], Jb[:, 0, 2] = Rp[:, 2], -Rp[:, 1]
    Jb[:, 1, 0], Jb[:, 1, 2] = -Rp[:, 2], Rp[:, 0]
    Jb[:, 2, 0], Jb[:, 2, 1] = Rp[:, 1], -Rp[:, 0]
    Jb[:, :, 3:] = np.eye(3)
    return out.reshape(3 * n, -1)


def _absolute_jacobian_t(fp: frame_pass.FramePass, out: np.ndarray) -> np.ndarray:
    """:func:`_absolute_jacobian` laid out poses last, ``out`` (41, 3, N) (every column contiguous); returns
    its (41, 3N) view, columns ordered coordinate-major (``c N + n``)."""
    P = fp.axes[kin.N_ROWS, 3]                                     # (3, N): R p
    frame_pass.param_jacobian_t(fp, out=out[:kin.N_PARAMS])
    w = out[kin.N_PARAMS:kin.N_PARAMS + 3]                        # e_k x (R p)
    w[0, 0] = w[1, 1] = w[2, 2] = 0.0
    w[1, 0], w[2, 0] = P[2], -P[1]
    np.negative(P[2], out=w[0, 1])
    w[2, 1] = P[0]
    w[0, 2], w[1, 2] = P[1], -P[0]
    out[kin.N_PARAMS + 3:] = np.eye(3)[:, :, None]
    return out.reshape(kin.N_PARAMS + 6, -1)


#: poses per block of the absolute problem's blockwise pass: a block's Jacobian (1,536 x 41) and pass stay
#: in a core's cache (1 MB on this project's hosts), and no array of the whole problem's size is taken
_POSE_BLOCK = 512


class _Work:
    """Memory of the absolute problem's blockwise pass, Jacobian and QR, kept by each thread from one
    identification to the next (fresh memory costs page faults: 1,100 a call, 3-4 ms of system time, when
    every evaluation took its own 3 MB)."""

    def __init__(self):
        nc = kin.N_PARAMS + 6
        self.passes = frame_pass.PassBuffers(_POSE_BLOCK)
        self._jac = np.empty(_POSE_BLOCK * 3 * nc)
        self._qr = np.empty(nc * nc + max(3 * _POSE_BLOCK * nc, _QR_BLOCK_DOUBLES + nc))

    @staticmethod
    def block(n_poses: int) -> int:
        """Poses per block for ``n_poses``: blocks of equal size, at most :data:`_POSE_BLOCK`."""
        return max(-(-n_poses // max(-(-n_poses // _POSE_BLOCK), 1)), 1)

    def jac(self, k: int) -> np.ndarray:
        """A contiguous (41, 3, k) array for a block of ``k`` poses."""
        return self._jac[:k * 3 * (kin.N_PARAMS + 6)].reshape(kin.N_PARAMS + 6, 3, k)

    def qr_rows(self, rows: int, c: int) -> np.ndarray:
        """A contiguous (rows, c) array, ``rows <= c + max(3 block, 32768 / c)``."""
        return self._qr[:rows * c].reshape(rows, c)


_WORK = threading.local()


def _work() -> _Work:
    """This thread's :class:`_Work` (made on its first identification)."""
    work = getattr(_WORK, "work", None)
    if work is None or work.passes.capacity != _POSE_BLOCK:
        work = _WORK.work = _Work()
    return work


def _absolute_normal(dh, x_base, q, meas, *, r_cols=None):
    """``(r, Normal, R)`` of the absolute formulation, summed over blocks of poses.

    ``r`` (3N,): measured minus modelled; the normal equations (:class:`Normal`) of the Jacobian of
    :func:`_absolute_jacobian` (41 columns), never held whole; ``R``: when ``r_cols`` (column indices) is
    given, an upper-triangular ``R`` with ``R^T R = J[:, r_cols]^T J[:, r_cols]`` (the identifiability
    analysis's), by Householder QR of the blocks stacked on the running ``R`` (every step orthogonal);
    None otherwise.
    """
    work, block = _work(), _Work.block(q.shape[0])
    R = rotvec_to_matrix(x_base[:3])
    n, nc = q.shape[0], kin.N_PARAMS + 6
    r = np.empty((n, 3))
    JtJ, Jtr = np.zeros((nc, nc)), np.zeros(nc)
    if r_cols is not None:
        c = len(r_cols)
        # rows gathered before each QR: about 32768 doubles (256 KiB), at least a block
        W = work.qr_rows(c + max(3 * block, _QR_BLOCK_DOUBLES // max(c, 1)), c)
        filled = 0
    for s, fp in frame_pass.frame_passes(dh, q, R, buffers=work.passes, block=block):
        k = fp.axes.shape[-1]
        # the block's residual coordinate-major (3, k), as its Jacobian's columns
        rb = meas[s:s + k].T - fp.axes[kin.N_ROWS, 3] - x_base[3:, None]
        r[s:s + k] = rb.T
        Jt = _absolute_jacobian_t(fp, work.jac(k))      # (41, 3k): J^T of the block
        JtJ += Jt @ Jt.T
        Jtr += Jt @ rb.reshape(-1)
        if r_cols is not None:
            if filled + 3 * k > W.shape[0]:
                Rr = np.linalg.qr(W[:filled], mode="r")
                filled = Rr.shape[0]
                W[:filled] = Rr
            W[filled:filled + 3 * k] = Jt[r_cols].T
            filled += 3 * k
    Rc = None
    if r_cols is not None:
        # the last block's rows always follow the last QR, so one more is due whatever the row count: with
        # fewer rows than columns (a few poses, many open columns) the rows as stacked are not triangular
        Rc = np.linalg.qr(W[:filled], mode="r")
    return r.reshape(-1), Normal(JtJ, Jtr), Rc


def _tool_points(dh, q) -> np.ndarray:
    """Tool points (N, 3) of ``dh`` over the poses, from the blockwise pass."""
    p = np.empty((q.shape[0], 3))
    for s, fp in frame_pass.frame_passes(dh, q, buffers=_work().passes, block=_Work.block(q.shape[0])):
        p[s:s + fp.axes.shape[-1]] = frame_pass.tool_points(fp)
    return p


@dataclass(frozen=True)
class _WithPrior(Normal):
    """Normal equations with a prior's rows added, and those of the data alone (``data``)."""

    data: Normal | None = None


def _update_base(x_base: np.ndarray, step: np.ndarray) -> np.ndarray:
    out = np.empty(6)
    out[:3] = matrix_to_rotvec(rotvec_to_matrix(step[:3]) @ rotvec_to_matrix(x_base[:3]))
    out[3:] = x_base[3:] + step[3:]
    return out


# --------------------------------------------------------------------------
# identifiability
# --------------------------------------------------------------------------
def _structural(dh: np.ndarray, use_beta: bool = True) -> dict:
    """Parameters fixed by the model's structure (Hayati's beta only where axes are parallel).

    ``use_beta=False`` keeps the plain DH model (every beta fixed), as a UR
    controller's calibration deltas need; redundant ``d`` of parallel axes
    are then left to the redundancy analysis.
    """
    if not use_beta:
        return {kin.PARAM_NAMES[5 * i + 4]: "plain DH model asked (no beta)" for i in range(kin.N_ROWS)}
    fixed = {}
    for i in range(kin.N_JOINTS - 1):  # rows whose twist is between two joint axes
        alpha = float(dh[i, 1])
        parallel = abs(math.sin(alpha)) < math.sin(PARALLEL_TOL_RAD)
        if parallel:
            fixed[kin.PARAM_NAMES[5 * i + 2]] = f"axes {i + 1} and {i + 2} parallel: beta replaces d (eq. (3))"
        else:
            fixed[kin.PARAM_NAMES[5 * i + 4]] = "axes not parallel: beta is used only for parallel axes"
    fixed[kin.PARAM_NAMES[5 * 5 + 4]] = "flange row: beta is used only between parallel joint axes"
    fixed[kin.PARAM_NAMES[5 * 6 + 4]] = "tool row: beta does not move the tool point"
    return fixed


#: rows of one block of the QR below: 32768 doubles (256 KiB) a block, so that each stays in a core's cache
_QR_BLOCK_DOUBLES = 32768


def _r_factor(J: np.ndarray) -> np.ndarray:
    """An ``R`` (n, n) with ``R^T R = J^T J`` for a tall ``J`` (m, n), by Householder QR in blocks of rows.

    Each block's ``R`` and then the stacked ``R``s are reduced by QR (every step orthogonal, as stable as
    one QR of ``J``); a block the size of a core's cache runs about twice as fast as one QR of 3,000 rows.
    """
    m, n = J.shape
    b = max(2 * n, _QR_BLOCK_DOUBLES // max(n, 1))
    if m <= 2 * b:
        return np.linalg.qr(J, mode="r")
    k = m // b
    parts = [np.linalg.qr(J[:k * b].reshape(k, b, n), mode="r").reshape(k * n, n)]
    if k * b < m:
        parts.append(np.linalg.qr(J[k * b:], mode="r"))
    return np.linalg.qr(np.concatenate(parts), mode="r")


def analyse_identifiability(J: np.ndarray, n_kin_start_fixed: dict, *, n_params: int,
                            order: list[int] | None = None) -> Identifiability:
    """Decide the identified parameters from the Jacobian ``J`` (m, n_params) at the start.

    ``n_kin_start_fixed`` names parameters fixed beforehand (structure).
    Columns are scaled to unit norm and taken in ``order``; a column is kept
    when more than :data:`REDUNDANCY_TOL` of it lies outside the span of the
    kept ones.
    """
    cols = _open_columns(n_kin_start_fixed, n_params)
    Jc = J[:, cols]
    if J.shape[0] > cols.size:
        Jc = _r_factor(Jc)
    return _identifiability(np.linalg.norm(J, axis=0), Jc, J.shape[0], n_kin_start_fixed, n_params=n_params,
                            order=order)


def _open_columns(n_kin_start_fixed: dict, n_params: int) -> np.ndarray:
    """Indices of the columns not fixed beforehand (the identifiability analysis works on these alone)."""
    return np.array([j for j in range(n_params) if _name(j) not in n_kin_start_fixed], dtype=np.int64)


def _identifiability(norms: np.ndarray, Jc: np.ndarray, m: int, n_kin_start_fixed: dict, *, n_params: int,
                     order: list[int] | None = None) -> Identifiability:
    """:func:`analyse_identifiability` from the Jacobian's column norms (n_params,), its row count ``m`` and
    ``Jc``: the columns of :func:`_open_columns` or any ``Q^T`` of them (``Q`` orthogonal; e.g. their ``R``)."""
    # a column this much smaller than the largest is numerically zero (e.g. theta1 in the distances)
    norms = np.where(norms < 1e-9 * max(float(norms.max()), 1e-300), 0.0, norms)
    fixed = dict(n_kin_start_fixed)
    # every decision below depends on the columns not fixed beforehand, and on them only through their
    # inner products: work on a small R of those columns (R^T R = J^T J) when J is tall
    cols = _open_columns(fixed, n_params)
    at = np.full(n_params, -1)
    at[cols] = np.arange(cols.size)
    order = list(range(n_params)) if order is None else order
    kept: list[int] = []
    Q = np.zeros((Jc.shape[0], 0))
    for j in order:
        name = _name(j)
        if name in fixed:
            continue
        if norms[j] == 0.0 or not np.isfinite(norms[j]):
            fixed[name] = "no effect on the measurements (zero column)"
            continue
        c = Jc[:, at[j]] / norms[j]
        r = c - Q @ (Q.T @ c)
        r = r - Q @ (Q.T @ r)  # re-orthogonalise
        rn = float(np.linalg.norm(r))
        if rn < REDUNDANCY_TOL:
            # name the kept parameters it is a combination of (largest coefficients)
            coef = (np.linalg.lstsq(Jc[:, at[kept]] / norms[kept], c, rcond=None)[0] if kept else np.zeros(0))
            big = [_name(kept[i]) for i in np.argsort(-np.abs(coef))[:3] if abs(coef[i]) > 1e-3]
            fixed[name] = "redundant with " + (", ".join(big) if big else "the other parameters")
            continue
        kept.append(j)
        Q = np.column_stack([Q, r / rn])
    free = np.array(sorted(kept), dtype=np.int64)
    if free.size == 0:
        raise InsufficientDataError("no parameter is identifiable from these poses")
    Js = Jc[:, at[free]] / norms[free]
    s = np.linalg.svd(Js, compute_uv=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    obs = {"O1": float(np.prod(s ** (1.0 / s.size)) / math.sqrt(m)), "O3": float(s[-1]),
           "O4": float(s[-1] ** 2 / s[0])}
    return Identifiability(free, fixed, s, cond, obs)


def _unseen_by_poses(dh, ident: Identifiability, method: str, fixed0: dict, n_p: int, order) -> list[str]:
    """Parameters the given poses leave unidentified that 200 poses spread over the joint space would see."""
    seen = set(ident.names)
    ref = _reference_names(np.ascontiguousarray(dh).tobytes(), method, tuple(sorted(fixed0.items())), n_p, tuple(order))
    return [name for name in ref if name not in seen]


@functools.lru_cache(maxsize=32)
def _reference_names(dh_bytes: bytes, method: str, fixed0: tuple, n_p: int, order: tuple) -> tuple[str, ...]:
    """The parameters 200 well-spread poses identify (cached: the same start model is checked once)."""
    dh = np.frombuffer(dh_bytes, dtype=float).reshape(kin.N_ROWS, 5)
    rng = np.random.default_rng(0)
    q_ref = rng.uniform(-2.6, 2.6, (200, kin.N_JOINTS))
    p_ref = model_positions(dh, q_ref)
    if method == "distance":
        _, J_ref = _distance_problem(dh, q_ref, p_ref, distance_pairs(200, max_partners=20))
    else:
        _, J_ref = _absolute_problem(dh, np.zeros(6), q_ref, p_ref)
    return tuple(analyse_identifiability(J_ref, dict(fixed0), n_params=n_p, order=list(order)).names)


def _kin_order() -> list[int]:
    """Preferred order of the kinematic parameters: joint rows in order, per row theta, alpha, a, d, beta."""
    per_row = (3, 1, 0, 2, 4)
    return [5 * r + c for r in range(kin.N_ROWS) for c in per_row]


def _parameter_sd(H: np.ndarray, cost: float, info: int, method: str, meas: np.ndarray, pairs,
                  Jf: np.ndarray | None = None) -> np.ndarray:
    """1-sigma of the free parameters from the residuals at the solution.

    The absolute residuals are the measured coordinates' noise itself. The
    distance residuals are not independent: every pose enters many pairs, so
    ``(J^T J)^-1 s^2`` would understate the uncertainty by about the square
    root of the pairs per pose. Both are written as the noise ``e`` of the
    measured points (isotropic, variance ``s_p^2``) mapped into the residuals,
    ``r = D e``, and the covariance is the sandwich
    ``H^-1 (s_p^2 J^T D D^T J) H^-1`` with ``H = J^T J`` (given; the distance method also needs ``Jf``,
    the free columns of ``J``).
    """
    try:
        Hi = np.linalg.pinv(H)
    except np.linalg.LinAlgError:
        return np.full(H.shape[0], np.nan)
    dof = max(info - H.shape[0], 1)
    if method != "distance":
        return np.sqrt(np.clip(np.diag(Hi) * cost / dof, 0.0, None))
    m = Jf.shape[0]
    # r_jk = |m_k - m_j| - |p_k - p_j|: the noise enters as u_jk . (e_k - e_j)
    dm = meas[pairs[:, 1]] - meas[pairs[:, 0]]
    u = dm / np.maximum(np.linalg.norm(dm, axis=1), 1e-12)[:, None]
    G = np.zeros((meas.shape[0], 3, Jf.shape[1]))
    uJ = u[:, :, None] * Jf[:, None, :]
    np.add.at(G, pairs[:, 1], uJ)
    np.add.at(G, pairs[:, 0], -uJ)
    G = G.reshape(-1, Jf.shape[1])
    # E[r^T r] = s_p^2 trace(D D^T) (dof / info), and trace(D D^T) = 2 m
    s2_point = cost / (2.0 * m) * info / dof
    cov = Hi @ (s2_point * (G.T @ G)) @ Hi
    return np.sqrt(np.clip(np.diag(cov), 0.0, None))


#: a length this close to 0, or an angle this close to a multiple of 90 deg, is the structure's 0 or 90
SNAP_MM = 5.0
SNAP_DEG = 3.0


def ideal_structure(dh) -> np.ndarray:
    """The table with near-zero lengths and near-right angles snapped (what the arm is built to be).

    A start that is itself a calibration (a model file) carries offsets of
    a fraction of a millimetre where the design has none; they break the
    exact redundancies of the structure (``a5`` and ``theta5`` of a wrist
    whose ``a5`` is 0) without making the parameters any more visible: the
    fit then moves such a pair by tens of millimetres and degrees against
    each other. Identifiability is decided on this snapped table.
    """
    out = np.array(dh, dtype=float)
    for c in (0, 2):
        col = out[:, c]
        col[np.abs(col) < SNAP_MM] = 0.0
    for c in (1, 3):
        deg = np.degrees(out[:, c])
        near = np.round(deg / 90.0) * 90.0
        snap = np.abs(deg - near) < SNAP_DEG
        out[snap, c] = np.radians(near[snap])
    out[:, 4] = 0.0
    return out


# --------------------------------------------------------------------------
# plausibility of the identified changes
# --------------------------------------------------------------------------
#: changes beyond these are not what a real arm's build tolerances give (joint rows / tool row)
PLAUSIBLE_LENGTH_MM = 5.0
PLAUSIBLE_ANGLE_DEG = 1.0
PLAUSIBLE_TOOL_LENGTH_MM = 25.0
PLAUSIBLE_TOOL_ANGLE_DEG = 10.0
#: two identified parameters whose estimates correlate beyond this are named together
CORRELATION_WARN = 0.995


#: 1-sigma of the weak prior at the start (joint rows / tool row)
PRIOR_LENGTH_MM = 2.0
PRIOR_ANGLE_DEG = 0.5
PRIOR_TOOL_LENGTH_MM = 10.0
PRIOR_TOOL_ANGLE_DEG = 5.0


PRIOR_BASE_MM = 5.0
PRIOR_BASE_DEG = 0.1
#: a prior whose data cost exceeds the chi-square quantile of this upper tail (its degrees of freedom, times
#: the residual variance) contradicts the data and is not used
PRIOR_CONSISTENCY_P = 1e-3


@functools.lru_cache(maxsize=256)
def _chi2_isf(p: float, dof: int) -> float:
    """``chi2.isf(p, dof)`` (scipy's distributions cost about half a millisecond a call)."""
    return float(chi2.isf(p, dof))


def prior_sd(name: str) -> float:
    """1-sigma of the prior of a parameter in internal units (mm, rad)."""
    if name.startswith("base_"):
        return PRIOR_BASE_MM if name[5] == "t" else math.radians(PRIOR_BASE_DEG)
    tool = name.endswith("TCP")
    if name[0] in "ad" and not name.startswith("alpha"):  # a, d: lengths; alpha, theta, beta: angles
        return PRIOR_TOOL_LENGTH_MM if tool else PRIOR_LENGTH_MM
    return math.radians(PRIOR_TOOL_ANGLE_DEG if tool else PRIOR_ANGLE_DEG)


def plausible_bound(name: str) -> tuple[float, str]:
    """``(bound, unit)`` of the change of a kinematic parameter a real arm makes plausible."""
    tool = name.endswith("TCP")
    if name[0] in "ad":
        return (PLAUSIBLE_TOOL_LENGTH_MM if tool else PLAUSIBLE_LENGTH_MM), "mm"
    return (PLAUSIBLE_TOOL_ANGLE_DEG if tool else PLAUSIBLE_ANGLE_DEG), "deg"


def _change(i: int, dh_new, dh_old) -> float:
    v = float(dh_new.reshape(-1)[i] - dh_old.reshape(-1)[i])
    return math.degrees(v) if _is_angle(i) else v


def _correlations(H: np.ndarray) -> np.ndarray:
    """Correlations of the parameters from ``H = J^T J`` of their columns (scaled to unit norm first)."""
    sc = np.sqrt(np.diag(H))
    sc[sc == 0] = 1.0
    C = np.linalg.pinv(H / np.outer(sc, sc))
    d = np.sqrt(np.maximum(np.diag(C), 1e-300))
    return C / np.outer(d, d)


def parameter_warnings(dh_new, dh_start, free, Jf, sigma: dict) -> list[dict]:
    """Implausible changes and near-perfect correlations among the identified kinematic parameters.

    Each warning: ``kind`` (``"implausible"`` or ``"correlated"``), ``parameters`` (names), ``message``.
    ``Jf``: the Jacobian's columns of ``free``.
    """
    return _warnings(dh_new, dh_start, free, Jf.T @ Jf, sigma)


def _warnings(dh_new, dh_start, free, H, sigma: dict) -> list[dict]:
    """:func:`parameter_warnings` from ``H = Jf^T Jf``."""
    out = []
    kin_free = [int(i) for i in free if i < kin.N_PARAMS]
    for i in kin_free:
        name = _name(i)
        bound, unit = plausible_bound(name)
        ch = _change(i, dh_new, dh_start)
        if abs(ch) > bound:
            out.append({"kind": "implausible", "parameters": [name], "change": ch, "unit": unit, "bound": bound,
                        "message": f"{name} changes by {ch:+.4g} {unit} (+-{sigma.get(name, math.nan):.2g}), beyond "
                                   f"the {bound:g} {unit} a real arm's tolerances make plausible: the poses leave it "
                                   "nearly free, and the fit uses it to absorb something else"})
    if len(kin_free) >= 2:
        pos = [k for k, i in enumerate(free) if i < kin.N_PARAMS]
        rho = _correlations(H)[np.ix_(pos, pos)]
        a, b = np.nonzero(np.triu(np.abs(rho) > CORRELATION_WARN, 1))
        for x, y in zip(a, b):
            n1, n2 = _name(kin_free[x]), _name(kin_free[y])
            out.append({"kind": "correlated", "parameters": [n1, n2], "rho": float(rho[x, y]),
                        "message": f"{n1} and {n2} are estimated together (correlation {rho[x, y]:+.4f}): the poses "
                                   "tell little more than a combination of them"})
    return out


# --------------------------------------------------------------------------
# identification
# --------------------------------------------------------------------------
def identify(dh_start, q_rad, measured_mm, *, method: str = "distance", pairs=None, base_T_start=None,
             max_iter: int = 100, tol: float = 1e-10, fixed_extra: dict | None = None,
             free_extra=(), use_beta: bool = True, strict: bool = False,
             allow_rank_deficient: bool | None = None, prior: bool = True) -> IdentificationResult:
    """Identify the kinematic parameters (and the base transform) from measured tool points.

    Parameters
    ----------
    dh_start : array_like, shape (7, 5)
        Starting model (nominal), mm and rad.
    q_rad : array_like, shape (N, 6)
        Joint angles of the measured poses.
    measured_mm : array_like, shape (N, 3)
        Measured tool points in the instrument frame.
    method : ``"distance"`` or ``"absolute"``
    pairs : array_like of int, shape (M, 2), optional
        Distance pairs (default :func:`distance_pairs` over all poses).
    base_T_start : array_like, shape (4, 4), optional
        Starting instrument <- base transform (absolute; default a rigid fit
        of the nominal points to the measured ones).
    max_iter, tol
        Iteration limit and relative cost change at which it has converged
        (:func:`station.analysis.lm_solver.levenberg_marquardt`; also
        converged when the next step is under :data:`STEP_TOL_SIGMA`
        standard deviations).
    fixed_extra : dict, optional
        ``name -> reason`` of further parameters to hold fixed (``--fix``).
    free_extra : iterable of str
        Parameters to identify even where the model's structure would fix
        them (a Hayati beta, a ``d`` of parallel axes) and to prefer over a
        redundant partner (``--free d_TCP`` keeps the tool's z and fixes
        ``d6`` instead).
    use_beta : bool
        Hayati's beta for parallel joint axes (default); False for a plain DH
        model (UR calibration deltas).
    strict : bool
        Refuse (InsufficientDataError naming them) poses that cannot see a
        parameter which well-spread poses of this arm would see. By default
        such parameters are fixed at their start and named with the reason.

    prior : bool
        After the least-squares fit, refit with a weak Gaussian prior at the
        start (1-sigma :data:`PRIOR_LENGTH_MM`, :data:`PRIOR_ANGLE_DEG`; the
        tool row wider), weighted by the fit's own noise: parameters the
        data see are not moved by it, parameters the poses barely see (a
        joint that hardly moved) stay near the start instead of following
        the noise into extrapolation. False: plain least squares.

    The fit runs in two stages on the same solver: the base transform and
    the tool row first (the nominal model's largest misfit on a new cell is
    where the instrument and the reflector are), then everything identifiable.
    """
    t0 = time.perf_counter()
    if allow_rank_deficient is not None:
        strict = not allow_rank_deficient
    if method not in ("distance", "absolute"):
        raise DataError(f"`method` must be 'distance' or 'absolute', got {method!r}")
    dh = kin.validate_dh(dh_start).copy()
    if dh.shape != (kin.N_ROWS, 5):
        raise DataError(f"`dh_start` must have shape (7, 5), got {dh.shape}")
    dh_start_arr = dh.copy()
    q = np.asarray(q_rad, dtype=float)
    meas = np.asarray(measured_mm, dtype=float)
    if q.ndim != 2 or q.shape[1] != kin.N_JOINTS:
        raise DataError(f"`q_rad` must have shape (N, 6), got {q.shape}")
    if meas.shape != (q.shape[0], 3):
        raise DataError(f"`measured_mm` must have shape ({q.shape[0]}, 3), got {meas.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(meas))):
        raise DataError("joint angles and measured points must be finite")
    known = set(kin.PARAM_NAMES) | set(BASE_NAMES)
    for nm in list(fixed_extra or {}) + list(free_extra):
        if nm not in known:
            raise DataError(f"unknown parameter {nm!r} (names: a1, alpha1, d1, theta1, beta1, ..., a6, ..., "
                            "aTCP, alphaTCP, dTCP, thetaTCP, betaTCP, base_rx, ..., base_tz)")
    both = set(fixed_extra or {}) & set(free_extra)
    if both:
        raise DataError(f"{', '.join(sorted(both))}: asked to be both fixed and free")
    n = q.shape[0]
    n_p = kin.N_PARAMS if method == "distance" else kin.N_PARAMS + 6
    order = _kin_order() if method == "distance" else list(range(kin.N_PARAMS, n_p)) + _kin_order()
    fixed0 = _structural(dh, use_beta)
    prefer = [i for i in range(n_p) if _name(i) in set(free_extra)]
    for nm in free_extra:
        fixed0.pop(nm, None)
    order = prefer + [i for i in order if i not in prefer]
    fixed0.update(fixed_extra or {})
    dh_ideal = ideal_structure(dh)
    # identifiability is the structure's: judged where the near-zero offsets are zero
    same_structure = np.array_equal(dh_ideal, dh)
    if method == "distance":
        pairs = distance_pairs(n) if pairs is None else np.asarray(pairs, dtype=np.int64)
        if pairs.ndim != 2 or pairs.shape[1] != 2 or pairs.size == 0 or pairs.min() < 0 or pairs.max() >= n:
            raise DataError(f"`pairs` must be (M, 2) pose indices in 0..{n - 1}")
        x_base = None
        r, J = _distance_problem(dh, q, meas, pairs)
        J_id = J if same_structure else _distance_problem(dh_ideal, q, meas, pairs)[1]
        ident = analyse_identifiability(J_id, fixed0, n_params=n_p, order=order)
        del J_id
    else:
        # the Jacobian is never held whole: its normal equations, and the R of its open columns for the
        # identifiability analysis, are summed over blocks of poses
        p_start = _tool_points(dh, q)
        B0 = rigid_fit(p_start, meas) if base_T_start is None else np.asarray(base_T_start, float)
        x_base = np.concatenate([matrix_to_rotvec(B0[:3, :3]), B0[:3, 3]])
        cols = _open_columns(fixed0, n_p)
        r, J, Rc = _absolute_normal(dh, x_base, q, meas, r_cols=cols if same_structure else None)
        N_id = J
        if not same_structure:
            _, N_id, Rc = _absolute_normal(dh_ideal, x_base, q, meas, r_cols=cols)
        norms = np.sqrt(np.diag(N_id.JtJ)) if isinstance(N_id, Normal) else np.linalg.norm(N_id, axis=0)
        ident = _identifiability(norms, Rc, 3 * n, fixed0, n_params=n_p, order=order)
        del N_id, Rc
    unseen = _unseen_by_poses(dh_ideal, ident, method, fixed0, n_p, order)
    # independent numbers in the data: K points carry 3K coordinates, and distances lose the 6 of a rigid motion
    info = 3 * n - (6 if method == "distance" else 0)
    n_wanted = ident.free.size + (len(unseen) if strict else 0)
    if info <= n_wanted:
        need = (n_wanted + (6 if method == "distance" else 0)) // 3 + 1
        raise InsufficientDataError(
            f"{n} poses give {info} independent numbers for {n_wanted} parameters: "
            f"the {method} method needs at least {need} poses here")
    if unseen and strict:
        raise InsufficientDataError(
            "these poses cannot see " + ", ".join(f"{k} ({ident.fixed[k]})" for k in unseen)
            + ": measure poses that move every joint (or leave out --strict to fix them)")
    fixed = dict(ident.fixed)
    held: dict[str, str] = {}
    for k in unseen:
        why = fixed.pop(k)
        if prior:
            held[k] = (f"held at its start by the prior: these poses cannot see it ({why}); poses that move every "
                       "joint would")
        else:
            fixed[k] = f"fixed at its start: these poses cannot see it ({why}); poses that move every joint would"
    free_all = np.array(sorted(set(ident.free.tolist()) | {i for i in range(n_p) if _name(i) in held}),
                        dtype=np.int64)
    ident = Identifiability(free_all, fixed, ident.singular_values, ident.condition_number, ident.observability)
    free = ident.free

    def evaluate(st):
        dh_, xb_ = st
        return (_distance_problem(dh_, q, meas, pairs) if method == "distance" else
                _absolute_normal(dh_, xb_, q, meas)[:2])

    def apply(st, full):
        dh_, xb_ = st
        dh_new = dh_ + full[:kin.N_PARAMS].reshape(kin.N_ROWS, 5)
        xb_new = _update_base(xb_, full[kin.N_PARAMS:]) if xb_ is not None else None
        return dh_new, xb_new

    from station.analysis.arm.lm_solver import levenberg_marquardt

    x_base0 = None if x_base is None else x_base.copy()
    # stage 1: base transform and tool row
    stage1 = np.array([i for i in free if i >= kin.N_PARAMS or i >= 5 * (kin.N_ROWS - 1)], dtype=np.int64)
    state = (dh, x_base)
    hist_states, hist_rms = [state], [math.sqrt(float(r @ r) / r.size)]
    it1 = 0
    # each fit starts where the last ended, with its residual and Jacobian, handed over (popped) so that the
    # fit alone holds them: a Jacobian of 1,000 poses is 1 MB, and fresh memory costs page faults
    at_state = [(r, J)]
    del r, J
    if 0 < stage1.size < free.size:
        s1 = levenberg_marquardt(evaluate, apply, state, free=stage1, max_iter=max_iter, rtol=tol,
                                 step_tol_sigma=STEP_TOL_SIGMA, keep_states=True, start=at_state.pop())
        state, it1 = s1.state, s1.iterations
        at_state = [(s1.r, s1.J)]
        hist_states += s1.states[1:]
        hist_rms += s1.rms_history[1:]
        del s1
    sol = levenberg_marquardt(evaluate, apply, state, free=free, max_iter=max_iter, rtol=tol,
                              step_tol_sigma=STEP_TOL_SIGMA, keep_states=True, start=at_state.pop())
    hist_states += sol.states[1:]
    hist_rms += sol.rms_history[1:]
    prior_note = None
    pri = np.array([i for i in free], dtype=np.int64)
    if prior and pri.size and sol.r.size > free.size:
        # a weak prior at the start (the build tolerances; the base near the nominal model's rigid fit):
        # well-seen parameters do not feel it, parameters the poses barely see (a joint that hardly moved)
        # stay near their start instead of following the noise into extrapolation
        s_noise = math.sqrt(sol.cost / (sol.r.size - free.size))
        psd = np.array([prior_sd(_name(i)) for i in pri])
        if x_base0 is not None:
            # the nominal model's rigid fit places the base only as well as the nominal model fits: its
            # misfit over the spread of the points bounds the rotation, the misfit itself the translation
            B0 = _base_T(x_base0)
            miss = math.sqrt(float(np.mean(np.sum((meas - p_start @ B0[:3, :3].T - B0[:3, 3]) ** 2, axis=1))))
            spread = math.sqrt(float(np.mean(np.sum((meas - meas.mean(axis=0)) ** 2, axis=1))))
            for k, i in enumerate(pri):
                if i >= kin.N_PARAMS:
                    psd[k] = max(psd[k], 3.0 * (miss / max(spread, 1e-9) if i < kin.N_PARAMS + 3 else miss))
        x_start = np.concatenate([dh_start_arr.reshape(-1), x_base0 if x_base0 is not None else np.zeros(0)])
        m_data = sol.r.size

        def flat(st):
            return np.concatenate([st[0].reshape(-1), st[1] if st[1] is not None else np.zeros(0)])

        def with_prior(keep: np.ndarray):
            idx, w = pri[keep], s_noise / psd[keep]

            def rows(st, r_, J_):
                rp = w * (x_start[idx] - flat(st)[idx])
                if isinstance(J_, Normal):   # the prior's rows w e_idx add w^2 to the diagonal and w rp to J^T r
                    JtJ, Jtr = J_.JtJ.copy(), J_.Jtr.copy()
                    JtJ[idx, idx] += w * w
                    Jtr[idx] += w * rp
                    return np.concatenate([r_, rp]), _WithPrior(JtJ, Jtr, J_)
                Jp = np.zeros((idx.size, n_p))
                Jp[np.arange(idx.size), idx] = w
                return np.concatenate([r_, rp]), lambda: np.concatenate([J_() if callable(J_) else J_, Jp])

            def evaluate_prior(st):
                return rows(st, *evaluate(st))

            return levenberg_marquardt(evaluate_prior, apply, sol.state, free=free, max_iter=max_iter, rtol=tol,
                                       step_tol_sigma=STEP_TOL_SIGMA, keep_states=True,
                                       start=rows(sol.state, sol.r, sol.J))

        # a weak prior costs the data little: beyond the chi-square bound of its own degrees of freedom it
        # contradicts the data. The base's prior (the nominal model's rigid fit) is the one that can: over a
        # scanner's small field the nominal misfit turns the rigid fit by more than its bound, and a base held
        # there made the arm's parameters absorb the turn (15 poses of a scanner cell: the training poses' mean
        # error 0.03 -> 0.17 mm, d3 +6.8 mm, held-out 0.08 -> 0.17 mm). Then the base goes free of it; if the
        # rest still contradicts the data, only what the poses cannot see is held.
        tries = [np.ones(pri.size, bool)]
        if np.any(pri >= kin.N_PARAMS):
            tries.append(pri < kin.N_PARAMS)
        solp, used = None, None
        for keep in tries:
            cand = with_prior(keep)
            r_c = cand.r[:m_data]   # the data's part of its residual
            if float(r_c @ r_c) - sol.cost <= _chi2_isf(PRIOR_CONSISTENCY_P, int(keep.sum())) * s_noise ** 2:
                solp, used = cand, keep
                break
        if solp is not None:
            base_part = (f"base {PRIOR_BASE_MM:g} mm / {PRIOR_BASE_DEG:g} deg from the nominal model's rigid fit"
                         if used.all() and x_base0 is not None else
                         "base free: the nominal model's rigid fit contradicted the data" if x_base0 is not None
                         else "no base")
            prior_note = (f"weak prior at the start: 1-sigma {PRIOR_LENGTH_MM:g} mm / {PRIOR_ANGLE_DEG:g} deg "
                          f"(tool row {PRIOR_TOOL_LENGTH_MM:g} mm / {PRIOR_TOOL_ANGLE_DEG:g} deg; {base_part})")
        else:
            prior_note = "no prior: the weak prior at the start contradicted the data (chi-square bound)"
            keep = np.array([_name(i) in held for i in pri], dtype=bool)
            if keep.any():  # what the poses cannot see is still held (they add next to nothing to it)
                solp = with_prior(keep)
                prior_note += f"; the parameters the poses cannot see are held by it ({', '.join(sorted(held))})"
        if solp is not None:
            hist_states += solp.states[1:]
            hist_rms += [math.sqrt(float(np.sum(evaluate(st)[0] ** 2)) / m_data) for st in solp.states[1:]]
            r_d = solp.r[:m_data]
            J_d = solp.J.data if isinstance(solp.J, _WithPrior) else solp.J[:m_data]
            # the solution is the fit with the prior: it converged or not. The fit without it is its start and
            # the reference of the chi-square check; along directions the poses barely see it may wander
            # without end (36 poses, joint 4 moved 15 deg: a3 crept 3.7 mm per 20 steps at 1e-6 relative gain
            # each, for 100 steps), and then its cost is an upper bound of its minimum
            if not sol.converged:
                prior_note += (f"; the fit without the prior did not settle in {sol.iterations} steps (it wanders "
                               "along what these poses barely see), the prior's fit started from where it stopped")
            sol = type(sol)(solp.state, r_d, J_d, float(r_d @ r_d), sol.iterations + solp.iterations,
                            solp.converged, solp.message, sol.rms_history, sol.states)
    dh, x_base = sol.state
    J, cost, m = sol.J, sol.cost, sol.r.size
    # uncertainties from the residuals at the solution; a held parameter's is its prior's (the poses add
    # next to nothing to it), and it takes no part in the warnings (its change is the prior's to keep small)
    seen = np.array([i for i in free if _name(i) not in held], dtype=np.int64)
    J_seen = None if isinstance(J, Normal) else J[:, seen]
    H_seen = J.JtJ[np.ix_(seen, seen)] if J_seen is None else J_seen.T @ J_seen
    sd = _parameter_sd(H_seen, cost, info, method, meas, pairs, J_seen)
    sd_seen = dict(zip(seen.tolist(), sd.tolist()))
    sigma = {}
    for i in free:
        v = prior_sd(_name(i)) if _name(i) in held else float(sd_seen[int(i)])
        sigma[_name(i)] = math.degrees(v) if _is_angle(int(i)) else v
    warnings = _warnings(dh, dh_start_arr, seen, H_seen, sigma)
    base_T = _base_T(x_base) if x_base is not None else None
    return IdentificationResult(dh, base_T, ident, sigma, hist_rms, it1 + sol.iterations, sol.converged, sol.message,
                                math.sqrt(cost / m), time.perf_counter() - t0,
                                {"n_residuals": m, "method": method, "warnings": warnings, "prior": prior_note,
                                 "unseen": list(unseen), "held": held, "stage1_iterations": it1,
                                 "history": [(h, None if xb is None else _base_T(xb)) for h, xb in hist_states]})
