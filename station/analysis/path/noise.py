"""The instrument's reading noise as the path figures' re-measurement draws take it: white plus a wander.

A tracker's reading error per coordinate is white noise of sd ``white_mm`` plus a wander of sd ``wander_mm``
that decorrelates over ``wander_tau_s`` (eq. (N1); its semivariogram is eq. (N2),
:class:`~station.models.tracker_noise.TrackerNoise`). A figure that averages samples over less than the
wander's time (a window's mean speed, a cycle's crossings of neighbouring planes) does not average the wander
away: drawn as white noise of the total sd, the spread of three 0.3 s windows' mean speed came out 0.55 of
what repeated measurements show (a Leica-like 0.6 um white, 2 um wander over 1 s), and drawn as white noise of
the white sd alone, 0.16 of it. The draws
here give the wander its correlation: a stationary first-order Gauss-Markov process at the samples' times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import DataError


@dataclass(frozen=True)
class PathNoise:
    """Per-coordinate reading noise, mm and s: white sd, wander sd and the wander's correlation time."""

    white_mm: float
    wander_mm: float = 0.0
    wander_tau_s: float | None = None

    @property
    def total_mm(self) -> float:
        return math.hypot(self.white_mm, self.wander_mm)

    @property
    def has_wander(self) -> bool:
        return self.wander_mm > 0.0 and bool(self.wander_tau_s)

    @classmethod
    def of(cls, noise) -> "PathNoise":
        """From a number (white sd, mm), a :class:`PathNoise`, or a tracker's noise model (``white_um``,
        ``wander_um``, ``wander_tau_s``: a :class:`~station.models.tracker_noise.TrackerNoise`)."""
        if isinstance(noise, PathNoise):
            return noise
        if hasattr(noise, "white_um"):
            tau = getattr(noise, "wander_tau_s", None)
            return cls(float(noise.white_um) * 1e-3, float(getattr(noise, "wander_um", 0.0)) * 1e-3,
                       None if tau is None else float(tau))
        v = float(noise)
        if not (math.isfinite(v) and v >= 0.0):
            raise DataError(f"the instrument noise must be a finite sd >= 0 mm, got {noise!r}")
        return cls(v)

    def wander_covariance(self, t_s) -> np.ndarray:
        """The wander's covariance between readings at times ``t_s`` (N,), mm^2."""
        t = np.asarray(t_s, dtype=float)
        if not self.has_wander:
            return np.zeros((t.size, t.size))
        return self.wander_mm ** 2 * np.exp(-np.abs(t[:, None] - t[None, :]) / float(self.wander_tau_s))

    def draw(self, rng: np.random.Generator, lead: tuple, t_s, k: int = 3) -> np.ndarray:
        """Draws ``lead + (N, k)``: white noise plus the wander at the times ``t_s`` (N,), each coordinate and
        each leading index its own realisation. Times need not be evenly spaced; they are taken in the given
        order, which must not decrease."""
        t = np.asarray(t_s, dtype=float).reshape(-1)
        e = rng.standard_normal((*lead, t.size, k)) * self.white_mm
        if not self.has_wander or t.size == 0:
            return e
        if np.any(np.diff(t) < 0.0):
            raise DataError("the noise's sample times must not decrease")
        rho = np.exp(-np.diff(t) / float(self.wander_tau_s))
        z = rng.standard_normal((*lead, t.size, k))
        w = np.empty_like(z)
        w[..., 0, :] = z[..., 0, :]
        for i in range(1, t.size):  # loop over samples: a first-order Gauss-Markov step
            w[..., i, :] = rho[i - 1] * w[..., i - 1, :] + math.sqrt(1.0 - rho[i - 1] ** 2) * z[..., i, :]
        return e + self.wander_mm * w
