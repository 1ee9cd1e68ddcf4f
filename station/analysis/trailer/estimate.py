"""Link lengths of the two-link trailer, beyond the seed's least squares.

Two estimators that use the exact model instead of a straight-line
prediction (compare :mod:`station.analysis.trailer.least_squares`):

:func:`estimate_odr`
    Orthogonal distance regression (errors in both variables) on the steady
    state, eq. (23), written as ``kappa = sin(psi) / (L2 + L1 cos(psi))``:
    minimise ``sum((kappa_i - f(psihat_i))^2 / s_k^2 + (psi_i - psihat_i)^2 / s_p^2)``
    over ``L1, L2`` (optionally a joint-angle offset) and the true joint angles
    ``psihat_i``. Consistent for any ``L1/L2`` (the combined methods M1-M24
    are not; they split ``L1 + L2`` by a line). The noise sigmas default to
    robust estimates from the data (:func:`~station.analysis.trailer_ls.noise_sigma`).
    Steady state only: with a moving trailer the joint angle lags eq. (23)
    and this estimator inherits that bias.

:func:`estimate_dynamic`
    Output-error fit of the joint-angle dynamics (D) of
    :mod:`station.models.trailer`,
    ``dpsi/dt = (v/L2) [kappa (L2 + L1 cos psi) - sin psi]``, driven by the
    measured curvature and speed, over ``L1, L2, psi(t_0)`` (optionally a
    joint-angle offset), by Levenberg-Marquardt with the exact Jacobian from
    the forward sensitivity equations. The lag of the joint angle (time
    constant ``L2/v``) carries ``L2`` to first order, whereas in the steady
    state ``L1`` and ``L2`` are separated only by the curvature of eq. (23)
    over the data range. Started from an integral-equation linear least
    squares (eq. (D) integrated in time is linear in ``L1/L2`` and ``1/L2``).

    The measured curvature is an input with errors: its noise, filtered by
    the dynamics, adds ``s_k^2 trace(G G^T)`` to the expected residual power
    (``G = d psi_sim / d kappa``), and that term depends on the lengths (a
    longer ``L2`` filters more), which biases a plain output-error fit
    (L2 long, L1 short, ~2-5 cm at the seed's noise). The objective is
    therefore bias-compensated: ``sum(r^2) - s_k^2 trace(G G^T)``, whose
    expectation is minimal at the true lengths. The covariance is a sandwich
    that includes the same filtered curvature noise (the residuals are
    correlated over ``L2/v``).

    Curvature samples are, by default, averages over the interval ending at
    their time stamp (what odometry measures: heading change over distance);
    read as point values they would be half a sample late, a bias of
    ``v dt / 2`` on L2. A step of curvature inside an interval is still
    ambiguous, so drive with rate-limited curvature (the procedure ramps).

    With the commanded curvature at hand (the procedure knows its set points
    and the device time each was applied), :func:`fit_dynamic_instrumented`
    uses it as an instrument: the input is ``g kappa_cmd + o`` with the
    drive's gain and offset fitted jointly, the measured curvature is one more
    observation, and the curvature noise no longer passes through the
    dynamics — a several-fold smaller spread. It assumes the drive follows
    its set points without a lag of its own (a lag ``tau`` would bias L2 by
    ``v tau``); :func:`align_command` checks that the command explains the
    measured curvature before it is used.

Both return :class:`~station.analysis.trailer_ls.TrailerEstimate` with
standard uncertainties (ODR: covariance scaled by the residual variance;
dynamic: the sandwich above). The two fitting engines are vectorised over
leading axes (many runs at once) for benchmarks: :func:`fit_odr`,
:func:`fit_dynamic`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.analysis.trailer.least_squares import (
    METHODS, TrailerEstimate, check_curvature_bound, combined_fit, estimate_combined, noise_sigma,
    physical_warnings, validate_samples,
)
from station.errors import ConfigError, DataError, InsufficientDataError
from station.models.trailer import ESTIMATORS, INPUT_SAMPLINGS, DegenerateCommandError, integrate_psi
from station.numeric import finite_number


@dataclass(frozen=True)
class FitResult:
    """Raw result of a vectorised fit.

    Attributes
    ----------
    theta : ndarray, shape (..., n)
        ``[L1, L2, ...]`` (ODR: ``[L1, L2, (psi_offset)]``; dynamic:
        ``[L1, L2, psi0, (psi_offset)]``).
    cov : ndarray, shape (..., n, n)
        Covariance scaled by the residual variance.
    ssr : ndarray, shape (...)
        Weighted residual sum of squares.
    dof : int
    condition_number : ndarray, shape (...)
        ``sqrt`` of the condition number of the (reduced) normal matrix of
        ``(L1, L2)`` — the eq. (17) of the linearised problem.
    iterations : int
    converged : ndarray of bool, shape (...)
    residual : ndarray, shape (..., p)
        Joint-angle residuals (measured minus model), rad.
    """

    theta: np.ndarray
    cov: np.ndarray
    ssr: np.ndarray
    dof: int
    condition_number: np.ndarray
    iterations: int
    converged: np.ndarray
    residual: np.ndarray


def _cond_L(N: np.ndarray) -> np.ndarray:
    """sqrt(cond) of the (L1, L2) block of the inverse covariance (Schur complement)."""
    try:
        C = np.linalg.inv(N)[..., :2, :2]
        w = np.linalg.eigvalsh(np.linalg.inv(C))
    except np.linalg.LinAlgError:
        return np.full(N.shape[:-2], np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(w[..., -1] / w[..., 0])


def _solve_damped(N, g, lam):
    n = N.shape[-1]
    diag = np.diagonal(N, axis1=-2, axis2=-1)
    A = N + (lam[..., None] * np.maximum(diag, 1e-300))[..., None] * np.eye(n)
    return np.linalg.solve(A, g[..., None])[..., 0]


# ----------------------------------------------------------------------------- ODR on eq. (23)
def _levenberg_marquardt(objective, theta, batch, *, max_iter, tol, xtol, adjust=None):
    """Batched Levenberg-Marquardt over the leading axes ``batch`` of ``theta``.

    ``objective(theta) -> (r, J, ps, extra)``: residuals (..., m), their
    Jacobian (..., m, n), the simulated joint angle, and a term added to the
    cost ``sum(r^2) + extra`` (0 for plain least squares). ``adjust(theta,
    ps, N, g) -> (N, g)`` may change the normal matrix and gradient of the
    step (the bias compensation of :func:`fit_dynamic`). Each problem stops on
    its own (small step, small relative decrease, or damping beyond 1e12).

    Returns ``theta, r, J, iterations, converged`` at the last accepted step.
    """
    r, J, ps, extra = objective(theta)
    current = np.sum(r * r, axis=-1) + extra
    lam = np.full(batch, 1e-3)
    converged = np.zeros(batch, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        N = np.einsum("...pi,...pj->...ij", J, J)
        g = np.einsum("...pi,...p->...i", J, r)
        if adjust is not None:
            N, g = adjust(theta, ps, N, g)
        step = -_solve_damped(N, g, lam)
        th_new = theta + np.where(converged[..., None], 0.0, step)
        with np.errstate(invalid="ignore", over="ignore"):
            r_new, J_new, ps_new, extra_new = objective(th_new)
            new = np.sum(r_new * r_new, axis=-1) + extra_new
        better = np.isfinite(new) & (new <= current) & ~converged
        rel = np.abs(current - new) / np.maximum(np.abs(current), 1e-300)
        theta = np.where(better[..., None], th_new, theta)
        r = np.where(better[..., None], r_new, r)
        ps = np.where(better[..., None], ps_new, ps)
        J = np.where(better[..., None, None], J_new, J)
        small = np.max(np.abs(step) / (1.0 + np.abs(theta)), axis=-1) < xtol
        converged |= small | (better & (rel < tol))
        current = np.where(better, new, current)
        lam = np.where(better, lam * 0.3, lam * 10.0)
        converged |= lam > 1e12
        if np.all(converged):
            break
    return theta, r, J, it, converged


def _odr_terms(k, p, theta, psihat, sk, sp, with_offset):
    L1 = theta[..., 0:1]
    L2 = theta[..., 1:2]
    s, c = np.sin(psihat), np.cos(psihat)
    D = L2 + L1 * c
    f = s / D
    off = theta[..., 2:3] if with_offset else 0.0
    rk = (k - f) / sk
    rp = (p - off - psihat) / sp
    # Jacobians: d rk / d(L1, L2), d rk / d psihat, d rp / d(offset), d rp / d psihat
    D2 = D * D
    Gk = np.stack([s * c / D2, s / D2], axis=-1) / sk[..., None]
    hk = -((L2 * c + L1) / D2) / sk
    hp = np.broadcast_to(-1.0 / sp, hk.shape)
    return rk, rp, Gk, hk, hp, D


def _odr_normal(rk, rp, Gk, hk, hp, with_offset):
    n = 3 if with_offset else 2
    shape = rk.shape
    G = np.zeros(shape + (2, n))  # per point: rows (rk, rp), columns theta
    G[..., 0, :2] = Gk
    if with_offset:
        G[..., 1, 2] = hp  # d rp / d offset = -1/sp
    h = np.stack([hk, hp], axis=-1)  # (..., p, 2)
    r = np.stack([rk, rp], axis=-1)
    hh = np.einsum("...i,...i->...", h, h)
    Gh = np.einsum("...ij,...i->...j", G, h)
    hr = np.einsum("...i,...i->...", h, r)
    N = np.einsum("...pij,...pik->...jk", G, G) - np.einsum("...pj,...pk,...p->...jk", Gh, Gh, 1.0 / hh)
    g = np.einsum("...pij,...pi->...j", G, r) - np.einsum("...pj,...p->...j", Gh, hr / hh)
    return N, g, Gh, hr, hh


def fit_odr(kappa, psi, theta0, sigma_kappa, sigma_psi, *, fit_psi_offset: bool = False,
            max_iter: int = 100, tol: float = 1e-10, xtol: float = 1e-8) -> FitResult:
    """Vectorised ODR of eq. (23) (see the module docstring).

    Parameters
    ----------
    kappa, psi : ndarray, shape (..., p)
    theta0 : ndarray, shape (..., 2)
        Starting ``[L1, L2]``.
    sigma_kappa, sigma_psi : float or ndarray, shape (...)
        Noise sigmas (their ratio weights the two errors).
    """
    k = np.asarray(kappa, dtype=float)
    p = np.asarray(psi, dtype=float)
    batch = k.shape[:-1]
    n = 3 if fit_psi_offset else 2
    theta = np.zeros(batch + (n,))
    theta[..., :2] = np.broadcast_to(np.asarray(theta0, dtype=float)[..., :2], batch + (2,))
    sk = np.broadcast_to(np.asarray(sigma_kappa, dtype=float), batch)[..., None]
    sp = np.broadcast_to(np.asarray(sigma_psi, dtype=float), batch)[..., None]
    psihat = p.copy()

    def cost(th, ph):
        rk, rp, *_ = _odr_terms(k, p, th, ph, sk, sp, fit_psi_offset)
        return np.sum(rk * rk, axis=-1) + np.sum(rp * rp, axis=-1)

    lam = np.full(batch, 1e-3)
    converged = np.zeros(batch, dtype=bool)
    current = cost(theta, psihat)
    it = 0
    for it in range(1, max_iter + 1):  # iterations of Levenberg-Marquardt
        rk, rp, Gk, hk, hp, _ = _odr_terms(k, p, theta, psihat, sk, sp, fit_psi_offset)
        N, g, Gh, hr, hh = _odr_normal(rk, rp, Gk, hk, hp, fit_psi_offset)
        dtheta = -_solve_damped(N, g, lam)
        dpsi = -(hr + np.einsum("...pj,...j->...p", Gh, dtheta)) / hh
        th_new = theta + dtheta
        ph_new = psihat + dpsi
        with np.errstate(invalid="ignore", over="ignore"):
            new = cost(th_new, ph_new)
        better = np.isfinite(new) & (new <= current) & ~converged
        rel = np.abs(current - new) / np.maximum(current, 1e-300)
        theta = np.where(better[..., None], th_new, theta)
        psihat = np.where(better[..., None], ph_new, psihat)
        small = np.max(np.abs(dtheta) / (1.0 + np.abs(theta)), axis=-1) < xtol
        converged |= small | (better & (rel < tol))
        current = np.where(better, new, current)
        lam = np.where(better, lam * 0.3, lam * 10.0)
        converged |= lam > 1e12  # no further decrease possible: at the minimum
        if np.all(converged):
            break
    rk, rp, Gk, hk, hp, _ = _odr_terms(k, p, theta, psihat, sk, sp, fit_psi_offset)
    N, *_ = _odr_normal(rk, rp, Gk, hk, hp, fit_psi_offset)
    dof = k.shape[-1] - n
    ssr = np.sum(rk * rk, axis=-1) + np.sum(rp * rp, axis=-1)
    cov = np.linalg.inv(N) * (ssr / dof)[..., None, None]
    off = theta[..., 2:3] if fit_psi_offset else 0.0
    return FitResult(theta, cov, ssr, dof, _cond_L(N), it, converged, p - off - psihat)


def estimate_odr(kappa, psi, *, sigma_kappa: float | None = None, sigma_psi: float | None = None,
                 L0_m: tuple[float, float] | None = None, fit_psi_offset: bool = False) -> TrailerEstimate:
    """Link lengths by orthogonal distance regression on eq. (23), one validated run.

    Parameters
    ----------
    kappa, psi : array_like, shape (p,)
        Measured curvature (1/m) and joint angle (rad), in time order.
    sigma_kappa, sigma_psi : float, optional
        Sensor noise sigmas; estimated from the data when omitted.
    L0_m : (float, float), optional
        Starting lengths; default: the seed's M17.
    fit_psi_offset : bool
        Also estimate a constant joint-angle sensor offset.
    """
    k, p, info = validate_samples(kappa, psi)
    sk = info["kappa_noise"] if sigma_kappa is None else finite_number(sigma_kappa, "sigma_kappa", positive=True)
    sp = info["psi_noise"] if sigma_psi is None else finite_number(sigma_psi, "sigma_psi", positive=True)
    floor = 1e-3 * max(sk, sp, 1e-9)
    sk, sp = max(sk, floor), max(sp, floor)
    theta0 = _start_lengths(k, p, L0_m)
    fit = fit_odr(k, p, theta0, sk, sp, fit_psi_offset=fit_psi_offset)
    return _to_estimate("odr", fit, k, info, {
        "sigma_kappa_used": sk, "sigma_psi_used": sp,
        "psi_offset_rad": float(fit.theta[2]) if fit_psi_offset else None,
        "psi_offset_sigma_rad": float(math.sqrt(fit.cov[2, 2])) if fit_psi_offset else None,
    }, ["steady-state model: a joint angle lagging eq. (23) (trailer moving while the curvature "
        "changes) biases it; prefer method 'dynamic' when the speed is known"])


# ----------------------------------------------------------------------------- dynamics
def _integral_start(t, k, p, v, sampling):
    """Linear LS on eq. (D) integrated in time: returns [L1, L2, psi0] (..., 3)."""
    dt = np.diff(t)

    def cumint(inp, state):  # integral of inp(t) * state(t); state is point-sampled
        s_mid = 0.5 * (state[..., 1:] + state[..., :-1])
        if sampling == "interval":
            inc = inp[..., 1:] * s_mid * dt
        else:
            inc = 0.5 * (inp[..., 1:] * state[..., 1:] + inp[..., :-1] * state[..., :-1]) * dt
        out = np.zeros(np.broadcast_shapes(inp.shape, state.shape))
        out[..., 1:] = np.cumsum(inc, axis=-1)
        return out

    one = np.ones_like(p)
    vk = v * k
    y = p - cumint(vk, one)
    A = np.stack([one, cumint(vk, np.cos(p)), -cumint(v * one, np.sin(p))], axis=-1)
    AtA = np.einsum("...pi,...pj->...ij", A, A)
    Aty = np.einsum("...pi,...p->...i", A, y)
    beta = np.linalg.solve(AtA, Aty[..., None])[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        L2 = 1.0 / beta[..., 2]
        L1 = beta[..., 1] * L2
    return np.stack([L1, L2, beta[..., 0]], axis=-1)


def fit_dynamic(t_s, kappa, psi, v_m_s, theta0=None, *, fit_psi_offset: bool = False,
                sigma_kappa=None, sigma_psi=None, bias_compensation: bool = True,
                sampling: str = "interval", max_iter: int = 60, tol: float = 1e-10,
                xtol: float = 1e-7, substeps: int = 1) -> FitResult:
    """Vectorised output-error fit of the joint-angle dynamics (D).

    Parameters
    ----------
    t_s : ndarray, shape (p,)
        Strictly increasing sample times, s.
    kappa, psi : ndarray, shape (..., p)
        Measured curvature (1/m) and joint angle (rad).
    v_m_s : float or ndarray, shape (..., p)
        Measured speed, m/s.
    theta0 : ndarray, shape (..., 3), optional
        Starting ``[L1, L2, psi0]``; default: the integral-equation start.
    sigma_kappa, sigma_psi : float or ndarray, shape (...), optional
        Sensor noise sigmas for the covariance; estimated from the data
        (second differences) when omitted.
    bias_compensation : bool
        Subtract the curvature-noise term (see the module docstring).
    sampling : {"interval", "point"}
        Curvature/speed samples are averages over the preceding interval
        (odometry) or point values (:func:`~station.models.trailer.integrate_psi`).

    Notes
    -----
    The covariance is the sandwich ``N^-1 (s_p^2 N + s_k^2 H H^T) N^-1``
    (``N = J^T J``, ``H = J^T G``): the measured curvature drives the model,
    so its noise reaches the residuals filtered by the dynamics — correlated
    over ``L2/v`` — and a white-residual covariance would understate the
    uncertainty about threefold at the seed's noise level.
    """
    t = np.asarray(t_s, dtype=float)
    k = np.asarray(kappa, dtype=float)
    p = np.asarray(psi, dtype=float)
    v = np.broadcast_to(np.asarray(v_m_s, dtype=float), np.broadcast_shapes(np.shape(v_m_s), p.shape))
    batch = p.shape[:-1]
    n = 4 if fit_psi_offset else 3
    start = _integral_start(t, k, p, v, sampling) if theta0 is None else np.asarray(theta0, dtype=float)
    theta = np.zeros(batch + (n,))
    theta[..., :3] = np.broadcast_to(start[..., :3], batch + (3,))
    bad = ~np.all(np.isfinite(theta[..., :2]), axis=-1) | (theta[..., 1] <= 0) | (theta[..., 0] < 0) \
        | (theta[..., 1] <= theta[..., 0])
    if np.any(bad):  # fall back on the seed's M17 start where the integral start is unphysical
        m17 = combined_fit(k, p, "M17")
        theta[..., 0] = np.where(bad, m17.L1_m, theta[..., 0])
        theta[..., 1] = np.where(bad, m17.L2_m, theta[..., 1])
        theta[..., 2] = np.where(bad, p[..., 0], theta[..., 2])

    sk = noise_sigma(k) if sigma_kappa is None else np.broadcast_to(np.asarray(sigma_kappa, float), batch)
    sp = noise_sigma(p) if sigma_psi is None else np.broadcast_to(np.asarray(sigma_psi, float), batch)
    sk2 = (sk ** 2) if bias_compensation else np.zeros(batch)

    def model(th):
        L1 = th[..., 0]
        L2 = np.maximum(th[..., 1], 1e-6)
        ps, sens = integrate_psi(t, k, v, th[..., 2], L1, L2, sensitivities=True, substeps=substeps,
                                 sampling=sampling)
        off = th[..., 3:4] if fit_psi_offset else 0.0
        r = p - ps - off
        J = -sens
        if fit_psi_offset:
            J = np.concatenate([J, -np.ones(J.shape[:-1] + (1,))], axis=-1)
        trace = _noise_trace(t, k, ps, v, L1, L2, sampling)
        return r, J, ps, trace

    def trace_derivatives(th, ps):
        """Gradient and Hessian of the noise trace in (L1, L2), central differences."""
        h = 1e-4 * np.maximum(1.0, np.abs(th[..., :2]))
        vals = {}
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                L1 = th[..., 0] + i * h[..., 0]
                L2 = np.maximum(th[..., 1] + j * h[..., 1], 1e-6)
                vals[i, j] = _noise_trace(t, k, ps, v, L1, L2, sampling)
        g = np.zeros(th.shape)
        H = np.zeros(th.shape + (th.shape[-1],))
        g[..., 0] = (vals[1, 0] - vals[-1, 0]) / (2 * h[..., 0])
        g[..., 1] = (vals[0, 1] - vals[0, -1]) / (2 * h[..., 1])
        H[..., 0, 0] = (vals[1, 0] - 2 * vals[0, 0] + vals[-1, 0]) / h[..., 0] ** 2
        H[..., 1, 1] = (vals[0, 1] - 2 * vals[0, 0] + vals[0, -1]) / h[..., 1] ** 2
        H[..., 0, 1] = H[..., 1, 0] = (vals[1, 1] - vals[1, -1] - vals[-1, 1] + vals[-1, -1]) \
            / (4 * h[..., 0] * h[..., 1])
        return g, H

    def objective(th):  # residuals, Jacobian, simulated psi, and the noise-trace term of the cost
        r, J, ps, trace = model(th)
        return r, J, ps, -sk2 * trace

    def compensate(theta, ps, N, g):  # the trace term's gradient and curvature (bias compensation)
        if not bias_compensation:
            return N, g
        gT, HT = trace_derivatives(theta, ps)
        N_eff = N - 0.5 * sk2[..., None, None] * HT
        pos = np.all(np.linalg.eigvalsh(N_eff) > 0, axis=-1)
        return np.where(pos[..., None, None], N_eff, N), g - 0.5 * sk2[..., None] * gT

    theta, r, J, it, converged = _levenberg_marquardt(objective, theta, batch, max_iter=max_iter, tol=tol,
                                                      xtol=xtol, adjust=compensate)
    N = np.einsum("...pi,...pj->...ij", J, J)
    dof = p.shape[-1] - n
    ssr = np.sum(r * r, axis=-1)
    L1 = theta[..., 0]
    L2 = np.maximum(theta[..., 1], 1e-6)
    H = _input_noise_gain(t, k, p - r - (theta[..., 3:4] if fit_psi_offset else 0.0), v, L1, L2, J, sampling)
    Ninv = np.linalg.inv(N)
    meat = (sp ** 2)[..., None, None] * N + (sk ** 2)[..., None, None] * np.einsum("...ip,...jp->...ij", H, H)
    cov = Ninv @ meat @ Ninv
    return FitResult(theta, cov, ssr, dof, _cond_L(N), it, converged, r)


def fit_dynamic_instrumented(t_s, kappa, psi, v_m_s, kappa_cmd, theta0=None, *,
                             fit_psi_offset: bool = False, sigma_kappa=None, sigma_psi=None,
                             sampling: str = "interval", max_iter: int = 60, tol: float = 1e-10,
                             xtol: float = 1e-7) -> FitResult:
    """Joint fit of the dynamics (D) and of the curvature, with the commanded
    curvature as an instrument (vectorised over leading axes).

    The input is ``kappa_in = g kappa_cmd + o`` (the drive's gain and offset,
    fitted); the measured curvature is one more observation of it. Minimises
    ``sum(((psi - psi_sim(kappa_in)) / s_p)^2) + sum(((kappa - kappa_in) / s_k)^2)``
    over ``[L1, L2, psi0, g, o, (psi_offset)]``: a structured errors-in-
    variables problem whose residuals are white, so the covariance is the
    plain one, scaled by the residual variance.

    Parameters
    ----------
    kappa_cmd : ndarray, shape (..., p)
        Commanded curvature aligned with the samples (same sampling meaning
        as ``kappa``).

    Other parameters as :func:`fit_dynamic`; ``theta0`` is ``[L1, L2, psi0]``.
    """
    t = np.asarray(t_s, dtype=float)
    k = np.asarray(kappa, dtype=float)
    p = np.asarray(psi, dtype=float)
    c = np.broadcast_to(np.asarray(kappa_cmd, dtype=float), p.shape)
    if not np.all(np.isfinite(c)):
        raise DataError("kappa_cmd contains NaN or infinite values")
    if np.any(np.ptp(c, axis=-1) <= 0):
        raise DegenerateCommandError("the commanded curvature is constant: it cannot serve as an instrument")
    v = np.broadcast_to(np.asarray(v_m_s, dtype=float), np.broadcast_shapes(np.shape(v_m_s), p.shape))
    batch = p.shape[:-1]
    sk = noise_sigma(k) if sigma_kappa is None else np.broadcast_to(np.asarray(sigma_kappa, float), batch)
    sp = noise_sigma(p) if sigma_psi is None else np.broadcast_to(np.asarray(sigma_psi, float), batch)
    floor = 1e-6 * np.maximum(np.maximum(sk, sp), 1e-6)
    sk, sp = np.maximum(sk, floor), np.maximum(sp, floor)
    # start: the drive's gain and offset by least squares, then the lengths on that input
    cm = c.mean(axis=-1, keepdims=True)
    g0 = np.sum((c - cm) * (k - k.mean(axis=-1, keepdims=True)), axis=-1) / np.sum((c - cm) ** 2, axis=-1)
    o0 = k.mean(axis=-1) - g0 * cm[..., 0]
    k0 = g0[..., None] * c + o0[..., None]
    n_off = 1 if fit_psi_offset else 0
    n = 5 + n_off
    theta = np.zeros(batch + (n,))
    if theta0 is None:
        start = fit_dynamic(t, k0, p, v, sigma_kappa=np.zeros(batch), sigma_psi=sp, bias_compensation=False,
                            sampling=sampling, max_iter=20).theta
    else:
        start = np.asarray(theta0, dtype=float)
    theta[..., :3] = np.broadcast_to(start[..., :3], batch + (3,))
    theta[..., 3], theta[..., 4] = g0, o0

    def model(th):
        L1, L2 = th[..., 0], np.maximum(th[..., 1], 1e-6)
        g, o = th[..., 3:4], th[..., 4:5]
        kin = g * c + o
        ps, sens = integrate_psi(t, kin, v, th[..., 2], L1, L2, sensitivities=True, sampling=sampling)
        # input sensitivities: (D) is linear in kappa, forward differences are exact to O(h)
        hg = 1e-7 * np.maximum(1.0, np.abs(g))
        dg = (integrate_psi(t, (g + hg) * c + o, v, th[..., 2], L1, L2, sampling=sampling) - ps) / hg
        ho = 1e-7
        do = (integrate_psi(t, kin + ho, v, th[..., 2], L1, L2, sampling=sampling) - ps) / ho
        off = th[..., 5:6] if fit_psi_offset else 0.0
        rp = (p - ps - off) / sp[..., None]
        rk = (k - kin) / sk[..., None]
        Jp = np.concatenate([-sens, -dg[..., None], -do[..., None]], axis=-1)
        if fit_psi_offset:
            Jp = np.concatenate([Jp, -np.ones(Jp.shape[:-1] + (1,))], axis=-1)
        Jp = Jp / sp[..., None, None]
        Jk = np.zeros(Jp.shape)
        Jk[..., 3] = -c / sk[..., None]
        Jk[..., 4] = -1.0 / sk[..., None]
        return np.concatenate([rp, rk], axis=-1), np.concatenate([Jp, Jk], axis=-2), ps

    theta, r, J, it, converged = _levenberg_marquardt(lambda th: (*model(th), 0.0), theta, batch,
                                                      max_iter=max_iter, tol=tol, xtol=xtol)
    N = np.einsum("...pi,...pj->...ij", J, J)
    m = p.shape[-1]
    dof = 2 * m - n
    ssr = np.sum(r * r, axis=-1)
    cov = np.linalg.inv(N) * (ssr / dof)[..., None, None]
    return FitResult(theta, cov, ssr, dof, _cond_L(N), it, converged, r[..., :m] * sp[..., None])


def align_command(kappa, kappa_cmd, *, max_lag: int = 0) -> dict:
    """Check the commanded curvature as an instrument for the measured one.

    Fits ``kappa = g cmd + o`` by least squares; with ``max_lag > 0`` also
    tries integer lags ``-max_lag..max_lag`` (samples; ``cmd[i - lag]`` goes
    with ``kappa[i]``) and keeps the least residual — a diagnostic only: with
    slowly varying commands the lag is poorly determined and a wrong one
    biases L2 by ``v`` times the lag, so the estimators use the set points'
    acknowledged device times (lag 0). The command is *consistent* if the
    residual is no larger than the curvature noise (robust second-difference
    estimate), i.e. the drive follows its set points up to gain and offset.

    Returns
    -------
    dict
        ``cmd`` (aligned, shape of ``kappa``), ``lag``, ``gain``, ``offset``,
        ``excess`` (residual variance / noise variance - 1), ``consistent``.
    """
    k = np.asarray(kappa, dtype=float)
    c = np.asarray(kappa_cmd, dtype=float)
    if c.shape != k.shape:
        raise DataError(f"kappa_cmd has shape {c.shape}, kappa {k.shape}")
    if not np.all(np.isfinite(c)):
        raise DataError("kappa_cmd contains NaN or infinite values")
    best = None
    for lag in range(-max_lag, max_lag + 1):
        idx = np.clip(np.arange(k.size) - lag, 0, k.size - 1)
        cs = c[idx]
        A = np.stack([cs, np.ones_like(cs)], axis=-1)
        coef, *_ = np.linalg.lstsq(A, k, rcond=None)
        resid = k - A @ coef
        ssr = float(resid @ resid)
        if best is None or ssr < best[0]:
            best = (ssr, lag, cs, coef, resid)
    ssr, lag, cs, coef, resid = best
    sk = float(noise_sigma(k))
    excess = float(np.var(resid) / max(sk * sk, 1e-300) - 1.0)
    consistent = bool(np.ptp(cs) > 0 and excess <= 8.0 * math.sqrt(2.0 / k.size))
    return {"cmd": cs, "lag": int(lag), "gain": float(coef[0]), "offset": float(coef[1]),
            "excess": excess, "consistent": consistent}


def _noise_weights(t, sampling):
    """Weights of curvature sample ``j`` on ``psi(t_i)``: ``(w_off[j]`` for j < i,
    ``w_diag[i]`` for j = i) — the integral of sample j's share of the input
    up to ``t_i`` (hat functions for point samples, the interval for averages)."""
    dt = np.diff(t)
    w_off = np.zeros_like(t)
    w_diag = np.zeros_like(t)
    if sampling == "interval":
        w_off[1:] = dt
        w_diag[1:] = dt
    else:
        w_off[1:] += 0.5 * dt
        w_off[:-1] += 0.5 * dt
        w_diag[1:] = 0.5 * dt
    return w_off, w_diag


def _linearised(k, psi_model, v, L1, L2):
    """``a = d(rate)/dpsi`` and ``b = d(rate)/dkappa`` of (D) along a trajectory."""
    a = -(v / L2[..., None]) * (k * L1[..., None] * np.sin(psi_model) + np.cos(psi_model))
    b = v * (L2[..., None] + L1[..., None] * np.cos(psi_model)) / L2[..., None]
    return a, b


def _noise_trace(t, k, psi_model, v, L1, L2, sampling="interval"):
    """``trace(G G^T)``: the residual power that white curvature noise of unit
    variance adds to an output-error fit, as a function of the lengths.

    ``G[i, j] = Phi(t_i, t_j) b_j w_ij`` (see :func:`_input_noise_gain`);
    forward recursion ``Q_i = Phi(t_i, t_{i-1})^2 (Q_{i-1} + (b w_off)_{i-1}^2)``,
    ``trace = sum_i Q_i + (b w_diag)_i^2``, along the trajectory ``psi_model``.
    """
    a, b = _linearised(k, psi_model, v, L1, L2)
    w_off, w_diag = _noise_weights(t, sampling)
    off2 = (b * w_off) ** 2
    total = np.sum((b * w_diag) ** 2, axis=-1)
    phi2 = np.exp((a[..., 1:] + a[..., :-1]) * np.diff(t))  # Phi(t_{i+1}, t_i)^2
    Q = np.zeros(off2.shape[:-1])
    for i in range(1, t.size):  # forward in time, vectorised over runs
        Q = phi2[..., i - 1] * (Q + off2[..., i - 1])
        total = total + Q
    return total


def _input_noise_gain(t, k, psi_model, v, L1, L2, J, sampling="interval"):
    """``J^T G`` (..., n, p): how white curvature noise reaches the parameters.

    ``G[i, j] = d psi_sim(t_i) / d kappa_j`` of the dynamics (D) linearised
    along the fitted trajectory: ``d(dpsi)/dt = a(t) dpsi + b(t) dkappa`` with
    ``a = -(v/L2)(kappa L1 sin psi + cos psi)``, ``b = v (L2 + L1 cos psi)/L2``,
    ``G[i, j] = Phi(t_i, t_j) b_j w_ij`` (:func:`_noise_weights`). Computed by
    the backward recursion ``S_j = J_j + Phi(t_{j+1}, t_j) S_{j+1}`` —
    sequential in time like the integration, vectorised over runs.
    """
    a, b = _linearised(k, psi_model, v, L1, L2)
    w_off, w_diag = _noise_weights(t, sampling)
    phi = np.exp(0.5 * (a[..., 1:] + a[..., :-1]) * np.diff(t))  # Phi(t_{j+1}, t_j)
    S = np.empty_like(J)
    S[..., -1, :] = J[..., -1, :]
    for j in range(t.size - 2, -1, -1):  # backward in time (adjoint of the integration)
        S[..., j, :] = J[..., j, :] + phi[..., j, None] * S[..., j + 1, :]
    H = b[..., None] * (w_off[:, None] * (S - J) + w_diag[:, None] * J)
    return H.swapaxes(-1, -2)


def estimate_dynamic(t_s, kappa, psi, v_m_s, *, L0_m: tuple[float, float] | None = None,
                     fit_psi_offset: bool = False, sampling: str = "interval",
                     kappa_cmd=None) -> TrailerEstimate:
    """Link lengths from the joint-angle dynamics (D), one validated run.

    Parameters
    ----------
    t_s : array_like, shape (p,)
        Device time stamps, s, strictly increasing.
    kappa, psi : array_like, shape (p,)
        Measured curvature (1/m) and joint angle (rad).
    v_m_s : float or array_like, shape (p,)
        Measured speed, m/s (needed: the dynamics run in distance travelled).
    L0_m : (float, float), optional
        Starting lengths; default: the integral-equation least squares.
    fit_psi_offset : bool
        Also estimate a constant joint-angle sensor offset.
    sampling : {"interval", "point"}
        ``"interval"`` (default): each curvature/speed sample is the average
        over the interval ending at its time stamp, as odometry reports it;
        ``"point"``: instantaneous values.
    kappa_cmd : array_like, shape (p,), optional
        The commanded curvature (the set points in force). If it passes
        :func:`align_command`'s check it serves as an instrument
        (:func:`fit_dynamic_instrumented`): the curvature noise then no longer
        enters the dynamics, which cuts the spread several-fold. Otherwise
        the measured curvature drives the model and a warning says why.
    """
    if sampling not in INPUT_SAMPLINGS:
        raise ConfigError(f"sampling must be one of {INPUT_SAMPLINGS}, got {sampling!r}")
    k, p, info = validate_samples(kappa, psi)
    t = np.asarray(t_s, dtype=float)
    if t.shape != k.shape:
        raise DataError(f"t_s has shape {t.shape}, kappa {k.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        i = int(np.argmax(~(np.diff(t) > 0))) if np.any(~(np.diff(t) > 0)) else 0
        raise DataError(f"t_s must be finite and strictly increasing (problem near index {i + 1})")
    if v_m_s is None:
        raise DataError("method 'dynamic' needs the speed v (the joint angle relaxes over the "
                        "distance travelled); add a v column")
    v = np.broadcast_to(np.asarray(v_m_s, dtype=float), k.shape)
    if not np.all(np.isfinite(v)):
        raise DataError("v contains NaN or infinite values")
    if np.any(v < 0):
        raise DataError(f"{int(np.sum(v < 0))} negative speed(s): the trailer model holds for forward motion")
    distance = float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)))
    if distance <= 0:
        raise DegenerateCommandError("the trailer did not move (distance 0 m): the joint angle has no dynamics")
    theta0 = None
    if L0_m is not None:
        L1, L2 = _lengths_arg(L0_m)
        theta0 = np.array([L1, L2, p[0]])
    warnings = []
    extra = {"input": "measured curvature"}
    fit = None
    if kappa_cmd is not None:
        al = align_command(k, kappa_cmd)
        extra.update({"command_lag_samples": al["lag"], "command_gain": al["gain"],
                      "command_offset_1_m": al["offset"], "command_excess": al["excess"]})
        if al["consistent"]:
            fit = fit_dynamic_instrumented(t, k, p, v, al["cmd"], theta0, fit_psi_offset=fit_psi_offset,
                                           sampling=sampling)
            extra["input"] = "commanded curvature as instrument"
            extra["command_gain"] = float(fit.theta[3])
            extra["command_offset_1_m"] = float(fit.theta[4])
        else:
            warnings.append(f"the commanded curvature does not explain the measured one (residual "
                            f"variance {al['excess'] + 1:.2f} x the noise): not used as an instrument")
    if fit is None:
        fit = fit_dynamic(t, k, p, v, theta0, fit_psi_offset=fit_psi_offset, sampling=sampling)
    off_idx = 5 if fit.theta.shape[-1] in (5, 6) else 3
    r = fit.residual
    rho = float(np.sum(r[1:] * r[:-1]) / np.sum(r * r)) if np.sum(r * r) > 0 else 0.0
    return _to_estimate("dynamic", fit, k, info, {
        "psi0_rad": float(fit.theta[2]), "distance_m": distance, "sampling": sampling,
        "residual_lag1_autocorrelation": rho, **extra,
        "psi_offset_rad": float(fit.theta[off_idx]) if fit_psi_offset else None,
        "psi_offset_sigma_rad": float(math.sqrt(fit.cov[off_idx, off_idx])) if fit_psi_offset else None,
    }, warnings)


# ----------------------------------------------------------------------------- dispatch
# every method name estimate_trailer accepts is named with the trailer's model (a config checks it there)
if tuple(METHODS) + ("odr", "dynamic") != ESTIMATORS:
    raise RuntimeError(f"station.models.trailer.ESTIMATORS {ESTIMATORS} are not Table 3's methods, odr, dynamic")


def estimate_trailer(data: dict, method: str, *, sampling: str = "interval",
                     use_command: bool = True) -> TrailerEstimate:
    """Link lengths of a record (``t``, ``kappa``, ``psi``, optional ``v``,
    ``kappa_cmd``) by ``method``.

    ``sampling`` is the meaning of the curvature samples for ``dynamic``, which
    also uses ``kappa_cmd`` as an instrument when present and ``use_command``
    (see :func:`estimate_dynamic`).

    With a ``phase`` column (a procedure record), the steady-state methods use
    the profile samples (phase 1) and ``dynamic`` the continuous record while
    driving (phases 0 and 1); the stopping samples (phase 2) are not used.
    """
    if method not in ESTIMATORS:
        raise ConfigError(f"method must be one of M1..M24, odr, dynamic; got {method!r}")
    screen_samples(data)
    try:
        est = _estimate(data, method, sampling, use_command)
    except np.linalg.LinAlgError as exc:
        raise DataError(f"{method}: the record does not determine the lengths ({exc})") from None
    if not (abs(est.L1_m) > 1e-6 or abs(est.L2_m) > 1e-6):
        raise DataError(f"{method}: degenerate estimate L1={est.L1_m:.3g} m, L2={est.L2_m:.3g} m; "
                        f"the record does not determine the lengths")
    return est


#: no trailer turns tighter than 5 cm (|kappa| <= 20 1/m); a sample beyond is a corrupted record
KAPPA_ABSURD_1_M = 20.0


def screen_samples(data: dict) -> None:
    """DataError naming the first row (1-based) whose curvature, angle or time no trailer can produce."""
    checks = [("kappa", lambda x: np.abs(x) <= KAPPA_ABSURD_1_M, f"|kappa| <= {KAPPA_ABSURD_1_M:g} 1/m"),
              ("psi", lambda x: np.abs(x) <= math.pi, "|psi| <= pi rad"),
              ("t", lambda x: np.ones(x.shape, bool), "finite"),
              ("v", lambda x: np.abs(x) <= 100.0, "|v| <= 100 m/s"),
              ("kappa_cmd", lambda x: np.abs(x) <= KAPPA_ABSURD_1_M, f"|kappa_cmd| <= {KAPPA_ABSURD_1_M:g} 1/m")]
    for name, ok, what in checks:
        if data.get(name) is None:
            continue
        x = np.asarray(data[name], dtype=float)
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(x) | ~ok(x)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DataError(f"data row {i + 1}: {name} = {float(x[i]):.6g} is not a trailer's ({what}); "
                            f"{int(bad.sum())} such row(s)")


def _estimate(data: dict, method: str, sampling: str, use_command: bool) -> TrailerEstimate:
    phase = data.get("phase")
    if method == "dynamic":
        sel = slice(None) if phase is None else np.asarray(phase) <= 1
        v = data.get("v")
        cmd = data.get("kappa_cmd") if use_command else None
        return estimate_dynamic(np.asarray(data["t"])[sel], np.asarray(data["kappa"])[sel],
                                np.asarray(data["psi"])[sel], None if v is None else np.asarray(v)[sel],
                                sampling=sampling, kappa_cmd=None if cmd is None else np.asarray(cmd)[sel])
    sel = slice(None) if phase is None else np.asarray(phase) == 1
    k, p = np.asarray(data["kappa"])[sel], np.asarray(data["psi"])[sel]
    if method == "odr":
        return estimate_odr(k, p)
    return estimate_combined(k, p, method)


# ----------------------------------------------------------------------------- helpers
def _lengths_arg(L0_m) -> tuple[float, float]:
    try:
        L1, L2 = (float(x) for x in L0_m)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"L0_m must be a pair of numbers (L1, L2), got {L0_m!r}") from exc
    if not (math.isfinite(L1) and math.isfinite(L2) and 0 <= L1 < L2):
        raise ConfigError(f"L0_m must satisfy 0 <= L1 < L2, got {L0_m!r}")
    return L1, L2


def _start_lengths(k, p, L0_m) -> np.ndarray:
    if L0_m is not None:
        return np.array(_lengths_arg(L0_m))
    m17 = combined_fit(k, p, "M17")
    L1, L2 = float(m17.L1_m), float(m17.L2_m)
    if not (math.isfinite(L1) and math.isfinite(L2) and 0 <= L1 < L2):
        a = float(m17.prediction.a)
        L1, L2 = a / 3.0, 2.0 * a / 3.0
    return np.array([L1, L2])


def _to_estimate(method, fit: FitResult, k, info, extra: dict, warnings: list) -> TrailerEstimate:
    L1, L2 = float(fit.theta[0]), float(fit.theta[1])
    if not bool(fit.converged):
        raise DataError(f"the {method} fit did not converge in {fit.iterations} iterations")
    if fit.dof <= 0:
        raise InsufficientDataError(f"the {method} fit has no degrees of freedom left")
    sig = np.sqrt(np.maximum(np.diag(fit.cov)[:2], 0.0))
    corr = float(fit.cov[0, 1] / (sig[0] * sig[1])) if sig[0] > 0 and sig[1] > 0 else 0.0
    w = physical_warnings(L1, L2) + list(warnings)
    check_curvature_bound(k, L1, L2, info["kappa_noise"])
    details = {"kappa_noise": info["kappa_noise"], "psi_noise": info["psi_noise"],
               "iterations": fit.iterations,
               "residual_rms_rad": float(math.sqrt(np.mean(fit.residual ** 2))),
               **{key: val for key, val in extra.items() if val is not None}}
    return TrailerEstimate(method, L1, L2, float(sig[0]), float(sig[1]), corr,
                           float(fit.condition_number), int(k.size), details, tuple(w))


__all__ = ["FitResult", "fit_odr", "estimate_odr", "fit_dynamic", "fit_dynamic_instrumented",
           "align_command", "estimate_dynamic", "estimate_trailer"]
