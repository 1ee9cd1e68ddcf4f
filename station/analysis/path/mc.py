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

#: re-measurement draws per figure: u to about 5 %
DEFAULT_TRIALS = 200


def from_draws(name: str, subject: str, value: float, draws, *, k: float = 2.0, extra: dict | None = None,
               n: int = 0, seed: int = 0, note: str = "", debias: bool = False) -> FigureUncertainty:
    """``extra``: further standard uncertainties (name -> u, units of the figure) added in quadrature.

    ``debias``: the figure is an extreme (a max or a range) that the noise pushes out in proportion to its
    sd: the draws (noise sd x sqrt 2) are pushed out by (sqrt 2 - 1) times the measurement's push, which is
    taken off the value (its uncertainty, half of it, is added in quadrature). The figure has to be given
    back by the caller from the result's ``value``.
    """
    d = np.asarray(draws, dtype=float)
    d = d[np.isfinite(d)]
    if debias and d.size:
        push = (float(np.mean(d)) - value) / (np.sqrt(2.0) - 1.0)
        value = max(value - push, 0.0)
        d = d - push * np.sqrt(2.0)
        extra = {**(extra or {}), "noise correction (half of it)": 0.5 * abs(push)}
    u_mc = float(np.sqrt(np.mean((d - value) ** 2))) if d.size else 0.0
    extra = {key: float(v) for key, v in (extra or {}).items()}
    u = math.sqrt(u_mc ** 2 + sum(v * v for v in extra.values()))
    lo, hi = (np.quantile(2 * value - d, [0.025, 0.975]) if d.size else (value, value))
    comp = {"instrument noise (Monte Carlo)": u_mc, **extra}
    return FigureUncertainty(name, subject, float(value), u, k * u, k, None, (float(lo), float(hi)), comp, int(n),
                             int(d.size), int(seed), note)


def from_u(name: str, subject: str, value: float, u_parts: dict, *, k: float = 2.0, n: int = 0,
           note: str = "") -> FigureUncertainty:
    """First-order uncertainty from independent parts (name -> u)."""
    u = math.sqrt(sum(float(v) ** 2 for v in u_parts.values()))
    return FigureUncertainty(name, subject, float(value), u, k * u, k, u, (value - k * u, value + k * u),
                             {key: float(v) for key, v in u_parts.items()}, int(n), 0, 0, note)
