"""Choosing the measurement poses of an arm calibration (seed 002 sec. 3).

The seed measures 64 poses spread by hand. What a pose contributes is the
information its tool point carries about the parameters: the rows of the
identification Jacobian. :func:`select_poses` picks, from a set of candidate
poses the cell allows (:func:`admissible`: inside the joint limits and the
safety gate's workspace box, the reflector or the jig facing the
instrument), the ``n`` that together maximise the determinant of the scaled
information matrix ``Js^T Js`` (D-optimal design; the observability index O1
of the seed's literature is its ``p``-th root). The greedy choice adds, one
at a time, the pose that raises ``log det`` most; with ``M`` the information
so far and ``J_i`` a candidate's 3 rows,

    det(M + J_i^T J_i) = det(M) det(I_3 + J_i M^-1 J_i^T),

so every candidate is scored at once. Fedorov exchange passes then swap a
chosen pose for a candidate while that raises ``log det``, until no single
swap does.

The information is that of the absolute formulation *with* the base
transform free: the kinematic part of it (the Schur complement over the
base) is what distance errors see as well, so the same choice serves both
methods.

Pure: arrays in, results out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.analysis.arm.identification import (
    _absolute_problem,
    _kin_order,
    _structural,
    analyse_identifiability,
)
from station.errors import DataError, InsufficientDataError
from station.models import kinematics as kin


#: the exchange passes stop earlier when a pass swaps nothing
MAX_EXCHANGE_PASSES = 20


@dataclass(frozen=True)
class PoseSelection:
    """The chosen poses and how much they see.

    Attributes
    ----------
    indices : ndarray of int
        Rows of the candidate set, in the order chosen.
    log_det : float
        ``log det(Js^T Js)`` of the chosen poses (columns scaled over the candidates).
    o1 : float
        Observability index O1: ``det^(1/2p) / sqrt(rows)``.
    parameters : list of str
        The parameters the information is about (identifiable, base included).
    swaps : int
        Exchanges the Fedorov pass made.
    """

    indices: np.ndarray
    log_det: float
    o1: float
    parameters: list
    swaps: int


def admissible(dh, q_rad, *, joint_limits_rad, box_min_mm=None, box_max_mm=None, instrument_mm=None,
               facing_axis_tool=(0.0, 0.0, 1.0), half_angle_deg: float = 30.0,
               range_mm: tuple[float, float] = (0.0, math.inf)) -> np.ndarray:
    """(N,) bool: candidate poses the cell allows.

    Parameters
    ----------
    dh : (7, 5) model (nominal), mm and rad
    q_rad : (N, 6) candidate joint vectors
    joint_limits_rad : (6, 2)
    box_min_mm, box_max_mm : (3,), optional
        The safety gate's workspace box (robot base frame).
    instrument_mm : (3,), optional
        Where the tracker or scanner stands, robot base frame. With it, a pose
        is kept only when the tool axis ``facing_axis_tool`` points at the
        instrument within ``half_angle_deg`` (a reflector's acceptance angle,
        or the jig corner's view cone) and the distance is within ``range_mm``.
    """
    q = np.asarray(q_rad, dtype=float)
    lim = np.asarray(joint_limits_rad, dtype=float)
    ok = np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), axis=1)
    T = kin.fk(dh, q)
    p = T[:, :3, 3]
    if box_min_mm is not None and box_max_mm is not None:
        ok &= np.all((p >= np.asarray(box_min_mm, float)) & (p <= np.asarray(box_max_mm, float)), axis=1)
    if instrument_mm is not None:
        to_inst = np.asarray(instrument_mm, float) - p
        dist = np.linalg.norm(to_inst, axis=1)
        axis = T[:, :3, :3] @ np.asarray(facing_axis_tool, float)
        cosang = np.einsum("ij,ij->i", axis, to_inst) / np.maximum(dist * np.linalg.norm(axis, axis=1), 1e-12)
        ok &= cosang >= math.cos(math.radians(half_angle_deg))
        ok &= (dist >= range_mm[0]) & (dist <= range_mm[1])
    return ok


def _jacobian(dh, q: np.ndarray) -> np.ndarray:
    """Absolute-formulation Jacobian with the base free, (3N, 41)."""
    return _absolute_problem(dh, np.zeros(6), q, kin.tool_position(dh, q))[1]


def _information_rows(dh, q: np.ndarray, use_beta: bool, q_scale: np.ndarray | None = None):
    """Scaled Jacobian rows (N, 3, p) of the identifiable parameters (base included), and their names.

    The identifiable set and the column scales (per-pose RMS of each column)
    are those of ``q_scale`` (default ``q``), so two pose sets are compared
    in the same units.
    """
    n_p = kin.N_PARAMS + 6
    ref = q if q_scale is None else q_scale
    J_ref = _jacobian(dh, ref)
    order = list(range(kin.N_PARAMS, n_p)) + _kin_order()
    ident = analyse_identifiability(J_ref, _structural(np.asarray(dh, float), use_beta), n_params=n_p, order=order)
    scale = np.linalg.norm(J_ref[:, ident.free], axis=0) / math.sqrt(ref.shape[0])
    scale[scale == 0] = 1.0
    J = J_ref if q_scale is None else _jacobian(dh, q)
    return (J[:, ident.free] / scale).reshape(q.shape[0], 3, -1), ident.names


def _gains(Jr: np.ndarray, Mi: np.ndarray) -> np.ndarray:
    """``log det(I + J_i M^-1 J_i^T)`` of every candidate ``i`` (C,)."""
    c, _, p = Jr.shape
    JM = (Jr.reshape(-1, p) @ Mi).reshape(c, 3, p)
    S = np.matmul(JM, Jr.transpose(0, 2, 1))  # (C, 3, 3)
    return np.linalg.slogdet(np.eye(3) + S)[1]


def _log_det(M: np.ndarray) -> float:
    sign, ld = np.linalg.slogdet(M)
    return float(ld) if sign > 0 else -math.inf


def select_poses(dh, candidates_q_rad, n: int, *, use_beta: bool = True, exchange: bool = True,
                 regularisation: float = 1e-6) -> PoseSelection:
    """Choose ``n`` of the candidate poses that maximise ``log det(Js^T Js)`` (D-optimal).

    Parameters
    ----------
    dh : (7, 5) model (nominal)
    candidates_q_rad : (C, 6) admissible candidate poses (see :func:`admissible`)
    n : int
        Poses to choose; at least enough for the identifiable parameters.
    use_beta : bool
        Hayati's beta for parallel axes (as :func:`identify`).
    exchange : bool
        Run the Fedorov exchange pass after the greedy choice.
    regularisation : float
        ``eps * I`` added while fewer poses than parameters are chosen.
    """
    q = np.asarray(candidates_q_rad, dtype=float)
    if q.ndim != 2 or q.shape[1] != kin.N_JOINTS:
        raise DataError(f"candidate poses must have shape (C, 6), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise DataError("candidate poses must be finite")
    Jr, names = _information_rows(dh, q, use_beta)
    p = Jr.shape[2]
    need = p // 3 + 1
    if n < need:
        raise InsufficientDataError(f"{n} poses cannot identify {p} parameters (3 numbers a pose): choose at least {need}")
    if n > q.shape[0]:
        raise InsufficientDataError(f"{n} poses asked from {q.shape[0]} admissible candidates")
    M = regularisation * np.eye(p)
    chosen: list[int] = []
    free = np.ones(q.shape[0], bool)
    for _ in range(n):
        gain = _gains(Jr, np.linalg.inv(M))
        gain[~free] = -np.inf
        k = int(np.argmax(gain))
        chosen.append(k)
        free[k] = False
        M = M + Jr[k].T @ Jr[k]
    swaps = 0
    if exchange:
        M = sum(Jr[k].T @ Jr[k] for k in chosen)
        for _pass in range(MAX_EXCHANGE_PASSES):
            swapped = False
            for pos in range(len(chosen)):
                k_out = chosen[pos]
                M_minus = M - Jr[k_out].T @ Jr[k_out]
                if _log_det(M_minus) == -math.inf:
                    continue
                Mi = np.linalg.inv(M_minus)
                gain = _gains(Jr, Mi)
                gain[~free] = -np.inf
                k_in = int(np.argmax(gain))
                own = float(np.linalg.slogdet(np.eye(3) + Jr[k_out] @ Mi @ Jr[k_out].T)[1])
                if gain[k_in] > own + 1e-9:
                    chosen[pos] = k_in
                    free[k_in], free[k_out] = False, True
                    M = M_minus + Jr[k_in].T @ Jr[k_in]
                    swaps += 1
                    swapped = True
            if not swapped:
                break
    idx = np.array(chosen, dtype=np.int64)
    ld = _log_det(sum(Jr[k].T @ Jr[k] for k in chosen))
    o1 = math.exp(ld / (2 * p)) / math.sqrt(3 * n) if math.isfinite(ld) else 0.0
    return PoseSelection(idx, ld, o1, names, swaps)


def information_log_det(dh, q_rad, *, reference_q_rad, use_beta: bool = True) -> float:
    """``log det(Js^T Js)`` of the poses ``q_rad``, in the parameters and scales of ``reference_q_rad``."""
    Jr, _ = _information_rows(dh, np.asarray(q_rad, float), use_beta, np.asarray(reference_q_rad, float))
    J = Jr.reshape(-1, Jr.shape[2])
    return _log_det(J.T @ J)
