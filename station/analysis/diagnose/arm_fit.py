"""The extended arm model of the diagnosis: prediction, Jacobian and its damped least-squares fit.

``P_meas = R p(dh', q + dq) + t`` where ``(R, t)`` is the instrument <- base
transform, ``dh'`` the nominal table plus the geometric deviations (seed 002
eq. (3)) scaled by the thermal term, and ``dq`` the sum of the joint terms
(:mod:`.terms`). The Jacobian is analytic: kinematic columns from seed 002
eq. (7)-(8) (:func:`station.models.kinematics.fk_and_param_jacobian`), joint
columns from the theta columns (a joint angle and its zero offset move the
tool point alike), base columns ``e_k x (R p)`` and ``e_k``.

Uncertainties are cluster-robust by pose (the sandwich
``(A'A)^-1 (sum_k A_k' r_k r_k' A_k) (A'A)^-1`` with the small-sample factor
``n / (n - p/3)``): the three coordinates of a pose share its stopping error,
so they are neither independent nor equally noisy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from station.analysis.arm.identification import rigid_fit
from station.models import kinematics as kin
from station.models.effects import LENGTH_PARAMS, scale_lengths

from .terms import Term

__all__ = ["ModelState", "predict", "jacobian", "fit", "fit_report", "robust_cov", "classical_floor"]

_THETA_COLS = np.arange(6) * 5 + 3
_LEN_COLS = LENGTH_PARAMS


@dataclass
class ModelState:
    """Nominal table, base transform and the selected terms with their parameters."""

    dh_nominal: np.ndarray
    R: np.ndarray
    t: np.ndarray
    terms: list = field(default_factory=list)
    theta: list = field(default_factory=list)
    base0: tuple | None = None   # (R, t) of the nominal model's rigid fit: where the prior holds the base

    def copy(self) -> "ModelState":
        return ModelState(self.dh_nominal, self.R.copy(), self.t.copy(), list(self.terms),
                          [th.copy() for th in self.theta], self.base0)

    def with_term(self, term: Term) -> "ModelState":
        s = self.copy()
        s.terms.append(term)
        s.theta.append(np.zeros(term.k))
        return s

    @property
    def n_params(self) -> int:
        return 6 + sum(term.k for term in self.terms)

    def dh_static(self) -> np.ndarray:
        dh = np.array(self.dh_nominal, dtype=float)
        for term, th in zip(self.terms, self.theta):
            if term.kind == "geometric":
                flat = dh.reshape(-1)
                flat[term.index] += th
        return dh


def _evaluate(state: ModelState, q: np.ndarray, rows: np.ndarray):
    dh0 = state.dh_static()
    dq = np.zeros((rows.size, 6))
    scale = None
    for term, th in zip(state.terms, state.theta):
        if term.kind == "joint":
            dq[:, term.joint - 1] += term.features[rows] @ th
        elif term.kind == "scale":
            s = term.features[rows] @ th
            scale = s if scale is None else scale + s
    dh = dh0 if scale is None else scale_lengths(np.broadcast_to(dh0, (rows.size, 7, 5)), scale)
    return dh0, dh, q[rows] + dq


def predict(state: ModelState, q: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Predicted instrument-frame points (len(rows), 3), mm."""
    _, dh, qe = _evaluate(state, q, rows)
    p = kin.tool_position(dh, qe)
    return p @ state.R.T + state.t


def term_columns(term: Term, Jp: np.ndarray, dh0: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Base-frame Jacobian columns (n, 3, k) of one term at the current model."""
    if term.kind == "geometric":
        return Jp[:, :, term.index]
    if term.kind == "joint":
        return Jp[:, :, _THETA_COLS[term.joint - 1]][:, :, None] * term.features[rows][:, None, :]
    lengths = dh0.reshape(-1)[_LEN_COLS]
    dp_ds = np.einsum("nij,j->ni", Jp[:, :, _LEN_COLS], lengths)
    return dp_ds[:, :, None] * term.features[rows][:, None, :]


def jacobian(state: ModelState, q: np.ndarray, rows: np.ndarray, extra_terms=()):
    """``(pred (n, 3), A (n, 3, p), [(term, A_term (n, 3, k)), ...])`` in the instrument frame.

    ``A`` columns: base rotation (3), base translation (3), then the state's terms in order.
    """
    dh0, dh, qe = _evaluate(state, q, rows)
    T, Jp = kin.fk_and_param_jacobian(dh, qe)
    p = T[:, :3, 3]
    Rp = p @ state.R.T
    n = rows.size
    cols = [np.cross(np.eye(3)[None, :, :], Rp[:, None, :]).transpose(0, 2, 1),
            np.broadcast_to(np.eye(3), (n, 3, 3))]
    for term in state.terms:
        cols.append(np.einsum("ij,njk->nik", state.R, term_columns(term, Jp, dh0, rows)))
    A = np.concatenate(cols, axis=2)
    extra = [(term, np.einsum("ij,njk->nik", state.R, term_columns(term, Jp, dh0, rows))) for term in extra_terms]
    return Rp + state.t, A, extra


def _apply_step(state: ModelState, step: np.ndarray) -> ModelState:
    s = state.copy()
    s.R = Rotation.from_rotvec(step[:3]).as_matrix() @ s.R
    s.t = s.t + step[3:6]
    off = 6
    for i, term in enumerate(s.terms):
        s.theta[i] = s.theta[i] + step[off:off + term.k]
        off += term.k
    return s


def initial_state(dh_nominal, q: np.ndarray, meas: np.ndarray, rows: np.ndarray) -> ModelState:
    """The station's simulation: nominal table, base transform by a rigid fit on ``rows``."""
    T = rigid_fit(kin.tool_position(dh_nominal, q[rows]), meas[rows])
    state = ModelState(np.asarray(dh_nominal, dtype=float), T[:3, :3].copy(), T[:3, 3].copy(),
                       base0=(T[:3, :3].copy(), T[:3, 3].copy()))
    return state


def fit(state: ModelState, q: np.ndarray, meas: np.ndarray, rows: np.ndarray, *, max_iter: int = 200,
        rtol: float = 1e-10) -> tuple[ModelState, float]:
    """Damped Levenberg-Marquardt on ``rows`` from ``state`` (the solver of the identification,
    :func:`station.analysis.lm_solver.levenberg_marquardt`); returns the fitted state and its RSS (mm^2)."""
    return fit_report(state, q, meas, rows, max_iter=max_iter, rtol=rtol)[:2]


def fit_report(state: ModelState, q: np.ndarray, meas: np.ndarray, rows: np.ndarray, *, max_iter: int = 200,
               rtol: float = 1e-10, hold_geometry: bool = False):
    """As :func:`fit`, with the solver's outcome third (``converged``, ``message``, ``iterations``).

    ``hold_geometry``: the geometric term (and the base) stay where they are; only the other terms move."""
    from station.analysis.arm.lm_solver import levenberg_marquardt

    held = np.zeros(0, np.int64)
    if hold_geometry:
        off, idx = 6, [np.arange(6)]
        for t in state.terms:
            if t.kind == "geometric":
                idx.append(off + np.arange(t.k))
            off += t.k
        held = np.concatenate(idx)

    def evaluate(st):
        pred, A, _ = jacobian(st, q, rows)
        M = A.reshape(-1, A.shape[2])
        if held.size:
            M = M.copy()
            M[:, held] = 0.0
        return (meas[rows] - pred).reshape(-1), M

    sol = levenberg_marquardt(evaluate, _apply_step, state, max_iter=max_iter, rtol=rtol)
    if hold_geometry:
        return sol.state, sol.cost, sol
    geo = [i for i, t in enumerate(sol.state.terms) if t.kind == "geometric"]
    m = rows.size * 3
    if geo and m > sol.state.n_params:
        # the identification's weak prior on the geometric deviations (station.analysis.arm.identification):
        # what the poses barely see stays near the nominal table instead of following the noise
        from station.analysis.arm.identification import BASE_NAMES, prior_sd

        gi = geo[0]
        off = 6 + sum(t.k for t in sol.state.terms[:gi])
        term = sol.state.terms[gi]
        base = sol.state.base0 is not None
        cols = np.concatenate([np.arange(6) if base else np.zeros(0, np.int64), off + np.arange(term.k)])
        sds = ([prior_sd(nm) for nm in BASE_NAMES] if base else []) + [prior_sd(kin.PARAM_NAMES[i])
                                                                      for i in term.index]
        if base:
            # as the identification: the nominal rigid fit's misfit over the points' spread bounds the base
            R0, t0 = sol.state.base0
            p_nom = kin.tool_position(sol.state.dh_nominal, q[rows]) @ R0.T + t0
            miss = float(np.sqrt(np.mean(np.sum((meas[rows] - p_nom) ** 2, axis=1))))
            spread = float(np.sqrt(np.mean(np.sum((meas[rows] - meas[rows].mean(axis=0)) ** 2, axis=1))))
            for k in range(6):
                sds[k] = max(sds[k], 3.0 * (miss / max(spread, 1e-9) if k < 3 else miss))
        w = np.sqrt(sol.cost / (m - sol.state.n_params)) / np.array(sds)

        def deviation(st):
            dev = [st.theta[gi]]
            if base:
                R0, t0 = st.base0
                dev = [Rotation.from_matrix(st.R @ R0.T).as_rotvec(), st.t - t0] + dev
            return np.concatenate(dev)

        def evaluate_prior(st):
            r_, J_ = evaluate(st)
            Jp = np.zeros((cols.size, J_.shape[1]))
            Jp[np.arange(cols.size), cols] = w
            return np.concatenate([r_, -w * deviation(st)]), np.concatenate([J_, Jp])

        solp = levenberg_marquardt(evaluate_prior, _apply_step, sol.state, max_iter=max_iter, rtol=rtol)
        r_d, J_d = evaluate(solp.state)
        sol = type(sol)(solp.state, r_d, J_d, float(r_d @ r_d), sol.iterations + solp.iterations,
                        sol.converged and solp.converged, solp.message if not solp.converged else sol.message,
                        sol.rms_history, [])
    return sol.state, sol.cost, sol


def robust_cov(A: np.ndarray, resid: np.ndarray) -> np.ndarray:
    """Cluster-robust (by pose) covariance of the least-squares parameters.

    Parameters
    ----------
    A : ndarray, shape (n, 3, p)
    resid : ndarray, shape (n, 3)
    """
    n, _, p = A.shape
    M = A.reshape(-1, p)
    scale = np.linalg.norm(M, axis=0)
    scale[scale == 0] = 1.0
    Ms = M / scale
    bread = np.linalg.pinv(Ms.T @ Ms)
    g = np.einsum("nip,ni->np", A / scale, resid)  # per-pose score
    meat = g.T @ g
    dof = max(n - p / 3.0, 1.0)
    cov = bread @ meat @ bread * (n / dof)
    return cov / np.outer(scale, scale)


def classical_floor(V: np.ndarray, X: np.ndarray, resid: np.ndarray, dof: float) -> np.ndarray:
    """``V`` raised, in every direction where it is smaller, to the classical covariance ``s^2 (X'X)^-1``
    (``s^2 = resid'resid / dof``, every coordinate equally noisy and independent).

    With few poses and many parameters the pose-robust sandwich of :func:`robust_cov` is too small where a few
    poses of high leverage carry the direction (their residuals are pulled towards the fit); the classical
    covariance pools the residual of every coordinate and is not. Where the poses' own scatter says more (the
    coordinates of a pose share its error), the robust one stays. Whitened by the classical covariance, the
    robust one's eigenvalues below 1 are set to 1.

    Parameters
    ----------
    V : ndarray, shape (k, k)
    X : ndarray, shape (rows, k)
    resid : ndarray, shape (rows,)
    """
    s2 = float(resid @ resid) / max(dof, 1.0)
    C = np.linalg.pinv(X.T @ X) * s2
    w, U = np.linalg.eigh(C)
    w = np.maximum(w, 1e-300)
    half = U * np.sqrt(w)                       # C = half half'
    inv_half = (U / np.sqrt(w)).T               # half^-1
    Vw = inv_half @ V @ inv_half.T
    ev, E = np.linalg.eigh((Vw + Vw.T) / 2.0)
    return half @ (E * np.maximum(ev, 1.0)) @ E.T @ half.T
