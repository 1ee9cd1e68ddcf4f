"""A held pose: the robot stands still while the tracker records; noise, drift and an RP-style figure.

What a stream without moves can tell (the same stream is refused by the ISO
analysis, which needs stops):

* noise per axis: the standard deviation of the samples about a straight
  line in time (the drift taken out), and in 3-D the root of the sum of the
  three variances (the rms distance from the drifting mean);
* drift: the slope of that line, per axis and in 3-D, in mm per minute, with
  its standard deviation from the noise;
* the tracker's reading noise (eq. (N1) of :mod:`station.models.tracker_noise`):
  white sd, wander sd and its correlation time, fitted by
  :func:`station.analysis.iso9283.tracker_noise_fit.fit_tracker_noise`
  (with at least :data:`~station.analysis.iso9283.tracker_noise_fit.MIN_FIT_SAMPLES`
  samples); when a wander is resolved the drift's standard deviation counts
  it: the slope of a line through AR(1) noise of lag-one correlation
  ``rho = exp(-dt / tau)`` has the variance of white noise times
  ``(1 + rho) / (1 - rho)``;
* an RP-style figure: the stream cut into windows of ``window_s``; the mean
  of each window plays an attained pose and ``l_bar + 3 S_l`` of eq. (2)
  (seed 000) is taken over the window means about their barycentre. It holds
  the drift within the hold as well as what the noise leaves in a window mean.

A stream with a move in it (the moving-average speed above the rest threshold
over at least ``min_move_mm``, as in the stop extraction) is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.analysis.iso9283.characteristics import position_repeatability
from station.analysis.iso9283.extraction import estimate_noise_mm, moving_speed, validate_stream
from station.analysis.iso9283.tracker_noise_fit import MIN_FIT_SAMPLES, NoiseFit, fit_tracker_noise
from station.errors import DataError, InsufficientDataError


#: fewest samples a window of the RP-style figure must be able to hold (at the stream's median step)
MIN_WINDOW_SAMPLES = 2


@dataclass(frozen=True)
class HoldResult:
    """Figures of a held pose (mm, s, mm/min); arrays per axis x, y, z."""

    n: int
    duration_s: float
    mean_mm: np.ndarray
    noise_mm: np.ndarray
    noise_3d_mm: float
    drift_mm_per_min: np.ndarray
    drift_sd_mm_per_min: np.ndarray
    drift_3d_mm_per_min: float
    window_s: float
    window_t_s: np.ndarray  # (W,) mean time of each window
    window_mean_mm: np.ndarray  # (W, 3)
    window_n: np.ndarray  # (W,)
    l_mm: np.ndarray  # (W,) distance of each window mean to their barycentre
    RP_mm: float
    l_bar_mm: float
    S_l_mm: float
    n_dropped: int  # samples of windows with less than half the fullest one's, left out of the RP figure
    noise_fit: NoiseFit | None = None  # the tracker's reading noise (None: too few samples)

    def to_dict(self) -> dict:
        def fl(a):
            return [round(float(x), 6) for x in np.asarray(a).ravel()]

        return {
            "schema": "station.hold/1", "units": {"position": "mm", "time": "s", "drift": "mm/min"},
            "n": self.n, "duration_s": round(self.duration_s, 6), "mean_mm": fl(self.mean_mm),
            "noise_mm": fl(self.noise_mm), "noise_3d_mm": round(self.noise_3d_mm, 6),
            "drift_mm_per_min": fl(self.drift_mm_per_min), "drift_sd_mm_per_min": fl(self.drift_sd_mm_per_min),
            "drift_3d_mm_per_min": round(self.drift_3d_mm_per_min, 6),
            "windows": {"window_s": self.window_s, "n": int(self.l_mm.size), "t_s": fl(self.window_t_s),
                        "mean_mm": [fl(m) for m in self.window_mean_mm], "n_samples": [int(x) for x in self.window_n],
                        "l_mm": fl(self.l_mm), "RP_mm": round(self.RP_mm, 6), "l_bar_mm": round(self.l_bar_mm, 6),
                        "S_l_mm": round(self.S_l_mm, 6), "n_dropped": self.n_dropped},
            "tracker_noise": None if self.noise_fit is None else self.noise_fit.to_dict("fit of a held pose"),
        }


def analyze_hold(t_s, xyz_mm, valid=None, *, window_s: float = 1.0, min_move_mm: float = 1.0) -> HoldResult:
    """Noise, drift and the RP-style window figure of a stream in which the robot holds one pose.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Time base, s (strictly increasing over the valid rows).
    xyz_mm : array_like, shape (N, 3)
    valid : array_like of bool, shape (N,), optional
        False for rows the instrument flagged.
    window_s : float
        Window length for the RP-style figure, s (at least two windows needed).
    min_move_mm : float
        A faster-than-rest motion over at least this net distance is a move: refused.
    """
    if not (np.isfinite(window_s) and window_s > 0):
        raise DataError(f"window_s must be finite and > 0, got {window_s!r}")
    t, xyz, rows_used, _ = validate_stream(t_s, xyz_mm, valid)
    n = t.size
    if n < 10:
        raise InsufficientDataError(f"a hold needs at least 10 valid samples, got {n}")
    dur = float(t[-1] - t[0])
    # a move? the extraction's test: moving-average speed above the rest threshold over min_move_mm
    dt = float(np.median(np.diff(t)))
    if not window_s >= MIN_WINDOW_SAMPLES * dt:
        raise DataError(f"window_s = {window_s:.6g} s holds less than {MIN_WINDOW_SAMPLES} samples of this stream "
                        f"(one every {dt:.6g} s): give a window of at least {MIN_WINDOW_SAMPLES * dt:.6g} s")
    h = max(1, int(round(0.025 / dt)))
    noise_sd = estimate_noise_mm(xyz, t)
    v_rest = max(2.0, 6.0 * np.sqrt(2.0) * noise_sd / (2 * h * dt))
    u = moving_speed(t, xyz, h, np.array([0], dtype=np.int64))
    fast = np.flatnonzero(u > v_rest)
    if fast.size:
        a, b = int(fast[0]), int(fast[-1])
        if np.linalg.norm(xyz[b] - xyz[a]) >= min_move_mm or np.ptp(xyz[fast], axis=0).max() >= min_move_mm:
            row = a if rows_used is None else int(rows_used[a])
            raise DataError(f"the stream moves (from row {row}, t = {float(t[a]):.3f} s, faster than "
                            f"{v_rest:.3g} mm/s): not a held pose; analyse a stream with stops with "
                            "'station analyze iso9283'")
    tc = t - t.mean()
    stt = float(tc @ tc)
    if stt <= 0:
        raise InsufficientDataError("the stream spans no time")
    mean = xyz.mean(axis=0)
    slope = (tc @ (xyz - mean)) / stt  # mm/s per axis
    resid = xyz - mean - np.outer(tc, slope)
    noise = np.sqrt((resid**2).sum(axis=0) / (n - 2))
    slope_sd = noise / np.sqrt(stt)
    fit = fit_tracker_noise(t, xyz) if n >= MIN_FIT_SAMPLES else None
    if fit is not None and fit.wander_tau_s is not None:
        rho = float(np.exp(-fit.dt_s / fit.wander_tau_s))
        var_um2 = fit.white_um ** 2 + fit.wander_um ** 2 * (1.0 + rho) / (1.0 - rho)
        slope_sd = np.maximum(slope_sd, np.full(3, np.sqrt(var_um2) * 1e-3 / np.sqrt(stt)))
    # windows of window_s from the first sample; a window with less than half the fullest one's samples (the
    # last, or one cut by a beam break) is left out
    # the windows the samples fall in, numbered 0.. in order (a gap in time makes no empty windows: memory and
    # time grow with the samples, never with duration / window_s)
    _, w = np.unique(np.floor((t - t[0]) / window_s), return_inverse=True)
    w = w.ravel()
    counts = np.bincount(w)
    full = counts >= 0.5 * counts.max()
    keep_w = np.flatnonzero(full & (counts > 0))
    if keep_w.size < 2:
        raise InsufficientDataError(f"the hold lasts {dur:.3g} s: at least two windows of {window_s:g} s are needed")
    sums = np.stack([np.bincount(w, weights=xyz[:, k]) for k in range(3)], axis=1)
    tsum = np.bincount(w, weights=t)
    wm = sums[keep_w] / counts[keep_w, None]
    rep = position_repeatability(wm)
    dropped = int(n - counts[keep_w].sum())
    return HoldResult(
        n=n, duration_s=dur, mean_mm=mean, noise_mm=noise, noise_3d_mm=float(np.sqrt(np.sum(noise**2))),
        drift_mm_per_min=60.0 * slope, drift_sd_mm_per_min=60.0 * slope_sd,
        drift_3d_mm_per_min=float(60.0 * np.linalg.norm(slope)), window_s=float(window_s),
        window_t_s=tsum[keep_w] / counts[keep_w], window_mean_mm=wm, window_n=counts[keep_w], l_mm=rep.l_mm,
        RP_mm=rep.RP_mm, l_bar_mm=rep.l_bar_mm, S_l_mm=rep.S_l_mm, n_dropped=dropped, noise_fit=fit,
    )
