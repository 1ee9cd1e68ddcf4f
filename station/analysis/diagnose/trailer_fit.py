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
stamp (``sampling="interval"``): it is the curvature of the interval's
midpoint, half a sample late. Taken as the curvature at the stamp, that
half-interval lag is a relaxation of ``-v dt / 2`` only to first order: a
fitted ``l`` comes out shorter than the physical one by about ``v dt / 2``,
and at the ideal trailer's relaxation (``l = L2``) the second-order
remainder, ``l (v dt / 2) d^2 psi / ds^2``, looks like a curvature gain
below 1 (about -0.1 %, a false find on a 3-minute record). The curvature at
each stamp is therefore taken between the midpoints of the intervals
(:func:`stamp_curvature`); the steady state of eq. (23) and the relaxation
are then those of the physical trailer. ``sampling="point"``: the
curvature is the value at the stamp.

Errors in the input: the measured curvature carries noise, and a column
built from it shares that noise with the residual of the same sample (a
regression on it is biased towards the noise). The columns the structure
tests use are therefore built from a leave-out local-linear smoothing of
the curvature (:func:`loo_smooth`): every stamp's curvature is estimated
from the samples its own value is not made of.

Units: m, rad, 1/m, s, m/s.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PARAM_NAMES", "EFFECT_PARAMS", "SAMPLINGS", "null_params", "predict", "lag_column", "columns",
           "stamp_curvature", "sample_positions", "loo_smooth", "segments", "hac_cov", "hac_bandwidth",
           "bartlett_weight"]

PARAM_NAMES = ("L1_m", "L2_m", "offset_rad", "gain", "relaxation_m")
#: candidate effect -> indices of its parameters
EFFECT_PARAMS = {"link_lengths": (0, 1), "hitch_angle_offset": (2,), "curvature_gain": (3,),
                 "hitch_dynamics": (4,)}
#: steps of the finite-difference columns (m, m, rad, 1, m)
_FD_STEP = np.array([1e-4, 1e-4, 1e-5, 1e-5, 1e-3])
#: what a curvature sample stands for: the average over the interval ending at its stamp, or the value at it
SAMPLINGS = ("interval", "point")
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
    kappa : ndarray, shape (N,) or (N, K)
        Curvature of each sample, 1/m; ``K`` curvature records at once (the
        columns of a 2-D array, e.g. perturbed by noise draws) give ``K``
        predictions, shape (N, K).
    dist_m : ndarray, shape (N,)
        Distance travelled since the previous sample (``v dt``; the first is unused), m.
    """
    L1, L2, off, g, ell = (float(x) for x in theta)
    e, c = _steady(g * kappa, L1, L2)
    if ell <= 0.0:
        return e + off
    if np.ndim(kappa) == 2:
        return _relax_many(e, g * kappa, L1, np.maximum(dist_m, 0.0) / ell) + off
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


def _relax_many(eq: np.ndarray, K: np.ndarray, L1: float, s: np.ndarray) -> np.ndarray:
    """:func:`predict`'s relaxation step for ``K`` curvature records at once (columns), shape (N, K)."""
    r = np.sqrt(1.0 + (K * L1) ** 2)
    a = np.arctan(K * L1)
    out = np.empty_like(eq)
    p = eq[0].copy()
    out[0] = p
    for k in range(1, eq.shape[0]):  # sequential in time, vectorised over the records
        e0, e1 = eq[k - 1], eq[k]
        if s[k] > 0.0:  # no travel: the joint holds
            half = 0.5 * (p - e1)
            h = np.where(half == 0.0, 1e-20, half)  # the secant's sinc at d = 0 is 1
            z = np.maximum(s[k] * r[k] * np.cos(p - half - a[k]) * (np.sin(h) / h), 1e-12)
            p = e1 + (p - e0) * np.exp(-z) + (e1 - e0) * np.expm1(-z) / z
        out[k] = p
    return out


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


def sample_positions(t_s: np.ndarray, sampling: str) -> np.ndarray:
    """Time each curvature sample stands for, s: its stamp, or the midpoint of the interval ending there.

    The first sample's interval is taken as long as the median interval.
    """
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, got {sampling!r}")
    if sampling == "point":
        return np.asarray(t_s, dtype=float)
    dt = np.diff(t_s)
    return t_s - 0.5 * np.concatenate([[float(np.median(dt))], dt])


def stamp_curvature(t_s: np.ndarray, kappa: np.ndarray, sampling: str) -> np.ndarray:
    """Curvature at each time stamp, 1/m, shape (N,).

    ``"point"``: the samples themselves. ``"interval"``: the line between the
    midpoints of the intervals ending at and after the stamp (each sample is
    the average over its interval, i.e. the curvature at the interval's
    midpoint to second order); the last stamp is extrapolated from the last
    two midpoints.
    """
    if sampling == "point":
        return np.asarray(kappa, dtype=float)
    m = sample_positions(t_s, sampling)
    out = np.empty_like(kappa, dtype=float)
    w = (t_s[:-1] - m[:-1]) / (m[1:] - m[:-1])
    out[:-1] = kappa[:-1] + w * (kappa[1:] - kappa[:-1])
    w_end = (t_s[-1] - m[-1]) / (m[-1] - m[-2])
    out[-1] = kappa[-1] + w_end * (kappa[-1] - kappa[-2])
    return out


def loo_smooth(t_s: np.ndarray, x: np.ndarray, half_window: int, sampling: str = "point"
               ) -> tuple[np.ndarray, np.ndarray]:
    """Local-linear level and slope of ``x`` at each time stamp, from the samples that do not enter it.

    The line through the ``half_window`` samples on each side (fewer at the
    ends), placed at :func:`sample_positions`, evaluated at the stamp. Left
    out are the samples the stamp's own value is made of
    (:func:`stamp_curvature`): the sample itself (``"point"``), or it and the
    next one (``"interval"``), so a column built from the level shares no
    noise with the residual of the same stamp. Returns ``(level, slope)``,
    each shape (N,), slope in units of x per second.
    """
    n = x.size
    pos = sample_positions(t_s, sampling)
    leave = 2 if sampling == "interval" else 1
    centre = pos.mean()
    u = pos - centre
    ue = t_s - centre  # where each estimate is wanted
    cs = [np.concatenate([[0.0], np.cumsum(a)]) for a in (np.ones(n), u, u * u, x, u * x)]
    k = np.arange(n)
    lo = np.maximum(k - half_window, 0)
    hi = np.minimum(k + leave + half_window, n)
    ex_hi = np.minimum(k + leave, n)
    S = [c[hi] - c[lo] - (c[ex_hi] - c[k]) for c in cs]
    n0, s1, s2, sx, sux = S
    # centred on the stamp
    su = s1 - n0 * ue
    suu = s2 - 2 * ue * s1 + n0 * ue * ue
    suxc = sux - ue * sx
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


def bartlett_weight(lag, bandwidth: int):
    """Weight of lag ``lag`` (an int or an array of them) in :func:`hac_cov`'s sum."""
    return 1.0 - lag / (bandwidth + 1.0)


def hac_cov(X: np.ndarray, resid: np.ndarray, seg: np.ndarray, bandwidth: int,
            extra_meat: np.ndarray | None = None) -> np.ndarray:
    """Heteroscedasticity- and autocorrelation-robust covariance of least-squares coefficients (N, p).

    ``(X'X)^-1 M (X'X)^-1`` with ``M = G_0 + sum_l (1 - l/(L+1)) (G_l + G_l')``,
    ``G_l = sum_k s_k s_{k-l}'``, ``s_k = x_k r_k`` (Bartlett weights, lags
    counted inside each contiguous stretch of the training record): the
    residuals of a trailer are correlated over the joint angle's relaxation,
    and their variance changes with the curvature. ``extra_meat`` (p, p),
    in the units of ``X' r``'s square, is added to ``M``: a part of the
    scores' variance the window cannot see (see :mod:`.trailer_input_noise`).
    """
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    Xs = X / scale
    bread = np.linalg.pinv(Xs.T @ Xs)
    S = Xs * resid[:, None]
    meat = S.T @ S
    if extra_meat is not None:
        meat = meat + extra_meat / np.outer(scale, scale)
    for lag in range(1, bandwidth + 1):
        g = _lag_products(S, S, seg, lag)
        meat += bartlett_weight(lag, bandwidth) * (g + g.T)
    n = X.shape[0]
    cov = bread @ meat @ bread * (n / max(n - X.shape[1], 1))
    return cov / np.outer(scale, scale)


def rms(x: np.ndarray) -> float:
    return math.sqrt(float(np.mean(x * x))) if x.size else math.nan
