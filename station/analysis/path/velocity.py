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
from scipy.signal import oaconvolve, savgol_coeffs, savgol_filter

from station.analysis.path.mc import DEFAULT_TRIALS, from_draws

#: time span of the derivative's local cubic, s
SPEED_WINDOW_S = 0.04


def _window(dt: float, n: int) -> int:
    w = int(round(SPEED_WINDOW_S / dt)) | 1
    w = max(w, 5)
    return min(w, n if n % 2 else n - 1)


def speed(xyz_mm, dt_s: float) -> np.ndarray:
    """Speed (mm/s) of uniformly sampled positions (n, 3) at interval ``dt_s``."""
    x = np.asarray(xyz_mm, dtype=float)
    v = savgol_filter(x, _window(dt_s, x.shape[0]), 3, deriv=1, delta=dt_s, axis=0, mode="interp")
    return np.linalg.norm(v, axis=1)


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


def velocity_uncertainty(pieces: list[tuple[np.ndarray, float]], v_c: float, noise_sd_mm: float,
                         pv: PathVelocity, subject: str, *, trials: int = DEFAULT_TRIALS, seed: int = 0,
                         k: float = 2.0) -> dict:
    """u, U of AV, RV, FV: each cycle's speed re-measured with the instrument noise along the path.

    ``pieces``: per cycle ``(speed samples in the window, dt_s)``; the noise's derivative is the same
    filter's (its kernel applied to white noise: an FFT convolution, the cost of one pass per trial).
    """
    rng = np.random.default_rng([seed, 44, 85])
    means = np.empty((trials, len(pieces)))
    ranges = np.empty((trials, len(pieces)))
    for j, (v, dt) in enumerate(pieces):  # loop over cycles
        w = _window(dt, 10 ** 9)
        h = savgol_coeffs(w, 3, deriv=1, delta=dt, use="conv")
        e = rng.standard_normal((trials, v.size + w - 1)) * noise_sd_mm
        dv = oaconvolve(e, h[None], mode="valid", axes=1)
        x = v[None] + dv
        means[:, j] = x.mean(axis=1)
        ranges[:, j] = np.ptp(x, axis=1)
    av, rv, fv = _figures(means, ranges, v_c)
    n = len(pieces)
    out = {"AV_percent": from_draws("AV_percent", subject, pv.AV_percent, av, k=k, n=n, seed=seed),
           "FV_percent": from_draws("FV_percent", subject, pv.FV_percent, fv, k=k, n=n, seed=seed, debias=True,
                                    note="corrected for the push of the tracker's noise on the range")}
    if rv is not None and pv.RV_percent is not None:
        out["RV_percent"] = from_draws("RV_percent", subject, pv.RV_percent, rv, k=k, n=n, seed=seed)
    return out
