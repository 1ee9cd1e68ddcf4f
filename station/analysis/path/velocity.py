"""Path velocity accuracy AV, repeatability RV and fluctuation FV (ISO 9283 clause 8.5), in % of the commanded.

The speed along the path is the derivative of the measured positions (a
Savitzky-Golay cubic over :data:`SPEED_WINDOW_S`, flat well beyond the servo's
ripple, it keeps the tracker's noise out of the derivative), taken over the
part of each cycle where the speed is meant to be constant. With v_bar_j the
mean speed of cycle j and v_c the commanded speed:
AV = (mean_j v_bar_j - v_c) / v_c x 100; RV = 3 S(v_bar_j) / v_c x 100;
FV = max_j (max v_ji - min v_ji) / v_c x 100 (largest fluctuation in one cycle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from station.analysis.path.mc import DEFAULT_TRIALS, from_draws
from station.analysis.path.noise import PathNoise

#: draws of the range (the costly part: a filtered noise per draw); u(FV) to about 10 %
FV_TRIALS = 50

#: time span of the derivative's local cubic, s
SPEED_WINDOW_S = 0.04


def _window(dt: float, n: int) -> int:
    w = int(round(SPEED_WINDOW_S / dt)) | 1
    w = max(w, 5)
    return min(w, n if n % 2 else n - 1)


def speed(xyz_mm, dt_s: float, noise_sd_mm: float = 0.0) -> np.ndarray:
    """Speed (mm/s) of uniformly sampled positions (n, 3) at interval ``dt_s``.

    The noise across the path (two axes, sd s_v = noise_sd x |h| each after the filter h) adds to the
    squared speed on average 2 s_v^2: taken off (sqrt(|v|^2 - 2 s_v^2)); along the path it averages out.
    """
    x = np.asarray(xyz_mm, dtype=float)
    w = _window(dt_s, x.shape[0])
    v = savgol_filter(x, w, 3, deriv=1, delta=dt_s, axis=0, mode="nearest")
    sv = noise_sd_mm * float(np.linalg.norm(savgol_coeffs(w, 3, deriv=1, delta=dt_s)))
    return np.sqrt(np.maximum(np.einsum("ij,ij->i", v, v) - 2.0 * sv * sv, 0.0))


def curvature_bias(radius_mm: float, v_mm_s: float, dt_s: float) -> float:
    """Relative error of :func:`speed` on a circle of this radius at this speed (the cubic's bias on the arc):
    the filter applied to the commanded circle; measured speeds are divided by 1 + this."""
    w = _window(dt_s, 10 ** 9)
    phi = v_mm_s * dt_s * (np.arange(w) - w // 2) / radius_mm
    p = radius_mm * np.stack([np.cos(phi), np.sin(phi), 0 * phi], axis=1)
    h = savgol_coeffs(w, 3, deriv=1, delta=dt_s, use="dot")
    return float(np.linalg.norm(h @ p) / v_mm_s - 1.0)


@dataclass(frozen=True)
class PathVelocity:
    AV_percent: float
    RV_percent: float | None
    FV_percent: float
    mean_speed_mm_s: np.ndarray  # (K,) per cycle
    range_mm_s: np.ndarray  # (K,) max - min per cycle


def _figures(means, ranges, v_c):
    av = (np.mean(means, axis=-1) - v_c) / v_c * 100.0
    rv = 3.0 * np.std(means, axis=-1, ddof=1) / v_c * 100.0 if means.shape[-1] >= 2 else None
    fv = np.max(ranges, axis=-1) / v_c * 100.0
    return av, rv, fv


def path_velocity(speeds: list[np.ndarray], v_c: float) -> PathVelocity:
    """``speeds``: each cycle's speed samples in the constant-speed window."""
    means = np.array([float(np.mean(v)) for v in speeds])
    ranges = np.array([float(np.ptp(v)) for v in speeds])
    av, rv, fv = _figures(means, ranges, v_c)
    return PathVelocity(float(av), None if rv is None else float(rv), float(fv), means, ranges)


def velocity_uncertainty(pieces: list[tuple[np.ndarray, float]], v_c: float, noise_sd_mm, pv: PathVelocity,
                         subject: str, *, trials: int = DEFAULT_TRIALS, seed: int = 0, k: float = 2.0) -> dict:
    """u, U of AV, RV, FV: each cycle's speed re-measured with the instrument noise along the path.

    ``pieces``: per cycle ``(speed samples in the window, dt_s)``; ``noise_sd_mm`` a white sd or a
    :class:`~station.analysis.path.noise.PathNoise` (white and wander). The noise's derivative
    is the filter's kernel h applied to the noise. A window's mean takes the noise e . g / n (g = h * ones(n)):
    drawn directly, with variance ``g^T C g / n^2`` (C the noise's covariance: white on the diagonal, the
    wander's ``wander^2 exp(-|t_i - t_j| / tau)``; a wander slower than the window moves its two ends apart
    and the mean with them). The range is drawn, once and twice the noise, only where it can be made: the
    cycles whose range is within reach of the largest and their samples within reach of their max and min
    (reach: 5 sd of the filtered noise, every w/8-th sample: both are smooth over the filter's w samples).
    """
    pn = PathNoise.of(noise_sd_mm)
    rng = np.random.default_rng([seed, 44, 85])
    K = len(pieces)
    u_mean = np.empty(K)
    sd_v = np.empty(K)
    kernels = []
    for j, (v, dt) in enumerate(pieces):  # loop over cycles
        h = savgol_coeffs(_window(dt, 10 ** 9), 3, deriv=1, delta=dt, use="dot")
        kernels.append(h)
        g = np.convolve(h, np.ones(v.size))
        var = (pn.white_mm * float(np.linalg.norm(g)) / v.size) ** 2
        if pn.has_wander:
            tg = dt * np.arange(g.size)
            var += float(g @ pn.wander_covariance(tg) @ g) / v.size ** 2
        u_mean[j] = np.sqrt(var)
        sd_v[j] = pn.total_mm * float(np.linalg.norm(h))
    means = pv.mean_speed_mm_s[None] + rng.standard_normal((trials, K)) * u_mean[None]
    reach = 5.0 * sd_v.max()
    tr = min(trials, FV_TRIALS)
    ranges = np.broadcast_to(pv.range_mm_s, (2, tr, K)).copy()
    for j in np.flatnonzero(pv.range_mm_s >= pv.range_mm_s.max() - 2.0 * reach):  # loop over candidate cycles
        (v, dt), h = pieces[j], kernels[j]
        # every (w/8)th of them: the filtered noise and the speed are smooth over the filter's span
        idx = np.flatnonzero((v >= v.max() - reach) | (v <= v.min() + reach))[::max(h.size // 8, 1)]
        taps = idx[:, None] + np.arange(h.size)[None] - h.size // 2  # the noise samples each speed sample takes
        used, inv = np.unique(taps, return_inverse=True)
        e = pn.draw(rng, (2, tr), dt * used, 1)[..., 0]
        e[1] += e[0]  # twice the noise: the first draw plus a fresh one
        dv = e[:, :, inv.reshape(taps.shape)] @ h
        x = v[idx][None, None] + dv
        # relative to the full range: the thinned samples' own range is what the draws move from
        ranges[:, :, j] = x.max(axis=2) - x.min(axis=2) + (pv.range_mm_s[j] - np.ptp(v[idx]))
    av, rv, _ = _figures(means, pv.range_mm_s[None], v_c)
    fv = ranges.max(axis=2) / v_c * 100.0
    n = K
    f_av, f_rv, f_fv = _filter_response(pieces, v_c)
    out = {"AV_percent": from_draws("AV_percent", subject, pv.AV_percent, av, k=k, n=n, seed=seed, extra=f_av),
           "FV_percent": from_draws("FV_percent", subject, pv.FV_percent, fv[0], k=k, n=n, seed=seed, draws2=fv[1],
                                    extrapolate="sd", extra=f_fv)}
    if rv is not None and pv.RV_percent is not None:
        out["RV_percent"] = from_draws("RV_percent", subject, pv.RV_percent, rv, k=k, n=n, seed=seed, extra=f_rv)
    return out


def _filter_response(pieces, v_c: float) -> tuple[dict, dict, dict]:
    """What the derivative's filter may have taken off the speed (a fast ripple), as standard uncertainties
    of AV, RV, FV: the change when the speed is filtered once more by the same span (a local cubic)."""
    dm, dr = [], []
    for v, dt in pieces:  # loop over cycles
        vv = savgol_filter(v, _window(dt, v.size), 3, mode="interp")
        dm.append(float(np.mean(v) - np.mean(vv)))
        dr.append(float(np.ptp(v) - np.ptp(vv)))
    key = "the derivative filter's response (filtered once more)"
    rms = float(np.sqrt(np.mean(np.square(dm))))
    return ({key: 100.0 * rms / v_c}, {key: 300.0 * rms / v_c},
            {key: 100.0 * float(np.max(np.abs(dr))) / v_c})
