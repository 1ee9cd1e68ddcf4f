"""A figure's uncertainty from re-measurement draws (GUM S1 style Monte Carlo on the measured data).

The figure is computed again on the measured inputs plus fresh instrument
noise; the spread of the draws about the measured value (their rms: the
spread and the noise's bias together) is its standard uncertainty ``u``;
``U = k u``; the interval is the draws reflected about the value (what the
truth could be, given this measurement).
"""

from __future__ import annotations

import math

import numpy as np

from station.analysis.uncertainty import FigureUncertainty

#: re-measurement draws per figure: u to about 7 %
DEFAULT_TRIALS = 100


def from_draws(name: str, subject: str, value: float, draws, *, k: float = 2.0, extra: dict | None = None,
               n: int = 0, seed: int = 0, note: str = "", draws2=None, extrapolate: str = "variance"
               ) -> FigureUncertainty:
    """``extra``: further standard uncertainties (name -> u, units of the figure) added in quadrature.

    ``draws2``: draws with twice the noise's variance added. Then the figure is one the noise pushes (a
    maximum, a range, a scatter): its value is taken back to no noise by extrapolating the mean figure
    quadratically in the added variance from 0, 1 and 2 times the instrument's to -1 times it
    (simulation-extrapolation: f(-1) = 3 f(0) - 3 f(1) + f(2)); with ``extrapolate="sd"`` (an extreme of
    many samples, pushed in proportion to the noise's sd) along the line through the sd's 1 and sqrt 2 to 0.
    u is the draws' spread with the whole correction added in quadrature as a standard uncertainty: the
    extrapolation's model is not checked, and with few cycles and noise near the scatter (RT of 5 cycles, noise
    16-20 um) half of it left 3 of 6 draws uncovered. The caller reads the corrected figure back from ``value``.
    """
    d = np.asarray(draws, dtype=float)
    d = d[np.isfinite(d)]
    extra = {key: float(v) for key, v in (extra or {}).items()}
    raw = float(value)
    if draws2 is not None and d.size:
        d2 = np.asarray(draws2, dtype=float)
        d2 = d2[np.isfinite(d2)]
        if extrapolate == "sd":  # a push in proportion to the noise's sd: the line through 1 and sqrt 2 to 0
            corrected = max(raw - (float(np.mean(d)) - raw) / (math.sqrt(2.0) - 1.0), 0.0)
        else:
            corrected = max(3.0 * raw - 3.0 * float(np.mean(d)) + float(np.mean(d2)), 0.0)
        extra["noise correction (all of it)"] = abs(raw - corrected)
        u_mc = float(np.std(d))
        value = corrected
        note = note or "corrected for the push of the tracker's noise (simulation-extrapolation)"
    else:
        u_mc = float(np.sqrt(np.mean((d - value) ** 2))) if d.size else 0.0
    u = math.sqrt(u_mc ** 2 + sum(v * v for v in extra.values()))
    lo, hi = (np.quantile(2 * raw - d, [0.025, 0.975]) + (value - raw) if d.size else (value, value))
    comp = {"instrument noise (Monte Carlo)": u_mc, **extra}
    return FigureUncertainty(name, subject, float(value), u, k * u, k, None, (float(lo), float(hi)), comp, int(n),
                             int(d.size), int(seed), note)


def from_u(name: str, subject: str, value: float, u_parts: dict, *, k: float = 2.0, n: int = 0,
           note: str = "") -> FigureUncertainty:
    """First-order uncertainty from independent parts (name -> u)."""
    u = math.sqrt(sum(float(v) ** 2 for v in u_parts.values()))
    return FigureUncertainty(name, subject, float(value), u, k * u, k, u, (value - k * u, value + k * u),
                             {key: float(v) for key, v in u_parts.items()}, int(n), 0, 0, note)
