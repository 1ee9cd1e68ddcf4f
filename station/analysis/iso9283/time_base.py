"""Whether a stream's time stamps can be its time base, and the sample index as the alternative.

Every time-based ISO 9283 figure (PST, eq. (6); MPT, eq. (10); drift) and the
moving horizons of eq. (4) rest on the time stamps. Stamps written by a logger
with a coarse clock (1 s resolution at 100 Hz), or stamps that run against the
samples, give wrong times silently. :func:`check_time_stamps` finds:

* stamps that go backwards;
* stamps that repeat: their resolution is coarser than the sample spacing;
* stamps whose median step disagrees with the sample count: ``n`` samples
  (plus the samples lost in the gaps the stamps show) over the time span give
  another spacing than the steps themselves; or so many gaps (more than
  :data:`MAX_GAP_FRACTION` of the steps) that the stamps come in bursts (a
  logger stamping packets on receipt) rather than at the sample rate.

The remedy is the sample rate (:func:`sample_index_time`): the sample index
divided by the rate becomes the time base, and the figures say so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.errors import DataError

#: the median step and the spacing the sample count gives may differ by this fraction
COUNT_TOLERANCE = 0.1
#: a step longer than this many median steps is a gap with lost samples
GAP_FACTOR = 1.5
#: more gaps than this fraction of the steps is not a stream with a few beam breaks but stamps in bursts
MAX_GAP_FRACTION = 0.05


@dataclass(frozen=True)
class TimeProblem:
    """One reason the stamps cannot be the time base; ``row`` the first row it shows at (None: the whole stream)."""

    row: int | None
    text: str


@dataclass(frozen=True)
class TimeStampCheck:
    """What the stamps say about themselves (s) and every problem found (empty: usable)."""

    n: int
    span_s: float
    median_step_s: float
    resolution_s: float
    count_spacing_s: float
    n_repeats: int
    n_backwards: int
    n_lost: int
    problems: tuple[TimeProblem, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


def _g(x: float) -> str:
    return f"{float(x):.6g}"


def check_time_stamps(t_s) -> TimeStampCheck:
    """Check stamps ``t_s`` (N,), s, of the samples in file order (rows flagged invalid included).

    Returns
    -------
    TimeStampCheck
        ``problems`` empty when the stamps can be the time base.
    """
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise DataError(f"t_s must be 1-D with at least 2 stamps, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        i = int(np.argmax(~np.isfinite(t)))
        raise DataError(f"t_s is not finite at row {i}")
    n = t.size
    dt = np.diff(t)
    back = np.flatnonzero(dt < 0)
    rep = np.flatnonzero(dt == 0)
    pos = dt[dt > 0]
    span = float(t.max() - t.min())
    med = float(np.median(pos)) if pos.size else 0.0
    res = float(pos.min()) if pos.size else 0.0
    problems = []
    if back.size:
        i = int(back[0]) + 1
        problems.append(TimeProblem(i, f"time goes back: {_g(t[i])} s after {_g(t[i - 1])} s on the row before "
                                       f"({back.size} time(s) in the stream)"))
    if rep.size:
        i = int(rep[0]) + 1
        problems.append(TimeProblem(
            i, f"{_g(t[i])} s repeats the time of the row before ({rep.size} repeated stamp(s) in {n} rows): the "
               f"stamps' resolution (smallest step {_g(res)} s) is coarser than the sample spacing "
               f"({_g(span / (n - 1))} s = span / samples)" if rep.size > 1 else
            f"{_g(t[i])} s repeats the time of the row before"))
    lost = 0
    count_spacing = span / (n - 1)
    if med > 0 and not back.size:
        big = pos[pos > GAP_FACTOR * med]
        lost = int(np.sum(np.maximum(np.rint(big / med) - 1, 0)))
        count_spacing = span / (n - 1 + lost)
        if not rep.size and big.size > MAX_GAP_FRACTION * dt.size:
            problems.append(TimeProblem(
                None, f"{big.size} of {dt.size} steps are longer than {GAP_FACTOR:g} x the median step "
                      f"{_g(med)} s: the stamps come in bursts, not at the sample rate (the sample count gives "
                      f"{_g(span / (n - 1))} s per sample over {_g(span)} s)"))
        elif not rep.size and abs(count_spacing / med - 1.0) > COUNT_TOLERANCE:
            problems.append(TimeProblem(
                None, f"the stamps' median step {_g(med)} s disagrees with the sample count: {n} samples"
                      + (f" and {lost} lost in gaps" if lost else "") + f" over {_g(span)} s give "
                      f"{_g(count_spacing)} s per sample"))
    return TimeStampCheck(n=n, span_s=span, median_step_s=med, resolution_s=res, count_spacing_s=float(count_spacing),
                          n_repeats=int(rep.size), n_backwards=int(back.size), n_lost=lost, problems=tuple(problems))


def sample_index_time(n: int, rate_hz: float) -> np.ndarray:
    """``t = i / rate_hz`` for the samples ``i = 0 .. n-1``, s (the sample index as the time base)."""
    if not (isinstance(rate_hz, (int, float, np.floating)) and np.isfinite(rate_hz) and rate_hz > 0):
        raise DataError(f"rate_hz must be a finite number > 0, got {rate_hz!r}")
    if n < 1:
        raise DataError(f"need at least 1 sample, got {n}")
    return np.arange(int(n), dtype=float) / float(rate_hz)
