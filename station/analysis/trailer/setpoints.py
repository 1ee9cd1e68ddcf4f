"""The curvature set points in force over the odometry's samples.

The trailer procedure streams curvature set points; the unit latches each at
its next control tick and acknowledges it with that tick's device time. The
samples' curvature is the average over the interval ending at their time
stamp, so the set points are averaged the same way (:func:`interval_average`)
before they serve as the instrument of the dynamic estimator
(:func:`station.analysis.trailer.estimate.estimate_dynamic`).

An acknowledgement lost on the line leaves its set point's tick unknown: it
took effect after the set point sent before it and no later than the next
acknowledged one. While the procedure streams set points every few ticks that
bracket is a tick or two; when the host is busy it sends fewer, and a bracket
of tens of seconds (seen: 76 s at a 200x pace beside other work) put a wrong
set point over hundreds of samples, so that the command no longer explained
the measured curvature and the estimator fell back to it.
:func:`place_unacknowledged` puts each such set point at the tick inside its
bracket where the measured curvature says the change happened (least
squares), so the bracket's width no longer matters.
"""

from __future__ import annotations

import numpy as np

__all__ = ["interval_average", "place_unacknowledged"]

#: relative difference of two sums of squares below which they are a tie (the rounding of the averages)
TIE = 1e-9


def interval_average(t_s, t_change, values, fallback) -> np.ndarray:
    """Average over each sample interval ``(t_{k-1}, t_k]`` of the piecewise-constant
    set point that takes ``values[j]`` from ``t_change[j]`` on (sorted).

    Before the first change, and for the first sample, ``fallback`` (the set
    point the procedure had in force when it took the sample) is used.
    Shapes: ``t_s`` (N,), ``t_change``/``values`` (M,) -> (N,).
    """
    t = np.asarray(t_s, dtype=float)
    fb = np.asarray(fallback, dtype=float)
    if t.size == 0 or len(t_change) == 0:
        return fb.copy()
    tc = np.asarray(t_change, dtype=float)
    vc = np.asarray(values, dtype=float)
    # cumulative integral of the set point at each change time
    F_knots = np.concatenate([[0.0], np.cumsum(vc[:-1] * np.diff(tc))])
    j = np.searchsorted(tc, t, side="right") - 1
    inside = j >= 0
    jj = np.clip(j, 0, None)
    F = np.where(inside, F_knots[jj] + vc[jj] * (t - tc[jj]), np.nan)
    out = fb.copy()
    ok = inside[1:] & inside[:-1] & (np.diff(t) > 0)
    out[1:][ok] = (F[1:][ok] - F[:-1][ok]) / np.diff(t)[ok]
    return out


def place_unacknowledged(t_s, kappa_1_m, fallback, t_change, values, acknowledged, t_earliest=None) -> np.ndarray:
    """Change times (M,) with the unacknowledged set points moved to the sample ticks of their brackets
    that best explain the measured curvature.

    Parameters
    ----------
    t_s, kappa_1_m, fallback : array_like, shape (N,)
        The samples' device times (increasing), measured curvature (1/m) and the set point the procedure
        had in force at each (as :func:`interval_average`'s ``fallback``).
    t_change : array_like, shape (M,)
        Change times in send order (non-decreasing): acknowledged ones exact, the others at the upper end
        of their bracket (the next acknowledged time, or the intended tick after the last one).
    values : array_like, shape (M,)
        The set points (1/m).
    acknowledged : array_like of bool, shape (M,)
    t_earliest : array_like, shape (M,), optional
        The earliest tick each set point can have taken effect: the tick after the newest sample the
        procedure had read when it sent it (the unit was at least there). Under load the unit runs ahead
        of what the procedure has read, so this is a lower bound, never the tick itself.

    A run of consecutive unacknowledged set points took effect, in order, after the acknowledged one before
    them, each no earlier than its earliest tick and no later than its bound. The unit latches at its ticks, so a set point changes the
    command of the sample intervals that begin at or after its tick. The run's ticks are chosen together,
    by dynamic programming over the samples of the bracket, to minimise the squared difference between the
    measured curvature and the command (ties keep the later tick, the bound the order of sending gives).
    """
    t = np.asarray(t_s, dtype=float)
    k = np.asarray(kappa_1_m, dtype=float)
    fb = np.asarray(fallback, dtype=float)
    tc = np.array(t_change, dtype=float)
    vc = np.asarray(values, dtype=float)
    ack = np.asarray(acknowledged, dtype=bool)
    early = np.full(tc.size, -np.inf) if t_earliest is None else np.nan_to_num(
        np.asarray(t_earliest, dtype=float), nan=-np.inf)
    if tc.size == 0 or t.size < 2:
        return tc
    lost = np.flatnonzero(~ack)
    runs = np.split(lost, np.flatnonzero(np.diff(lost) > 1) + 1) if lost.size else []
    for run in runs:
        i0, i1 = int(run[0]), int(run[-1])
        lo = tc[i0 - 1] if i0 > 0 else -np.inf
        bounds = tc[i0:i1 + 1]
        if not np.all(np.isfinite(bounds)):
            continue
        # sample k's interval (t[k-1], t[k]] takes the set point in force at t[k-1]: the window is the
        # samples whose interval starts after lo and no later than the last bound
        # (and before the set point after the run: from its tick on, it is in force)
        after = tc[i1 + 1] if i1 + 1 < tc.size else np.inf
        ks = np.flatnonzero((t[:-1] > lo) & (t[:-1] <= bounds[-1]) & (t[:-1] < after)) + 1
        if ks.size == 0:
            continue
        keep = np.ones(tc.size, bool)
        keep[i0:i1 + 1] = False
        base = interval_average(t, tc[keep], vc[keep], fb)[ks]  # the command without the run
        m = i1 - i0 + 1
        vals = [base] + [np.full(ks.size, vc[i0 + j]) for j in range(m)]
        cost = np.stack([(k[ks] - v) ** 2 for v in vals])  # (m + 1, n): segment j in force at sample ks[n]
        start = t[ks - 1]  # the tick each sample's interval starts at
        # segment j may begin at a sample's start tick after lo; it must have begun once that tick passes
        # set point j's bound (set point j took effect no later than its bound)
        must = np.array([np.searchsorted(start, b, side="left") for b in bounds])  # first sample at or beyond
        # and segment j cannot be in force at a sample whose interval starts before set point j's earliest tick
        soon = np.array([np.searchsorted(start, e, side="left") for e in early[i0:i1 + 1]])
        n = ks.size
        dp = np.full((m + 1, n), np.inf)
        arg = np.zeros((m + 1, n), dtype=np.int64)
        dp[0, 0] = cost[0, 0]
        dp[1:, 0] = cost[1:, 0]  # segment j at the first sample: set points 1..j all at its start tick
        for j in range(m):
            if must[j] <= 0:
                dp[:j + 1, 0] = np.inf
            if soon[j] > 0:
                dp[j + 1:, 0] = np.inf
        for s in range(1, n):
            prev = dp[:, s - 1]
            for j in range(m + 1):
                # come from segment jj <= j: set points jj+1..j all change at this sample's start tick
                # (a tie begins segment j as late as it can: the latest tick for the set points)
                best, bj = prev[j], j
                for jj in range(j - 1, -1, -1):
                    if prev[jj] <= best + TIE * abs(best):
                        best, bj = prev[jj], jj
                dp[j, s] = best + cost[j, s]
                arg[j, s] = bj
            for j in range(m):  # beyond set point j+1's bound, segments before it are impossible; before its
                if s >= must[j]:  # earliest tick, it and the segments after it
                    dp[:j + 1, s] = np.inf
                if s < soon[j]:
                    dp[j + 1:, s] = np.inf
        # the last sample is in segment m if its start tick passed every bound; else the best segment
        last = dp[:, n - 1]
        if not np.isfinite(last.min()):
            continue  # bounds that contradict each other: the times as given
        j = int(np.flatnonzero(last <= last.min() + TIE * abs(last.min()))[0])
        first = np.full(m + 1, n, dtype=np.int64)  # first sample of each segment (n: after the window)
        for s in range(n - 1, 0, -1):
            first[j] = s
            j = int(arg[j, s])
        first[j] = 0  # segments 1..j-1 skipped before the first sample began with j there (below)
        # segments that never began in the window keep their bound; a set point begins at its segment's
        # first sample's start tick, or with the next segment that did begin (the same tick)
        placed = bounds.copy()
        nxt = n
        for j in range(m, 0, -1):
            if first[j] < n and first[j] <= nxt:
                nxt = first[j]
            if nxt < n:
                placed[j - 1] = min(start[nxt], bounds[j - 1])
        tc[i0:i1 + 1] = np.maximum.accumulate(placed)
    return tc
