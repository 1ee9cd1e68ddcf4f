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

import math
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


#: a whole-stamp interval whose rate departs from the estimate by more than this fraction (and more than
#: the one sample a stamp boundary can shift) is reported as a place where the rate varies
RATE_VARIES_FRACTION = 0.02


@dataclass(frozen=True)
class RateEstimate:
    """The sample rate read from coarse stamps: samples per stamp interval between stamp changes.

    ``rate_hz`` is the samples of every whole interval over their seconds;
    ``spread_hz`` the standard deviation of the intervals' own rates;
    ``per_interval_hz`` (K,) those rates, ``first_row`` (K,) the row each
    interval starts at; ``varies`` the intervals (indices into them) whose rate
    departs from ``rate_hz`` beyond what a stamp boundary explains.
    """

    rate_hz: float
    spread_hz: float
    resolution_s: float
    n_intervals: int
    per_interval_hz: np.ndarray
    first_row: np.ndarray
    varies: np.ndarray
    #: seconds the whole intervals span (the rate is good to about one sample over it)
    span_s: float = math.nan

    def to_dict(self) -> dict:
        return {"rate_hz": float(self.rate_hz), "spread_hz": float(self.spread_hz),
                "stamp_resolution_s": float(self.resolution_s), "n_intervals": int(self.n_intervals),
                "min_hz": float(self.per_interval_hz.min()), "max_hz": float(self.per_interval_hz.max()),
                "n_varying": int(self.varies.size), "span_s": float(self.span_s)}


def estimate_rate_from_stamps(t_s) -> RateEstimate:
    """Estimate the sample rate of a stream whose stamps repeat (a clock coarser than the sampling).

    The stamps change at rows ``c_0 < c_1 < ...``; the samples from ``c_k`` up
    to ``c_{k+1}`` were taken while the clock read ``t[c_k]``, so interval
    ``k`` holds ``c_{k+1} - c_k`` samples over ``t[c_{k+1}] - t[c_k]`` seconds.
    The first and the last run of equal stamps are partial (the stream starts
    and ends within a second) and are not used. Needs stamps in order and at
    least one whole interval; DataError otherwise.
    """
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < 3 or not np.all(np.isfinite(t)):
        raise DataError("estimating the rate needs at least 3 finite stamps")
    dt = np.diff(t)
    if np.any(dt < 0):
        i = int(np.argmax(dt < 0)) + 1
        raise DataError(f"row {i}: the stamps go back; no rate can be read from them")
    change = np.flatnonzero(dt > 0) + 1  # rows where a new stamp starts
    if change.size < 2:
        raise DataError(f"the stamps change {change.size} time(s): no whole stamp interval to count samples in")
    counts = np.diff(change).astype(float)
    secs = t[change[1:]] - t[change[:-1]]
    res = float(np.min(secs))
    rates = counts / secs
    rate = float(counts.sum() / secs.sum())
    spread = float(np.std(rates, ddof=1)) if rates.size > 1 else 0.0
    expect = rate * secs
    varies = np.flatnonzero(np.abs(counts - expect) > np.maximum(1.0 + 1e-9, RATE_VARIES_FRACTION * expect))
    return RateEstimate(rate_hz=rate, spread_hz=spread, resolution_s=res, n_intervals=int(counts.size),
                        per_interval_hz=rates, first_row=change[:-1].astype(np.int64), varies=varies,
                        span_s=float(secs.sum()))
