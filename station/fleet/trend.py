"""Trend test for the fleet: does a characteristic grow with time, robot by robot?

Pure: arrays in, arrays out. For each robot (a group label per run), the
least-squares slope of the value against time,

    b = sum((t - tbar)(y - ybar)) / sum((t - tbar)^2),
    se(b) = sqrt( sum(r^2) / (n - 2) / sum((t - tbar)^2) ),   r = y - ybar - b (t - tbar),

and the one-sided p-value of ``t = b / se(b)`` under Student's t with
``n - 2`` degrees of freedom (H0: no increase). A fleet tests hundreds of
robots at once, so a threshold on p alone flags ``alpha`` of the healthy
ones; :func:`benjamini_hochberg` turns the p-values into q-values that keep
the expected share of false flags among the flagged at or under ``q``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from station.errors import DataError


@dataclass(frozen=True)
class Trends:
    """Per group (``groups`` sorted): runs ``n``, ``slope`` (value unit per time unit), its ``se``, one-sided ``p``."""

    groups: np.ndarray
    n: np.ndarray
    slope: np.ndarray
    se: np.ndarray
    p: np.ndarray


def trends(group: np.ndarray, t: np.ndarray, y: np.ndarray) -> Trends:
    """Slope and one-sided p of ``y`` against ``t`` per group, vectorised over all groups.

    Groups with fewer than 3 runs or no spread in time get NaN slope and p = 1.
    """
    group, t, y = np.asarray(group), np.asarray(t, float), np.asarray(y, float)
    if not (group.shape == t.shape == y.shape) or group.ndim != 1:
        raise DataError(f"group, t and y must be 1-D of one length, got {group.shape}, {t.shape}, {y.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise DataError("t and y must be finite (leave out runs without a value)")
    labels, g = np.unique(group, return_inverse=True)
    k = labels.size
    n = np.bincount(g, minlength=k).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        tbar = np.bincount(g, t, k) / n
        ybar = np.bincount(g, y, k) / n
        dt, dy = t - tbar[g], y - ybar[g]
        stt = np.bincount(g, dt * dt, k)
        sty = np.bincount(g, dt * dy, k)
        slope = sty / stt
        resid = dy - slope[g] * dt
        dof = n - 2
        se = np.sqrt(np.bincount(g, resid * resid, k) / dof / stt)
        tstat = slope / se
    ok = (n >= 3) & (stt > 0)
    p = np.ones(k)
    # no scatter about the line: certain where it rises, no evidence of a rise where it does not
    exact = np.where(slope[ok] > 0, np.inf, -np.inf)
    p[ok] = stats.t.sf(np.where(se[ok] > 0, tstat[ok], exact), dof[ok])
    p = np.nan_to_num(p, nan=1.0)
    slope = np.where(ok, slope, np.nan)
    se = np.where(ok, se, np.nan)
    return Trends(labels, n.astype(int), slope, se, p)


def benjamini_hochberg(p: np.ndarray) -> np.ndarray:
    """q-values of the Benjamini-Hochberg step-up procedure (false discovery rate)."""
    p = np.asarray(p, float)
    if p.ndim != 1 or np.any((p < 0) | (p > 1)):
        raise DataError("p must be a 1-D array of probabilities")
    m = p.size
    if m == 0:
        return p.copy()
    order = np.argsort(p)
    scaled = p[order] * m / np.arange(1, m + 1)
    q_sorted = np.minimum.accumulate(scaled[::-1])[::-1]
    q = np.empty(m)
    q[order] = np.minimum(q_sorted, 1.0)
    return q
