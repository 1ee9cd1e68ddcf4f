"""The curvature noise's share of the trailer diagnosis's covariance that the robust window cannot see.

The diagnosis's model is driven by the measured curvature (or its leave-out
smoothing, :func:`.trailer_fit.loo_smooth`): the curvature sensor's noise
passes through the model into the residual, filtered by the joint angle's
relaxation (eq. (D) of :mod:`station.models.trailer`, scaled to relax over
``l``) or by the smoothing. At the low frequencies of the columns it is
as large as the curvature noise times the slope of eq. (23) (seed 003);
its correlation lasts ``l / (v dt)`` samples (50 for the ideal trailer's
``l = L2 = 2.48 m`` at 1 m/s and 20 Hz) and falls off exponentially. The
robust covariance's Bartlett window of ``L`` lags, counted inside the
training stretches, sees a share of about ``1 - l / (v dt L)`` of that
long-run variance: about 60 % at the 135 lags a 3-minute record allows, and
the residual's own autocorrelation cannot show what it misses (the filtered
noise is under 1 % of the residual's variance). Where the curvature noise
dominates (a hitch sensor of 0.5 mrad), the window alone made the
relaxation's interval 30 % too narrow on a 3-minute record at 1 m/s (88 of
100 intervals held the truth) and more than twice too narrow on a 90 s
record at 0.4 m/s (23 of 40); at the default sensor noise (2 to 5 mrad) the
share is small and the window alone held the truth at about the nominal
rate.

Propagated instead of estimated from the residual (errors in variables): a
fixed set of draws of white curvature noise with the record's own sigma
(:func:`station.analysis.trailer.least_squares.noise_sigma` of the measured
curvature) is passed through the fit's input map (the same stamping or
smoothing) and the model (:func:`.trailer_fit.predict`), giving responses
``D_d``. The scores' variance due to that noise is ``E[(J' D)(J' D)']``;
what the window sees of it is the Bartlett sum over the responses' part left
in a fitted residual (``D`` less its projection on ``J``). The difference,
the part the window cannot see, is added to the window's meat
(:func:`.trailer_fit.hac_cov`); the joint-angle noise, heteroscedasticity and
any short-range structure stay with the robust window.

Units: the meat is in units of ``(J' r)^2``: rad^2 times the squared units of ``J``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .trailer_fit import bartlett_weight, predict

__all__ = ["NOISE_DRAWS", "unseen_input_meat"]

#: draws of the curvature noise propagated (the unseen share's relative sd is about sqrt(2 / NOISE_DRAWS))
NOISE_DRAWS = 128
#: the draws are a fixed quadrature of the noise, so a diagnosis of one record is reproducible
_DRAW_SEED = 20261128


def unseen_input_meat(theta: np.ndarray, J: np.ndarray, rows: np.ndarray, seg: np.ndarray, bandwidth: int, *,
                      kappa_in: np.ndarray, to_input: Callable[[np.ndarray], np.ndarray], dist_m: np.ndarray,
                      sigma: float) -> np.ndarray:
    """Scores' variance from the curvature noise beyond what a Bartlett window of ``bandwidth`` lags sees, (p, p).

    Parameters
    ----------
    theta : ndarray, shape (5,)
        The fitted model (:mod:`.trailer_fit`).
    J : ndarray, shape (n, p)
        The model's columns on the fit's rows.
    rows : ndarray, shape (n,)
        The fit's rows (indices into the record), with ``seg`` their contiguous stretches.
    bandwidth : int
        The robust window's lags.
    kappa_in : ndarray, shape (N,)
        The curvature driving the fit, 1/m.
    to_input : callable
        Maps raw curvature noise (N,) to its part of ``kappa_in`` (linear: the stamping or the smoothing).
    dist_m : ndarray, shape (N,)
        Travel per sample, m.
    sigma : float
        The measured curvature's white-noise sigma, 1/m.

    Returns the positive semi-definite part of ``E[(J' D)(J' D)'] - E[Bartlett meat of M D]``.
    """
    p = J.shape[1]
    if not (sigma > 0.0) or p == 0 or rows.size == 0:
        return np.zeros((p, p))
    rng = np.random.default_rng(_DRAW_SEED)
    n_all = kappa_in.size
    noise = np.column_stack([to_input(rng.normal(0.0, sigma, n_all)) for _ in range(NOISE_DRAWS)])
    D = (predict(theta, kappa_in[:, None] + noise, dist_m) - predict(theta, kappa_in, dist_m)[:, None])[rows]
    A = J.T @ D
    full = A @ A.T / NOISE_DRAWS
    Q = np.linalg.qr(J)[0]
    MD = D - Q @ (Q.T @ D)  # what a fitted residual keeps of the response
    seen = np.zeros((p, p))
    for s in np.unique(seg):  # the window's expected meat: Bartlett weights on each stretch's covariance
        m = seg == s
        k = np.arange(int(m.sum()))
        lag = np.abs(k[:, None] - k[None, :])
        W = np.where(lag <= bandwidth, bartlett_weight(lag, bandwidth), 0.0)
        C = MD[m] @ MD[m].T / NOISE_DRAWS
        seen += J[m].T @ (W * C) @ J[m]
    w, V = np.linalg.eigh(0.5 * ((full - seen) + (full - seen).T))
    return (V * np.maximum(w, 0.0)) @ V.T
