"""Weaving stroke error WS and weaving frequency error WF (ISO 9283 clause 11), in % of the commanded.

Each cycle's deviation across the base line, along the weaving direction,
y(t), is fitted by least squares with a sine of free amplitude, phase and
frequency on a straight trend (y = a cos wt + b sin wt + c0 + c1 t; w from a
grid over +/-30 % of the commanded, then refined). A_j = sqrt(a^2 + b^2),
F_j = w / 2 pi. WS = (mean_j A_j - A_c) / A_c x 100 (the stroke is twice the
amplitude on both sides, so the ratio is the same); WF = (mean_j F_j - F_c) /
F_c x 100. u from the fit's covariance (the residual's variance: the noise and
whatever of the robot's motion the sine does not hold), averaged over cycles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from station.analysis.path.mc import from_u

#: the frequency grid's span about the commanded (fraction) and its points
SPAN = 0.3
GRID = 121


@dataclass(frozen=True)
class SineFit:
    amplitude_mm: float
    frequency_Hz: float
    u_amplitude_mm: float
    u_frequency_Hz: float
    rms_mm: float


def _design(t, w):
    return np.stack([np.cos(w * t), np.sin(w * t), np.ones_like(t), t], axis=1)


def _rss(t, y, w):
    A = _design(t, w)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    return float(r @ r), coef


def fit_sine(t_s, y_mm, f_c_hz: float) -> SineFit:
    """Least-squares sine on a trend; ``f_c_hz`` the commanded frequency (the search is within +/-SPAN)."""
    t = np.asarray(t_s, float) - float(np.mean(t_s))
    y = np.asarray(y_mm, float)
    w_c = 2 * np.pi * f_c_hz
    grid = w_c * np.linspace(1 - SPAN, 1 + SPAN, GRID)
    # the grid's residuals in one batch (normal equations per frequency) on a series thinned to ~20 samples a
    # period of the fastest frequency searched: enough to find the minimum the refinement then takes on all
    full_t, full_y = t, y
    step = max(int(len(t) / max((t[-1] - t[0]) * 20 * (1 + SPAN) * f_c_hz, 1.0)), 1)
    t, y = t[::step], y[::step]
    C, S = np.cos(np.outer(grid, t)), np.sin(np.outer(grid, t))
    n = t.size
    G = np.empty((grid.size, 4, 4))
    G[:, 0, 0], G[:, 1, 1], G[:, 0, 1] = (C * C).sum(1), (S * S).sum(1), (C * S).sum(1)
    G[:, 0, 2], G[:, 1, 2], G[:, 0, 3], G[:, 1, 3] = C.sum(1), S.sum(1), C @ t, S @ t
    G[:, 2, 2], G[:, 2, 3], G[:, 3, 3] = n, t.sum(), t @ t
    iu = np.triu_indices(4, 1)
    G[:, iu[1], iu[0]] = G[:, iu[0], iu[1]]
    b = np.stack([C @ y, S @ y, np.full(grid.size, y.sum()), np.full(grid.size, t @ y)], axis=1)
    coef = np.linalg.solve(G, b[..., None])[..., 0]
    rss = y @ y - np.einsum("gi,gi->g", coef, b)
    i = int(np.argmin(rss))
    t, y = full_t, full_y
    step = grid[1] - grid[0]
    opt = minimize_scalar(lambda w: _rss(t, y, w)[0], bounds=(grid[i] - step, grid[i] + step), method="bounded",
                          options={"xatol": 1e-7 * w_c})
    w = float(opt.x)
    rss_w, (a, b, c0, c1) = _rss(t, y, w)
    one = np.ones_like(t)
    s2 = rss_w / max(n - 5, 1)
    J = np.column_stack([np.cos(w * t), np.sin(w * t), one, t, t * (-a * np.sin(w * t) + b * np.cos(w * t))])
    cov = s2 * np.linalg.inv(J.T @ J)
    amp = float(np.hypot(a, b))
    g = np.array([a, b]) / max(amp, 1e-300)
    u_amp = float(np.sqrt(max(g @ cov[:2, :2] @ g, 0.0)))
    return SineFit(amp, w / (2 * np.pi), u_amp, float(np.sqrt(cov[4, 4])) / (2 * np.pi), float(np.sqrt(s2)))


@dataclass(frozen=True)
class WeavingResult:
    WS_percent: float
    WF_percent: float | None
    fits: list


def weaving(fits: list[SineFit], A_c: float, F_c: float, subject: str, *, frequency: bool = True,
            k: float = 2.0) -> tuple[WeavingResult, dict]:
    """WS (and WF unless ``frequency`` is False: a clock that cannot be trusted) from the cycles' fits."""
    n = len(fits)
    A = np.array([f.amplitude_mm for f in fits])
    F = np.array([f.frequency_Hz for f in fits])
    ws = (A.mean() - A_c) / A_c * 100.0
    u = {"WS_percent": from_u("WS_percent", subject, ws, {
        "sine fit (noise and unfitted motion)": 100.0 / A_c * np.sqrt(np.sum([f.u_amplitude_mm ** 2 for f in fits])) / n},
        k=k, n=n)}
    wf = None
    if frequency:
        wf = (F.mean() - F_c) / F_c * 100.0
        u["WF_percent"] = from_u("WF_percent", subject, wf, {
            "sine fit (noise and unfitted motion)": 100.0 / F_c * np.sqrt(np.sum([f.u_frequency_Hz ** 2 for f in fits])) / n},
            k=k, n=n)
    return WeavingResult(float(ws), None if wf is None else float(wf), fits), u
