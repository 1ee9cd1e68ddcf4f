"""The extended trailer model of the diagnosis: prediction of the joint angle, its columns, its fit.

The station's model is the patent's static one (seed 003 eq. (23)): the
joint angle is the steady state of the measured curvature,
``psi = atan(kappa L1) + asin(kappa L2 / sqrt(1 + kappa^2 L1^2))``
(:func:`station.models.trailer.steady_state_psi`). The extension has five
parameters, each the null value of one candidate effect when it is off:

=====  =====================  ======================================  ======
index  name                   meaning                                 null
=====  =====================  ======================================  ======
0, 1   ``L1_m``, ``L2_m``     link lengths (``link_lengths``)          nominal
2      ``offset_rad``         joint-angle sensor zero (``hitch_angle_offset``)  0
3      ``gain``               path curvature = gain x measured         1
                              (``curvature_gain``)
4      ``relaxation_m``       the joint angle relaxes towards the      0
                              steady state over this distance travelled
                              (``hitch_dynamics``)
=====  =====================  ======================================  ======

Hitch dynamics: eq. (D) of :mod:`station.models.trailer` with its rate
scaled, ``dpsi/dt = (v / l) [g kappa (L2 + L1 cos psi) - sin psi]``; ``l = L2``
is the ideal trailer of (D), ``l -> 0`` the static model. Each sample's
curvature is taken at its time stamp, as the static model takes it, and
varies linearly between samples, so the static model is exactly the
``l -> 0`` limit and the lag is linear in ``l`` there (``-(l / (v c))
dpsi_ss/dt``). Integrated with the exponential step of a first-order lag
driven by a ramp, linearised about the equilibrium:
``psi_k = e_k + (psi_{k-1} - e_{k-1}) a_k - (e_k - e_{k-1}) (1 - a_k) / z_k``,
``z_k = v_k dt_k c_k / l``, ``a_k = exp(-z_k)``, ``e_k`` the steady state of
the sample's curvature and ``c_k = sqrt(1 + kappa^2 L1^2) cos(e_k - atan(kappa L1))``
the slope of (D) there, taken as the secant between the state and the
equilibrium (exact for the linearised (D), stable for any ``l``; within
a few 1e-4 rad of an RK4 integration of (D) at the seed's lag of 0.1 rad). The state starts at the steady state of the first sample.
Odometry's curvature is an average over the interval ending at its time
stamp, half a sample late: a fitted ``l`` is shorter than the physical
relaxation by about ``v dt / 2``.

Errors in the input: the measured curvature carries noise, and a column
built from it shares that noise with the residual of the same sample (a
regression on it is biased towards the noise). The columns the structure
tests use are therefore built from a leave-one-out local-linear smoothing of
the curvature (:func:`loo_smooth`): every sample's curvature is estimated
from its neighbours only.

Units: m, rad, 1/m, s, m/s.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PARAM_NAMES", "EFFECT_PARAMS", "null_params", "predict", "lag_column", "columns", "loo_smooth",
           "segments", "hac_cov", "hac_bandwidth"]

PARAM_NAMES = ("L1_m", "L2_m", "offset_rad", "gain", "relaxation_m")
#: candidate effect -> indices of its parameters
EFFECT_PARAMS = {"link_lengths": (0, 1), "hitch_angle_offset": (2,), "curvature_gain": (3,),
                 "hitch_dynamics": (4,)}
#: steps of the finite-difference columns (m, m, rad, 1, m)
_FD_STEP = np.array([1e-4, 1e-4, 1e-5, 1e-5, 1e-3])
#: arcsine argument kept inside this bound (curvature beyond eq. (25) for trial parameters)
_ASIN_CLIP = 0.999999


def null_params(L1_m: float, L2_m: float) -> np.ndarray:
    """The station's model: nominal lengths, no offset, unit gain, no lag."""
    return np.array([L1_m, L2_m, 0.0, 1.0, 0.0])


def _steady(kappa: np.ndarray, L1: float, L2: float) -> tuple[np.ndarray, np.ndarray]:
    """Steady state of eq. (23) (stable branch) and the slope ``c`` of (D) there."""
    r = np.sqrt(1.0 + (kappa * L1) ** 2)
    a = np.arctan(kappa * L1)
    u = np.arcsin(np.clip(kappa * L2 / r, -_ASIN_CLIP, _ASIN_CLIP))
    return a + u, r * np.cos(u)


def predict(theta: np.ndarray, kappa: np.ndarray, dist_m: np.ndarray) -> np.ndarray:
    """Joint angle predicted by the extended model, rad, shape (N,).

    Parameters
    ----------
    theta : ndarray, shape (5,)
        ``L1_m, L2_m, offset_rad, gain, relaxation_m``.
    kappa : ndarray, shape (N,)
        Curvature of each sample, 1/m.
    dist_m : ndarray, shape (N,)
        Distance travelled since the previous sample (``v dt``; the first is unused), m.
    """
    L1, L2, off, g, ell = (float(x) for x in theta)
    e, c = _steady(g * kappa, L1, L2)
    if ell <= 0.0:
        return e + off
    K = g * kappa
    r_l = (np.sqrt(1.0 + (K * L1) ** 2)).tolist()
    a_l = np.arctan(K * L1).tolist()
    s_l = (np.maximum(dist_m, 0.0) / ell).tolist()
    eq = e.tolist()
    out = [0.0] * len(eq)
    p = eq[0]
    out[0] = p
    exp, expm1, cos, sin = math.exp, math.expm1, math.cos, math.sin
    for k in range(1, len(eq)):  # sequential in time: the joint angle's state
        e0, e1 = eq[k - 1], eq[k]
        d = p - e1
        # secant slope of (D) between the state and the equilibrium (c_k at d = 0)
        half = 0.5 * d
        sinc = sin(half) / half if abs(half) > 1e-8 else 1.0
        z = s_l[k] * r_l[k] * cos(p - half - a_l[k]) * sinc
        if z > 1e-9:
            p = e1 + (p - e0) * exp(-z) + (e1 - e0) * expm1(-z) / z
        else:
            p = p  # no travel: the joint holds
        out[k] = p
    return np.asarray(out) + off


def lag_column(theta: np.ndarray, kappa: np.ndarray, kappa_rate: np.ndarray, v_m_s: np.ndarray) -> np.ndarray:
    """``d psi / d relaxation_m`` at ``relaxation_m = 0``: ``-(dpsi_ss/dt) / (v c)``, shape (N,).

    ``dpsi_ss/dt = g kappa_rate (L2 + L1 cos psi) / c`` (eq. (23) differentiated);
    ``kappa_rate`` in 1/(m s).
    """
    L1, L2, _, g, _ = (float(x) for x in theta)
    e, c = _steady(g * kappa, L1, L2)
    return -g * kappa_rate * (L2 + L1 * np.cos(e)) / (c * c * np.maximum(v_m_s, 1e-3))


def columns(theta: np.ndarray, kappa: np.ndarray, dist_m: np.ndarray, which, *, kappa_rate=None,
            v_m_s=None) -> np.ndarray:
    """Columns ``d psi / d theta[i]`` for ``i in which``, shape (N, len(which)).

    Finite differences of :func:`predict`, except the lag at
    ``relaxation_m = 0``, which is :func:`lag_column` (needs ``kappa_rate``
    and ``v_m_s``).
    """
    base = predict(theta, kappa, dist_m)
    cols = []
    for i in which:
        if i == 2:
            cols.append(np.ones_like(base))
            continue
        if i == 4 and theta[4] <= 0.0:
            cols.append(lag_column(theta, kappa, kappa_rate, v_m_s))
            continue
        h = _FD_STEP[i] if i != 4 else max(_FD_STEP[4], 1e-3 * theta[4])
        th = np.array(theta, dtype=float)
        th[i] += h
        cols.append((predict(th, kappa, dist_m) - base) / h)
    return np.column_stack(cols) if cols else np.zeros((base.size, 0))


def loo_smooth(t_s: np.ndarray, x: np.ndarray, half_window: int) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-out local-linear level and slope of ``x`` at each sample, from its neighbours.

    The line through the ``half_window`` samples on each side (fewer at the
    ends), the sample itself left out, evaluated at its time. Returns
    ``(level, slope)``, each shape (N,), slope in units of x per second.
    """
    n = x.size
    u = t_s - t_s.mean()
    cs = [np.concatenate([[0.0], np.cumsum(a)]) for a in (np.ones(n), u, u * u, x, u * x)]
    lo = np.maximum(np.arange(n) - half_window, 0)
    hi = np.minimum(np.arange(n) + half_window + 1, n)
    S = [c[hi] - c[lo] - a for c, a in zip(cs, (np.ones(n), u, u * u, x, u * x))]
    n0, s1, s2, sx, sux = S
    # centred on each sample's own time
    su = s1 - n0 * u
    suu = s2 - 2 * u * s1 + n0 * u * u
    suxc = sux - u * sx
    det = n0 * suu - su * su
    ok = det > 1e-12 * np.maximum(n0 * suu, 1e-300)
    slope = np.where(ok, (n0 * suxc - su * sx) / np.where(ok, det, 1.0), 0.0)
    level = np.where(ok, (sx - slope * su) / np.maximum(n0, 1), sx / np.maximum(n0, 1))
    return level, slope


def segments(rows: np.ndarray) -> np.ndarray:
    """Label (0..S-1) of the contiguous stretch each of ``rows`` (sorted indices) belongs to."""
    return np.cumsum(np.concatenate([[True], np.diff(rows) > 1])) - 1


def _lag_products(A: np.ndarray, B: np.ndarray, seg: np.ndarray, lag: int) -> np.ndarray:
    """``sum_k A[k]' B[k - lag]`` over pairs inside one stretch."""
    same = seg[lag:] == seg[:-lag]
    return A[lag:][same].T @ B[:-lag][same]


def hac_bandwidth(resid: np.ndarray, seg: np.ndarray, max_lag: int, tol: float = 0.05) -> int:
    """Lags over which the residual is correlated: twice the first lag whose autocorrelation is below ``tol``.

    At least 5 samples, at most ``max_lag``.
    """
    r = resid - resid.mean()
    v = float(r @ r)
    if v <= 0.0:
        return 5
    for lag in range(1, max_lag + 1):
        rho = float(_lag_products(r[:, None], r[:, None], seg, lag)[0, 0]) / v
        if rho < tol:
            return int(min(max(5, 2 * lag), max_lag))
    return int(max_lag)


def hac_cov(X: np.ndarray, resid: np.ndarray, seg: np.ndarray, bandwidth: int) -> np.ndarray:
    """Heteroscedasticity- and autocorrelation-robust covariance of least-squares coefficients (N, p).

    ``(X'X)^-1 M (X'X)^-1`` with ``M = G_0 + sum_l (1 - l/(L+1)) (G_l + G_l')``,
    ``G_l = sum_k s_k s_{k-l}'``, ``s_k = x_k r_k`` (Bartlett weights, lags
    counted inside each contiguous stretch of the training record): the
    residuals of a trailer are correlated over the joint angle's relaxation,
    and their variance changes with the curvature.
    """
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    Xs = X / scale
    bread = np.linalg.pinv(Xs.T @ Xs)
    S = Xs * resid[:, None]
    meat = S.T @ S
    for lag in range(1, bandwidth + 1):
        g = _lag_products(S, S, seg, lag)
        meat += (1.0 - lag / (bandwidth + 1.0)) * (g + g.T)
    n = X.shape[0]
    cov = bread @ meat @ bread * (n / max(n - X.shape[1], 1))
    return cov / np.outer(scale, scale)


def rms(x: np.ndarray) -> float:
    return math.sqrt(float(np.mean(x * x))) if x.size else math.nan
