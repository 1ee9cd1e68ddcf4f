"""The tracker's reading noise fitted from a held pose: white sd, wander sd and its correlation time.

A held pose is read by the tracker as the true position (drifting slowly as
the arm warms up) plus the reading noise of eq. (N1)
(:mod:`station.models.tracker_noise`). With the drift line taken out of each
axis, the empirical semivariogram at lag ``m`` samples,

    g_hat(m) = mean over axes and pairs of (x[k + m] - x[k])^2 / 2,

is fitted by eq. (N2), ``white^2 + wander^2 (1 - exp(-m dt / tau))``, in
relative least squares over lags from one sample to a tenth of the hold
(about 40 lags, spaced evenly in log). Only pairs of samples that are
``m`` sample intervals apart in time are used (a beam break does not pair
samples across it). A correlation time at the lower bound (half a sample) is
noise as white as the samples can tell, and is folded into ``white``; a
wander below 2 % of the white variance is not resolved (reported 0, no
time constant). The latency is not measurable from a hold (nothing moves).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import DataError, InsufficientDataError
from station.models.tracker_noise import TrackerNoise

__all__ = ["NoiseFit", "fit_tracker_noise", "MIN_FIT_SAMPLES"]

#: fewest valid samples of a hold whose noise is fitted
MIN_FIT_SAMPLES = 200
#: lags of the semivariogram: up to this fraction of the hold, this many (log-spaced)
_MAX_LAG_FRACTION = 0.1
_N_LAGS = 40
#: a wander whose variance is below this fraction of the white one is not resolved
_MIN_WANDER_FRACTION = 0.02
#: a wander's rise over the lags must exceed this many standard errors of the semivariogram of white noise
_RISE_SE = 5.0


@dataclass(frozen=True)
class NoiseFit:
    """Fit of eq. (N2) to a held pose (um per coordinate, s)."""

    white_um: float
    wander_um: float
    wander_tau_s: float | None
    dt_s: float
    lags_s: np.ndarray
    gamma_um2: np.ndarray
    model_gamma_um2: np.ndarray
    rms_rel: float  # rms relative misfit of the semivariogram
    note: str

    def noise(self, source: str = "") -> TrackerNoise:
        return TrackerNoise(white_um=self.white_um, wander_um=self.wander_um, wander_tau_s=self.wander_tau_s,
                            latency_s=0.0, source=source)

    def to_dict(self, source: str = "") -> dict:
        d = self.noise(source).to_dict()
        d["latency_s"] = None  # not measured by a hold
        d["fit"] = {"method": "semivariogram of the detrended hold, eq. (N2), relative least squares",
                    "dt_s": round(self.dt_s, 9), "lags_s": [round(float(x), 6) for x in self.lags_s],
                    "gamma_um2": [round(float(x), 6) for x in self.gamma_um2],
                    "model_gamma_um2": [round(float(x), 6) for x in self.model_gamma_um2],
                    "rms_relative_misfit": round(self.rms_rel, 6), "note": self.note,
                    "latency": "not measurable from a hold; latency_s is null"}
        return d


def _semivariogram(t: np.ndarray, x: np.ndarray, dt: float, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(lags kept, g_hat (L,))`` in the units of ``x`` squared, pairs exactly ``m`` intervals apart."""
    keep, out = [], []
    for m in lags:  # ~40 lags, each vectorised over the samples
        ok = np.abs((t[m:] - t[:-m]) - m * dt) < 0.5 * dt
        if np.count_nonzero(ok) < 30:
            continue
        d = x[m:][ok] - x[:-m][ok]
        keep.append(m)
        out.append(0.5 * float(np.mean(d * d)))
    return np.array(keep, dtype=np.int64), np.array(out)


def fit_tracker_noise(t_s, xyz_mm) -> NoiseFit:
    """Fit eq. (N2) to a held pose's valid samples (``t_s`` (N,) s increasing, ``xyz_mm`` (N, 3)).

    Raises
    ------
    InsufficientDataError
        Fewer than :data:`MIN_FIT_SAMPLES` samples, or too few pairs at every lag.
    DataError
        Non-finite input, or a time base that does not increase.
    """
    from scipy.optimize import least_squares

    t = np.asarray(t_s, dtype=float).reshape(-1)
    xyz = np.asarray(xyz_mm, dtype=float)
    if xyz.shape != (t.size, 3) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(xyz))):
        raise DataError("the noise fit needs finite times (N,) and positions (N, 3)")
    if t.size < MIN_FIT_SAMPLES:
        raise InsufficientDataError(f"the noise fit needs at least {MIN_FIT_SAMPLES} valid samples, got {t.size}")
    steps = np.diff(t)
    if np.any(steps <= 0):
        raise DataError("the noise fit needs strictly increasing times")
    dt = float(np.median(steps))
    tc = t - t.mean()
    x = xyz - xyz.mean(axis=0)
    slope = (tc @ x) / float(tc @ tc)
    x = (x - np.outer(tc, slope)) * 1e3  # um, drift line out
    n_max = max(1, int(_MAX_LAG_FRACTION * t.size))
    lags = np.unique(np.round(np.logspace(0.0, math.log10(n_max), _N_LAGS)).astype(np.int64))
    m, g = _semivariogram(t, x, dt, lags)
    if m.size < 4 or not np.all(g > 0):
        raise InsufficientDataError("the noise fit found too few pairs of samples a whole number of intervals "
                                    "apart (a hold with steady stamps is needed)")
    lag_s = m * dt
    T = float(t[-1] - t[0])
    tau_lo, tau_hi = 0.5 * dt, max(T / 3.0, dt)

    def model(p):
        w2, g2, tau = p
        return w2 + g2 * (1.0 - np.exp(-lag_s / tau))

    g1, gL = float(g[0]), float(g[-1])
    rise = np.flatnonzero(g >= g1 + 0.63 * (gL - g1))
    tau0 = float(np.clip(lag_s[rise[0]] if rise.size else lag_s[-1], tau_lo * 1.01, tau_hi * 0.99))
    p0 = [max(g1 * 0.9, 1e-12), max(gL - g1, 1e-3 * g1), tau0]
    fit = least_squares(lambda p: (model(p) - g) / g, p0, bounds=([0.0, 0.0, tau_lo], [np.inf, np.inf, tau_hi]),
                        x_scale=[g1, max(gL, g1), tau0])
    w2, g2, tau = (float(v) for v in fit.x)
    model_g = model(fit.x)
    note = "white noise and a wander resolved"
    if tau <= tau_lo * 1.001:
        w2, g2, tau, note = w2 + g2, 0.0, None, "the wander is as fast as the samples: folded into the white noise"
    elif g2 < _MIN_WANDER_FRACTION * max(w2, 1e-30):
        w2, g2, tau, note = w2 + g2, 0.0, None, "no wander resolved (below 2 % of the white variance)"
    elif g2 * (math.exp(-lag_s[0] / tau) - math.exp(-lag_s[-1] / tau)) < (
            _RISE_SE * w2 * math.sqrt(2.0 / (3.0 * (t.size - m[-1])))):
        # the rise the wander makes over the lags (from the first to the last: a fit's extrapolation to lag 0 is
        # not seen) is within the scatter white noise gives the semivariogram at its longest lag (each lag's mean
        # of (dx)^2 / 2 over 3 (N - m) pairs: relative sd sqrt(2 / (3 (N - m)))): on white noise a slow "wander"
        # was fitted to that scatter on 1 in 8 drawn holds, and a "wander" of under a sample's time to a first
        # lag 1 % low (CI seed 1781346930: tau 3.8 ms at 5 ms samples, a rise of 2.7 um^2 from lag 0 that is
        # 0.7 um^2 over the lags)
        w2, g2, tau, note = w2 + g2, 0.0, None, ("no wander resolved (its rise over the lags is within "
                                                 f"{_RISE_SE:g} standard errors of white noise's)")
    elif tau >= tau_hi * 0.999:
        note = ("the wander's correlation time reaches a third of the hold: it is at least that long (a longer "
                "hold tells it)")
    rms = float(np.sqrt(np.mean(((model_g - g) / g) ** 2)))
    return NoiseFit(math.sqrt(w2), math.sqrt(g2), tau, dt, lag_s, g, model_g, rms, note)
