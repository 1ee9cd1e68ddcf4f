"""Attained poses from a continuous tracker stream (seed 000, section 3.1.3).

The robot runs the ISO 9283 cycle with a short dwell at every commanded pose
while the tracker streams the tool point (``t, x, y, z``, 10-3000 Hz, with
holes where the beam broke).  This module finds, in that stream, one attained
pose per stop and assigns it to its commanded pose and cycle, as the seed does:

1. velocity from successive samples, eq. (3):
   ``v(i) = |p(i) - p(i-1)| / (t(i) - t(i-1))``.  On streams faster than the
   seed's 100 Hz the difference is taken over the seed's sampling interval
   (``lag = round(0.01 s * rate)`` samples; ``velocity_step_s=0`` keeps
   successive samples): at 1 kHz the successive-sample velocity is mostly
   measurement noise (sqrt(2) sigma / dt ~ 20 mm/s) and hides the last of the
   settling, which would make the attained pose depend on the tracker's rate;
2. a moving average of the velocity splits the stream into acceleration
   phases and deceleration phases (seed Figs. 3-4).  We average the velocity
   *vector* with time weights over ``2h+1`` samples, which telescopes to
   ``|p(i+h) - p(i-h)| / (t(i+h) - t(i-h))``: at rest it has no noise floor
   (the mean of ``|v|`` would), so one threshold ``v_rest`` separates motion
   from rest at any sampling rate.  A deceleration phase runs from the speed
   peak of a move to the start of the next move;
3. moving horizons ``M_j`` of ``2M+1`` samples centred on ``j = Mp, 2Mp, ...``
   (eq. (4)); in each deceleration phase the horizon with the least sum of
   ``v`` over its ``2M+1`` samples is the least-velocity window, and its centre
   sample ``p(j)`` is the attained pose.  Taking the centre of the quietest
   window, not the single slowest sample, avoids picking the best point and so
   flattering the repeatability (seed 3.1.3).  The attained pose must be a
   sample at rest (moving average below ``v_rest``).  The horizon is sought in
   the phase's *final* rest (after the last sample of the phase's move; a stir
   too small to be a move does not end it) when that rest holds one (the
   horizon's centre in it): a pause on the way shorter than the dwell that separates moves
   (a vAP pre-point held 0.2 s, smoothed to less than ``min_dwell_s``) joins
   the next move, and in a phase holding two rests the quietest window would
   otherwise fall in either one by the noise alone.

Beam breaks are handled explicitly: a step in time longer than
``break_factor`` sampling intervals splits the stream; no velocity and no
window spans it, and the moving average near it is one-sided.  Every gap is
reported.  A deceleration phase with a beam break inside (or whose
least-velocity horizon is not at rest) is split at the breaks: each piece of
its rest gets the largest horizon ``M' <= M`` that fits (down to ``2*1+1``
samples) and the pieces compete on mean velocity per sample (the seed's least
sum when the sizes are equal); the stop then carries ``fallback`` (and
``window_M < M`` if smaller).  A phase with no valid horizon at rest is
reported as a failed phase, never filled in.

Stops are assigned to the nearest commanded pose within ``assign_tol_mm`` and
then walked through the commanded order: a pose skipped in the order is a
*missing* stop (with the reason: beam break, failed phase, or no stop); a stop
far from every pose is *unassigned* (e.g. the start points of multi-direction
approaches); a stop near a pose but inconsistent with the order and the
elapsed time is *out of sequence*.  Nothing is silently shifted.

All functions are pure: arrays in, frozen dataclasses out.  Sample indices in
the results are rows of the stream as given (0-based, header excluded).
"""

from __future__ import annotations

from enum import IntEnum

from dataclasses import dataclass, field

import numpy as np

from station.errors import DataError, InsufficientDataError
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

#: stop status codes (``Stops.status``)
class StopStatus(IntEnum):
    """What became of a detected stop."""

    ASSIGNED = 0
    UNASSIGNED = 1  # farther than assign_tol_mm from every commanded pose
    OUT_OF_SEQUENCE = 2  # near a pose, but not where the commanded order allows
    NOT_IN_ORDER = 3  # near a pose that the commanded order never visits
    INITIAL_REST = 4  # the rest before the first move, not a stop of the commanded order


STATUS_ASSIGNED = StopStatus.ASSIGNED
STATUS_UNASSIGNED = StopStatus.UNASSIGNED
STATUS_OUT_OF_SEQUENCE = StopStatus.OUT_OF_SEQUENCE
STATUS_NOT_IN_ORDER = StopStatus.NOT_IN_ORDER
STATUS_INITIAL_REST = StopStatus.INITIAL_REST
STATUS_NAMES = tuple(s.name.lower() for s in StopStatus)

#: accepted sampling rates, Hz (with a little slack for clock jitter)
RATE_RANGE_HZ = TRACKER_RATE_RANGE_HZ
#: the assignment tolerance is at least this many times the tracker's noise
ASSIGN_NOISE_FACTOR = 20.0


@dataclass(frozen=True)
class ExtractionParams:
    """The numbers the extraction ran with (all derived ones included).

    Attributes
    ----------
    rate_hz : float
        Sampling rate from the median sampling interval.
    median_dt_s : float
        Median sampling interval, s.
    lag : int
        Velocity of eq. (3) taken between samples ``lag`` apart (1 = successive
        samples; more on streams faster than the seed's 100 Hz, see
        ``velocity_step_s``).
    M : int
        Horizon half size, samples (window = 2M+1 samples), eq. (4).
    Mp : int
        Horizon step, samples, eq. (4).
    h : int
        Half width of the moving average that splits the phases, samples.
    noise_mm : float
        Per-axis position noise estimated from second differences, mm.
    v_rest_mm_s : float
        Moving-average speed below which the tool is at rest, mm/s.
    gap_factor : float
        A step longer than ``gap_factor`` sampling intervals is a reported gap.
    break_s : float
        A step longer than this splits the stream (beam break), s.
    min_move_mm : float
        A move shorter than this (net) is not a move.
    min_dwell_s : float
        A rest shorter than this is not a stop.
    assign_tol_mm : float
        Largest distance from a stop to its commanded pose, mm.
    """

    rate_hz: float
    median_dt_s: float
    lag: int
    M: int
    Mp: int
    h: int
    noise_mm: float
    v_rest_mm_s: float
    gap_factor: float
    break_s: float
    min_move_mm: float
    min_dwell_s: float
    assign_tol_mm: float


@dataclass(frozen=True)
class Gaps:
    """Holes in the stream (lost samples, beam breaks), shape (G,) each.

    ``row_before``/``row_after`` are the stream rows either side of the hole;
    ``splits`` marks the holes longer than ``break_s`` (no window spans them).
    """

    row_before: np.ndarray
    row_after: np.ndarray
    t_start_s: np.ndarray
    t_end_s: np.ndarray
    lost_samples: np.ndarray
    splits: np.ndarray

    @property
    def n(self) -> int:
        return int(self.row_before.size)

    @property
    def duration_s(self) -> np.ndarray:
        return self.t_end_s - self.t_start_s


@dataclass(frozen=True)
class Stops:
    """One entry per deceleration phase that gave an attained pose, shape (K,).

    Index attributes starting with ``i_`` index the *used* samples (the stream
    without the rows flagged invalid); ``row`` is the stream row of the
    attained pose.

    Attributes
    ----------
    row : ndarray of int, (K,)
        Stream row of the attained pose (centre of the least-velocity window).
    i_center, i_window_first, i_window_last : ndarray of int, (K,)
        Used-sample indices of the window centre and its first/last sample.
    i_phase_start, i_phase_end : ndarray of int, (K,)
        Deceleration phase: from the speed peak of the move to the sample
        before the next move.
    i_move_start : ndarray of int, (K,)
        First sample of the move that ends in this stop.
    t_s : ndarray, (K,)
        Time of the attained pose, s.
    position_mm : ndarray, (K, 3)
        Attained position, mm.
    window_sum_mm_s : ndarray, (K,)
        Sum of the 2M+1 velocities in the chosen window, mm/s.
    window_M : ndarray of int, (K,)
        Horizon half size actually used (``< M`` only after a fallback).
    fallback : ndarray of bool, (K,)
        The phase had a beam break inside, or its least-velocity horizon was
        not at rest: the horizon was taken inside the rest, piece by piece
        between breaks, with the largest ``window_M <= M`` that fits, the
        pieces compared by mean velocity per sample.
    approach_unit : ndarray, (K, 3)
        Unit vector of the final approach: from the last sample of the move
        that is at least ``approach_final_mm`` from the attained pose (the
        start of the move when it is shorter) to the attained pose. A robot
        passing a pre-point without dwelling (ISO 9283 multi-directional
        approaches) merges two moves into one deceleration phase; the final
        stretch still gives the direction it came in along.
    approach_mm : ndarray, (K,)
        Length of that move, mm.
    gap_in_approach : ndarray of bool, (K,)
        A beam break lies between the start of the move and the attained pose.
    pose : ndarray of int, (K,)
        Index of the commanded pose, -1 if none.
    cycle : ndarray of int, (K,)
        Cycle number (0-based, counted from the first moved stop), -1 if none;
        -1 also for the rest before the first move when it counts and the
        first moved stop opens a cycle (the rest ends the cycle before).
    seq : ndarray of int, (K,)
        Position in the unrolled commanded order (cycle * L + k), -1 if none
        (and for the counted rest before a cycle's first stop).
    distance_to_pose_mm : ndarray, (K,)
        Distance to the nearest commanded pose, mm.
    nearest_pose : ndarray of int, (K,)
        Index of the nearest commanded pose (even when unassigned).
    status : ndarray of int, (K,)
        One of the ``STATUS_*`` codes.
    initial : ndarray of bool, (K,)
        The stop is the rest before the first move (only the first stop can
        be): it has no move into it (``i_move_start`` = its phase start,
        ``approach_unit`` zero). It counts as a stop of the pose it stands at
        when the commanded order puts that pose right before the first moved
        stop; otherwise its status is ``INITIAL_REST``.
    """

    row: np.ndarray
    i_center: np.ndarray
    i_window_first: np.ndarray
    i_window_last: np.ndarray
    i_phase_start: np.ndarray
    i_phase_end: np.ndarray
    i_move_start: np.ndarray
    t_s: np.ndarray
    position_mm: np.ndarray
    window_sum_mm_s: np.ndarray
    window_M: np.ndarray
    fallback: np.ndarray
    approach_unit: np.ndarray
    approach_mm: np.ndarray
    gap_in_approach: np.ndarray
    pose: np.ndarray
    cycle: np.ndarray
    seq: np.ndarray
    distance_to_pose_mm: np.ndarray
    nearest_pose: np.ndarray
    status: np.ndarray
    initial: np.ndarray

    @property
    def n(self) -> int:
        return int(self.row.size)


@dataclass(frozen=True)
class MissingStop:
    """A commanded pose of the order with no attained pose in its cycle."""

    cycle: int
    pose: str
    seq: int
    reason: str
    t_after_s: float  # time of the last attained pose before the hole
    t_before_s: float  # time of the first attained pose after it


@dataclass(frozen=True)
class FailedPhase:
    """A deceleration phase in which no least-velocity window could be taken."""

    i_phase_start: int
    i_phase_end: int
    row_start: int
    row_end: int
    t_start_s: float
    t_end_s: float
    reason: str


@dataclass(frozen=True)
class Extraction:
    """Attained poses of a stream, with everything that went wrong reported.

    Attributes
    ----------
    params : ExtractionParams
    names : tuple of str
        Commanded pose names, shape (P,).
    commanded_mm : ndarray, (P, 3)
    order : tuple of int
        Commanded order of one cycle as pose indices (length L).
    n_rows : int
        Rows in the stream as given.
    n_used : int
        Rows used (``valid`` true).
    rows_used : ndarray of int or None
        Stream row of every used sample, None when all rows were used.
    gaps : Gaps
    stops : Stops
    missing : tuple of MissingStop
    failed_phases : tuple of FailedPhase
    moves_i : ndarray of int, (R, 3)
        Every move found: used-sample indices of start, speed peak, end.
    initial_rest_i : tuple of int or None
        Rest before the first move (used-sample index range); its
        least-velocity horizon is the first stop when one fits
        (``stops.initial``).
    trailing_motion : bool
        The stream ends while the tool moves (last move has no stop).
    n_cycles : int
        Cycles touched from the first to the last assigned stop.
    """

    params: ExtractionParams
    names: tuple[str, ...]
    commanded_mm: np.ndarray
    order: tuple[int, ...]
    n_rows: int
    n_used: int
    rows_used: np.ndarray | None
    gaps: Gaps
    stops: Stops
    missing: tuple[MissingStop, ...]
    failed_phases: tuple[FailedPhase, ...]
    moves_i: np.ndarray
    initial_rest_i: tuple[int, int] | None
    trailing_motion: bool
    n_cycles: int
    warnings: tuple[str, ...] = field(default=())

    def to_rows(self, i) -> np.ndarray:
        """Used-sample indices -> stream rows."""
        i = np.asarray(i, dtype=np.int64)
        return i.copy() if self.rows_used is None else self.rows_used[i]

    def assigned(self, pose: int) -> np.ndarray:
        """Indices into ``stops`` of the assigned stops of one pose, in time order."""
        s = self.stops
        return np.flatnonzero((s.pose == pose) & (s.status == STATUS_ASSIGNED))


# --------------------------------------------------------------------------
# input validation
# --------------------------------------------------------------------------


def validate_stream(t_s, xyz_mm, valid=None, *, extra=None):
    """Check a stream and drop the rows flagged invalid.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Device timestamps, s; strictly increasing over the valid rows.
    xyz_mm : array_like, shape (N, 3)
        Positions, mm.  NaN is allowed only in rows flagged invalid.
    valid : array_like of bool, shape (N,), optional
        False for rows the instrument flagged (beam broken, not ready).
    extra : dict of str -> array_like, shape (N, k), optional
        Further per-row arrays (e.g. orientation) checked and compressed the
        same way.

    Returns
    -------
    t : ndarray (n,), xyz : ndarray (n, 3) (column-major), rows_used :
    ndarray (n,) or None (all rows used), extra : dict of compressed arrays

    Raises
    ------
    DataError
        Wrong shapes, NaN/inf in a valid row (naming row and column), time
        not strictly increasing (naming the rows), duplicate timestamps.
    """
    t = np.asarray(t_s, dtype=float)
    xyz = np.asarray(xyz_mm, dtype=float)
    if t.ndim != 1:
        raise DataError(f"t_s must be 1-D (N,), got shape {t.shape}")
    if xyz.shape != (t.size, 3):
        raise DataError(f"xyz_mm must have shape (N, 3) = ({t.size}, 3), got {xyz.shape}")
    extra = {k: np.asarray(v, dtype=float) for k, v in (extra or {}).items()}
    for k, v in extra.items():
        if v.shape[:1] != (t.size,):
            raise DataError(f"{k} must have {t.size} rows like t_s, got shape {v.shape}")
    rows_used = None
    if valid is not None:
        valid = np.asarray(valid)
        if valid.shape != t.shape or valid.dtype != bool:
            raise DataError(f"valid must be a bool array of shape {t.shape}, got {valid.dtype} {valid.shape}")
        if not valid.all():
            rows_used = np.flatnonzero(valid)
            t = t[rows_used]
            xyz = xyz[rows_used]
            extra = {k: v[rows_used] for k, v in extra.items()}

    def row(i):
        return int(i) if rows_used is None else int(rows_used[i])

    if t.size == 0:
        raise InsufficientDataError("the stream has no valid samples")
    # column-major: every per-axis operation here and below runs on contiguous memory
    xyz = np.asfortranarray(xyz)
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"t_s is not finite at row {row(i)} ({float(t[i])})")
    for k, name in enumerate("xyz"):
        bad = ~np.isfinite(xyz[:, k])
        if bad.any():
            i = int(np.argmax(bad))
            raise DataError(
                f"xyz_mm column {name} is not finite at row {row(i)} ({float(xyz[i, k])}); "
                f"flag such rows invalid (status) instead of writing NaN"
            )
    for key, v in extra.items():
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.argwhere(bad)[0][0])
            raise DataError(f"{key} is not finite at row {row(i)}")
    nonpos = t[1:] <= t[:-1]
    if nonpos.any():
        dt = np.diff(t)
        i = int(np.argmax(nonpos))
        if dt[i] == 0:
            raise DataError(f"t_s has duplicate timestamps at rows {row(i)} and {row(i + 1)} (t = {float(t[i])} s)")
        raise DataError(
            f"t_s is not sorted: row {row(i + 1)} (t = {float(t[i + 1])} s) comes after row {row(i)} "
            f"(t = {float(t[i])} s)"
        )
    return t, xyz, rows_used, extra


# --------------------------------------------------------------------------
# building blocks (vectorised)
# --------------------------------------------------------------------------


def sample_velocity(t, xyz, step_invalid=None, fill=np.nan, lag: int = 1):
    """Velocity from successive samples, seed eq. (3), shape (N,).

    ``v(i) = |p(i) - p(i-lag)| / (t(i) - t(i-lag))``; ``lag = 1`` is the seed's
    formula, a larger lag takes it over the seed's sampling interval on a
    faster stream.  ``v[:lag]`` and the indices in ``step_invalid`` (e.g. the
    samples whose step crosses a beam break) are set to ``fill`` (NaN by
    default).
    """
    n = t.size
    lag = int(lag)
    v = np.empty(n)
    v[:lag] = fill
    if n > lag:
        acc = v[lag:]
        d = np.empty(n - lag)
        for k in range(3):  # loop over axes
            col = xyz[:, k]
            np.subtract(col[lag:], col[:-lag], out=d)
            np.multiply(d, d, out=d)
            if k == 0:
                acc[:] = d
            else:
                acc += d
        np.sqrt(acc, out=acc)
        np.subtract(t[lag:], t[:-lag], out=d)
        acc /= d
    if step_invalid is not None and len(step_invalid):
        v[step_invalid] = fill
    return v


def moving_speed(t, xyz, h, block_starts):
    """Moving average of the velocity vector over 2h+1 samples, its norm, (N,).

    ``|p(i+h) - p(i-h)| / (t(i+h) - t(i-h))``, clamped to the contiguous block
    (between beam breaks) that holds sample i.  NaN for a one-sample block.
    """
    n = t.size
    u = np.full(n, np.nan)
    if n >= 2 * h + 1:
        num = u[h : n - h]
        d = np.empty(n - 2 * h)
        for k in range(3):  # loop over axes
            col = xyz[:, k]
            np.subtract(col[2 * h :], col[: n - 2 * h], out=d)
            np.multiply(d, d, out=d)
            if k == 0:
                num[:] = d
            else:
                num += d
        np.sqrt(num, out=num)
        np.subtract(t[2 * h :], t[: n - 2 * h], out=d)
        num /= d
        del d
    # samples whose span would cross a block edge: recompute one-sided
    edges = np.concatenate([block_starts, [n]])
    near = np.concatenate(
        [np.arange(max(e - h, 0), min(e + h, n)) for e in edges]
    ) if edges.size else np.zeros(0, np.int64)
    near = np.unique(near)
    if near.size:
        blk = np.searchsorted(block_starts, near, side="right") - 1
        b_lo = block_starts[blk]
        b_hi = edges[blk + 1] - 1
        lo = np.maximum(near - h, b_lo)
        hi = np.minimum(near + h, b_hi)
        ok = hi > lo
        d = xyz[hi[ok]] - xyz[lo[ok]]
        uu = np.full(near.size, np.nan)
        uu[ok] = np.sqrt(np.einsum("ij,ij->i", d, d)) / (t[hi[ok]] - t[lo[ok]])
        u[near] = uu
    return u


def estimate_noise_mm(xyz, t=None, max_points=100_000, at=None):
    """Per-axis white position noise from second differences (robust MAD), mm.

    With ``t`` the second difference is taken of the velocities (times the
    median interval), so a constant velocity sampled at uneven instants adds
    nothing.  Evaluated on at most ``max_points`` evenly spread samples, or
    on the samples ``at`` (e.g. those at rest; 1 <= at <= N-2).
    """
    n = xyz.shape[0]
    if n < 3:
        return 0.0
    if at is None:
        step = max(1, (n - 2) // max_points)
        i = np.arange(1, n - 1, step)
    else:
        i = np.asarray(at, dtype=np.int64)
        i = i[(i >= 1) & (i <= n - 2)]
        if i.size > max_points:
            i = i[:: i.size // max_points]
        if i.size < 10:
            return estimate_noise_mm(xyz, t, max_points)
    if t is not None:
        dt0, dt1 = t[i] - t[i - 1], t[i + 1] - t[i]
        med = float(np.median(dt1))
    sig = []
    for k in range(3):  # loop over axes
        if t is None:
            d2 = xyz[i + 1, k] - 2.0 * xyz[i, k] + xyz[i - 1, k]
        else:
            d2 = ((xyz[i + 1, k] - xyz[i, k]) / dt1 - (xyz[i, k] - xyz[i - 1, k]) / dt0) * med
        sig.append(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0))
    return float(np.sqrt(np.mean(np.square(sig))))


def window_sums(v, M, centers, invalid=None):
    """Sum of v over the 2M+1 samples around each centre.

    Parameters
    ----------
    v : ndarray (N,)
        Velocities; NaN marks an undefined step unless ``invalid`` is given.
    M : int
    centers : ndarray of int (W,), with M <= c < N - M
    invalid : ndarray of int, optional
        Sorted indices of undefined steps (then ``v`` must hold finite values
        there, e.g. 0, and is not copied).

    Returns
    -------
    sums : ndarray (W,), valid : ndarray of bool (W,) (no undefined step inside)
    """
    if invalid is None:
        invalid = np.flatnonzero(np.isnan(v))
        if invalid.size:
            v = v.copy()
            v[invalid] = 0.0
    c = np.empty(v.size + 1)
    c[0] = 0.0
    np.cumsum(v, out=c[1:])
    sums = c[centers + M + 1] - c[centers - M]
    del c
    nbad = np.searchsorted(invalid, centers + M, side="right") - np.searchsorted(invalid, centers - M, side="left")
    return sums, nbad == 0


def least_velocity_windows(v, M, Mp, phase_start, phase_end, invalid=None, origin=0):
    """The least-velocity horizon of each deceleration phase, seed eq. (4).

    Parameters
    ----------
    v : ndarray, (N,)
        Velocity from successive samples (NaN where undefined, or see
        ``invalid`` of :func:`window_sums`).
    M, Mp : int
        Horizon half size and step, samples.
    phase_start, phase_end : ndarray of int, (R,)
        Inclusive sample ranges of the phases (disjoint, increasing).

    origin : int
        Index in the whole stream of ``v[0]`` when ``v`` is a piece of it; the
        horizons stay on the stream's grid ``j = Mp, 2Mp, ...``.

    Returns
    -------
    center : ndarray of int, (R,)
        Centre sample of the least-velocity horizon (index into ``v``), -1
        where none fits.
    wsum : ndarray, (R,)
        Its velocity sum (NaN where none).
    """
    n = v.size
    R = phase_start.size
    center = np.full(R, -1, dtype=np.int64)
    wsum = np.full(R, np.nan)
    if R == 0:
        return center, wsum
    g0 = -(-(M + origin) // Mp)  # first grid point with j - M >= 0 (j local)
    g1 = (n - 1 - M + origin) // Mp
    if g1 < max(g0, 1):
        return center, wsum
    j = np.arange(max(g0, 1), g1 + 1, dtype=np.int64) * Mp - origin
    r = np.searchsorted(phase_start, j - M, side="right") - 1
    inside = r >= 0
    inside[inside] &= j[inside] + M <= phase_end[r[inside]]
    j, r = j[inside], r[inside]
    if j.size == 0:
        return center, wsum
    sums, ok = window_sums(v, M, j, invalid)
    j, r, sums = j[ok], r[ok], sums[ok]
    order = np.lexsort((j, sums, r))  # by phase, then least sum, then earliest
    rs = r[order]
    first = np.concatenate([[True], rs[1:] != rs[:-1]]) if rs.size else np.zeros(0, bool)
    pick = order[first]
    center[r[pick]] = j[pick]
    wsum[r[pick]] = sums[pick]
    return center, wsum


def final_rest_start(moving, phase_start, phase_end, min_len):
    """Start of each phase's final rest: the sample after the last one in motion (``moving``, bool (N,)),
    when at least ``min_len`` samples of rest remain before the phase's end; else the phase's start."""
    phase_start = np.asarray(phase_start, dtype=np.int64)
    phase_end = np.asarray(phase_end, dtype=np.int64)
    mi = np.flatnonzero(moving)
    if mi.size == 0 or phase_start.size == 0:
        return phase_start.copy()
    k = np.searchsorted(mi, phase_end, side="right") - 1
    last = np.where(k >= 0, mi[np.maximum(k, 0)], -1)
    rest0 = last + 1
    use = (last >= phase_start) & (phase_end - rest0 + 1 >= min_len)
    return np.where(use, rest0, phase_start)


def final_approach_start(xyz, move_start, center, approach_final_mm):
    """Index of the last sample in ``[move_start, center)`` at least ``approach_final_mm`` from ``xyz[center]``.

    One small array operation per stop (a loop over stops, not samples);
    ``move_start`` where no sample is that far (a short move).
    """
    out = np.asarray(move_start, dtype=np.int64).copy()
    for k, (a, c) in enumerate(zip(move_start, center)):
        if c <= a:
            continue
        seg = xyz[a:c] - xyz[c]
        far = np.flatnonzero(np.einsum("ij,ij->i", seg, seg) >= approach_final_mm**2)
        if far.size:
            out[k] = a + far[-1]
    return out


def _runs(mask):
    """Start and end (inclusive) indices of the runs of True in a bool array."""
    if mask.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    d = np.diff(mask.view(np.int8))
    starts = np.flatnonzero(d == 1) + 1
    ends = np.flatnonzero(d == -1)
    if mask[0]:
        starts = np.concatenate([[0], starts])
    if mask[-1]:
        ends = np.concatenate([ends, [mask.size - 1]])
    return starts.astype(np.int64), ends.astype(np.int64)


# --------------------------------------------------------------------------
# the extraction
# --------------------------------------------------------------------------


def _check_commanded(commanded_mm, names, order):
    c = np.asarray(commanded_mm, dtype=float)
    if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] == 0:
        raise DataError(f"commanded_mm must have shape (P, 3) with P >= 1, got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise DataError("commanded_mm contains NaN or inf")
    if names is None:
        names = tuple(f"P{k + 1}" for k in range(c.shape[0]))
    names = tuple(str(n) for n in names)
    if len(names) != c.shape[0]:
        raise DataError(f"names has {len(names)} entries for {c.shape[0]} commanded poses")
    if len(set(names)) != len(names):
        raise DataError(f"names must be unique, got {list(names)}")
    if order is None:
        order_idx = tuple(range(c.shape[0]))
    else:
        lookup = {n: k for k, n in enumerate(names)}
        order_idx = []
        for item in order:
            if isinstance(item, (int, np.integer)) and not isinstance(item, bool):
                if not 0 <= int(item) < c.shape[0]:
                    raise DataError(f"order: pose index {item} out of range 0..{c.shape[0] - 1}")
                order_idx.append(int(item))
            elif str(item) in lookup:
                order_idx.append(lookup[str(item)])
            else:
                raise DataError(f"order: unknown pose {item!r} (known: {', '.join(names)})")
        order_idx = tuple(order_idx)
        if not order_idx:
            raise DataError("order must name at least one pose")
    return c, names, order_idx


@dataclass(frozen=True)
class ExtractionOptions:
    """Settings of the attained-pose extraction (:func:`extract_attained_poses`); every field has the seed's
    default or one derived from the stream.

    Attributes
    ----------
    window_s : float
        Horizon length when ``M`` is not given: ``M = round(window_s * rate / 2)``
        (default 0.1 s; the seed's M = 10 at 100 Hz is 0.2 s).
    velocity_step_s : float
        Interval over which the velocity of eq. (3) is taken: the samples
        ``lag = max(1, round(velocity_step_s * rate))`` apart.  The default
        0.01 s is the seed's sampling interval: at 100 Hz and below it is the
        seed's velocity from successive samples; on a faster stream the
        successive-sample velocity is dominated by measurement noise
        (sqrt(2) sigma / dt) and would hide the last of the settling, making
        the attained pose depend on the tracker's rate.  0 = successive
        samples at any rate.
    M, Mp : int, optional
        Horizon half size and step in samples, eq. (4) (default from
        ``window_s``; ``Mp`` defaults to ``M`` as in the seed).
    smooth_s : float, optional
        Length of the moving average that splits the phases (default
        ``window_s / 2``).
    v_rest_mm_s : float, optional
        Rest threshold on the moving-average speed (default: the larger of
        2 mm/s and 6x the speed noise of the moving average).
    min_move_mm : float
        Net displacement below which a move is ignored (noise, ringing).
    min_dwell_s : float, optional
        Rest shorter than this is not a stop (default ``window_s``).
    gap_factor : float
        Steps longer than ``gap_factor`` sampling intervals are reported gaps.
    break_factor : float
        Steps longer than ``break_factor`` intervals split the stream.
    assign_tol_mm : float
        Largest distance from a stop to the commanded pose it is assigned to.
    min_fallback_M : int
        Smallest horizon half size tried when the full horizon does not fit.
    approach_final_mm : float
        Length of the final stretch of a move that gives its approach
        direction (``Stops.approach_unit``; vAP groups stops by it), mm.
    initial_rest_stop : bool
        The rest before the first move (at least ``min_dwell_s`` long) is a
        stop of the pose it stands at, when the commanded order puts that pose
        right before the first moved stop: that pose gets its first attained
        pose and the first move its posing time (a lab program P1, P2, ..., P5
        started at rest at P1). Default False, the seed's convention (3.1.3:
        the waiting interval before the first move is not extracted); the
        procedure keeps it so that a resumed run, which starts its stream at
        rest at P1 after ``home``, counts the same stops as an uninterrupted
        one. ``station analyze`` counts it unless ``--initial-rest skip``.
    """

    window_s: float = 0.1
    velocity_step_s: float = 0.01
    M: int | None = None
    Mp: int | None = None
    smooth_s: float | None = None
    v_rest_mm_s: float | None = None
    min_move_mm: float = 1.0
    min_dwell_s: float | None = None
    gap_factor: float = 1.5
    break_factor: float = 5.0
    assign_tol_mm: float = 25.0
    min_fallback_M: int = 1
    approach_final_mm: float = 50.0
    initial_rest_stop: bool = False

    def check(self) -> None:
        """DataError naming the first setting out of range."""
        for pname, val in (("window_s", self.window_s), ("min_move_mm", self.min_move_mm),
                           ("gap_factor", self.gap_factor), ("break_factor", self.break_factor),
                           ("assign_tol_mm", self.assign_tol_mm), ("approach_final_mm", self.approach_final_mm)):
            if not (np.isfinite(val) and val > 0):
                raise DataError(f"{pname} must be finite and > 0, got {float(val)}")
        if self.gap_factor <= 1.0 or self.break_factor < self.gap_factor:
            raise DataError(f"need 1 < gap_factor <= break_factor, got {self.gap_factor}, {self.break_factor}")


def extraction_options(options: ExtractionOptions | None = None, **fields) -> ExtractionOptions:
    """``options`` (default: the defaults) with ``fields`` set; TypeError naming a field that does not exist."""
    import dataclasses

    base = ExtractionOptions() if options is None else options
    return dataclasses.replace(base, **fields) if fields else base


def extract_attained_poses(t_s, xyz_mm, commanded_mm, *, names=None, order=None, valid=None,
                           options: ExtractionOptions | None = None, **fields) -> Extraction:
    """Attained poses of a continuous stream, assigned to commanded poses and cycles.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Device timestamps, s, strictly increasing.
    xyz_mm : array_like, shape (N, 3)
        Tool positions in the frame of ``commanded_mm``, mm.
    commanded_mm : array_like, shape (P, 3)
        Commanded positions, mm.
    names : sequence of str, length P, optional
        Pose names (default ``P1..PP``).
    order : sequence of str or int, optional
        Commanded order of one cycle; a pose may appear more than once.
        Default: the poses in the given order, rotated so that the cycle
        starts with the first stop found (the seed starts at rest at P1 and
        runs P2, P3, P4, P5, P1).
    valid : array_like of bool, shape (N,), optional
        False for rows the instrument flagged invalid (dropped, reported).
    options : ExtractionOptions, optional
        The extraction's settings (horizon, velocity step, rest threshold,
        dwell, gaps, assignment tolerance, approach, initial rest); keyword
        arguments of the same names set single fields (``window_s=0.2``).

    Returns
    -------
    Extraction

    Raises
    ------
    DataError
        Bad input (named); sampling rate outside 10-3000 Hz.
    InsufficientDataError
        Fewer than 3 samples, or no move at all.
    """
    n_rows = int(np.shape(t_s)[0]) if np.ndim(t_s) else 0
    t, xyz, rows_used, _ = validate_stream(t_s, xyz_mm, valid)
    return extract_validated(t, xyz, rows_used, n_rows, commanded_mm, names=names, order=order,
                             options=extraction_options(options, **fields))


def extract_validated(t, xyz, rows_used, n_rows, commanded_mm, *, names=None, order=None,
                      options: ExtractionOptions | None = None, **fields) -> Extraction:
    """:func:`extract_attained_poses` on arrays already through :func:`validate_stream`, in named stages.

    ``rows_used`` maps used samples to stream rows (None: identity);
    ``n_rows`` is the number of rows of the stream as given. The stages:
    :func:`_sampling` (the rate and every setting in samples), :func:`_gaps`
    (gaps and beam breaks), :func:`_moves` (moves and phases from the moving
    average speed), :func:`_horizons` (the least-velocity horizon of each
    phase, eq. (4), and the special phases), :func:`_stop_points` (attained
    positions and approach directions) and :func:`_assignment` (commanded pose,
    order and cycle of each stop).
    """
    opt = extraction_options(options, **fields)
    commanded, names, order_idx = _check_commanded(commanded_mm, names, order)
    opt.check()
    n = t.size
    if n < 3:
        raise InsufficientDataError(f"the stream has {n} valid samples, at least 3 are needed")
    to_row = (lambda i: i) if rows_used is None else (lambda i: rows_used[i])
    smp = _sampling(t, opt)
    gaps, brk, block_starts = _gaps(t, smp, opt, to_row)
    mv = _moves(t, xyz, smp, opt, brk, block_starts)
    hz = _horizons(t, xyz, smp, opt, mv, brk, to_row)
    sp = _stop_points(t, xyz, opt, mv, hz, brk)
    asg = _assignment(sp, commanded, names, order, order_idx, opt, mv.noise, brk, t, hz.failed)
    stops = Stops(
        row=np.asarray(to_row(sp.ci), dtype=np.int64),
        i_center=sp.ci,
        i_window_first=sp.ci - sp.wM,
        i_window_last=sp.ci + sp.wM,
        i_phase_start=sp.ph_start,
        i_phase_end=sp.ph_end,
        i_move_start=sp.mstart,
        t_s=t[sp.ci],
        position_mm=sp.pos,
        window_sum_mm_s=sp.wsum,
        window_M=sp.wM.astype(np.int64),
        fallback=sp.fallback,
        approach_unit=sp.app_unit,
        approach_mm=sp.app_len,
        gap_in_approach=sp.gap_app,
        pose=asg.pose.astype(np.int64),
        cycle=asg.cycle,
        seq=asg.seq,
        distance_to_pose_mm=asg.dist,
        nearest_pose=asg.nearest.astype(np.int64),
        status=asg.status,
        initial=sp.initial,
    )
    warnings = []
    if sp.ci.size and np.any(stops.fallback):
        warnings.append(
            f"{int(np.count_nonzero(stops.fallback))} stop(s) took their horizon between beam breaks or inside a "
            f"short rest ({int(np.count_nonzero(stops.window_M < smp.M))} with fewer than 2M+1 = {2 * smp.M + 1} "
            "samples)"
        )
    return Extraction(
        params=ExtractionParams(
            rate_hz=float(smp.rate), median_dt_s=smp.med_dt, lag=smp.lag, M=smp.M, Mp=smp.Mp, h=smp.h,
            noise_mm=mv.noise, v_rest_mm_s=mv.v_rest, gap_factor=opt.gap_factor, break_s=smp.break_s,
            min_move_mm=float(opt.min_move_mm), min_dwell_s=float(smp.min_dwell), assign_tol_mm=float(asg.tol_mm),
        ),
        names=names,
        commanded_mm=commanded,
        order=asg.order_idx,
        n_rows=n_rows,
        n_used=n,
        rows_used=rows_used,
        gaps=gaps,
        stops=stops,
        missing=tuple(asg.missing),
        failed_phases=tuple(hz.failed),
        moves_i=mv.moves_i,
        initial_rest_i=mv.initial_rest,
        trailing_motion=mv.trailing_motion,
        n_cycles=asg.n_cycles,
        warnings=tuple(warnings),
    )


@dataclass(frozen=True)
class _Sampling:
    """The stream's rate and every setting in samples."""

    med_dt: float
    rate: float
    lag: int
    M: int
    Mp: int
    h: int
    min_dwell: float
    break_s: float


def _sampling(t, opt: ExtractionOptions) -> _Sampling:
    """Rate from the median interval (10-3000 Hz), velocity lag, horizon M, Mp (eq. (4)), smoothing h."""
    window_s, velocity_step_s, M, Mp = opt.window_s, opt.velocity_step_s, opt.M, opt.Mp
    dt = np.diff(t)
    # to the nanosecond: the rounding of the stamps (which depends on where in time they lie, e.g. after a
    # resume) must not tip the half-widths below from one integer to the next
    med_dt = round(float(np.median(dt[:: max(1, dt.size // 500_000)])), 9)
    rate = 1.0 / med_dt
    lo_r, hi_r = RATE_RANGE_HZ
    if not (0.95 * lo_r <= rate <= 1.05 * hi_r):
        raise DataError(f"sampling rate {rate:.3g} Hz (median interval {med_dt:.3g} s) is outside {lo_r:g}-{hi_r:g} Hz")
    if not (np.isfinite(velocity_step_s) and velocity_step_s >= 0):
        raise DataError(f"velocity_step_s must be finite and >= 0, got {velocity_step_s!r}")
    lag = max(1, int(round(velocity_step_s * rate)))
    if M is None:
        M = max(1, int(round(window_s * rate / 2)))  # 0.2 s at 100 Hz: M = 10, as in the seed
    if Mp is None:
        Mp = M
    M, Mp = int(M), int(Mp)
    if M < 1 or Mp < 1:
        raise DataError(f"M and Mp must be >= 1, got M={M}, Mp={Mp}")
    smooth = 0.5 * window_s if opt.smooth_s is None else float(opt.smooth_s)
    if not (np.isfinite(smooth) and smooth > 0):
        raise DataError(f"smooth_s must be finite and > 0, got {opt.smooth_s!r}")
    h = max(1, int(round(smooth * rate / 2)))
    min_dwell = window_s if opt.min_dwell_s is None else float(opt.min_dwell_s)
    return _Sampling(med_dt, rate, lag, M, Mp, h, min_dwell, opt.break_factor * med_dt)


def _gaps(t, smp: _Sampling, opt: ExtractionOptions, to_row):
    """``(Gaps, brk, block_starts)``: steps longer than ``gap_factor`` intervals; those longer than
    ``break_factor`` split the stream (a break between ``brk`` and ``brk + 1``)."""
    dt = np.diff(t)
    gap_i = np.flatnonzero(dt > opt.gap_factor * smp.med_dt)
    split = dt[gap_i] > smp.break_s
    gaps = Gaps(
        row_before=np.asarray(to_row(gap_i), dtype=np.int64),
        row_after=np.asarray(to_row(gap_i + 1), dtype=np.int64),
        t_start_s=t[gap_i],
        t_end_s=t[gap_i + 1],
        lost_samples=np.maximum(np.rint(dt[gap_i] / smp.med_dt).astype(np.int64) - 1, 0),
        splits=split,
    )
    brk = gap_i[split]  # break between brk and brk+1
    block_starts = np.concatenate([[0], brk + 1]).astype(np.int64)
    return gaps, brk, block_starts


@dataclass
class _Moves:
    """Moves (start, speed peak, end) and the phases from each peak to the next move."""

    noise: float
    v_rest: float
    u: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    moves_i: np.ndarray
    initial_rest: tuple | None
    trailing_motion: bool
    phase_start: np.ndarray
    phase_end: np.ndarray


def _moves(t, xyz, smp: _Sampling, opt: ExtractionOptions, brk, block_starts) -> _Moves:
    """Moves from the moving-average speed above the rest threshold, net ``min_move_mm``, split by dwells."""
    n = t.size
    h, med_dt, min_dwell, min_move_mm = smp.h, smp.med_dt, smp.min_dwell, opt.min_move_mm
    noise = estimate_noise_mm(xyz, t)
    if opt.v_rest_mm_s is None:
        v_noise = np.sqrt(2.0) * noise / ((2 * h) * med_dt)
        v_rest = float(max(2.0, 6.0 * v_noise))
    else:
        v_rest = float(opt.v_rest_mm_s)
        if not (np.isfinite(v_rest) and v_rest > 0):
            raise DataError(f"v_rest_mm_s must be finite and > 0, got {opt.v_rest_mm_s!r}")
    u = moving_speed(t, xyz, h, block_starts)
    moving = u > v_rest  # NaN -> False
    starts, ends = _runs(moving)
    # the noise as reported: from samples at rest (motion has acceleration in it)
    probe = np.arange(1, n - 1, max(1, n // 100_000))
    probe = probe[~(moving[probe - 1] | moving[probe] | moving[probe + 1])]
    noise = estimate_noise_mm(xyz, t, at=probe)
    del moving
    if starts.size:
        disp = np.linalg.norm(xyz[ends] - xyz[starts], axis=1)
        keep = disp >= min_move_mm
        starts, ends = starts[keep], ends[keep]
    if starts.size > 1:
        rest_dur = t[starts[1:] - 1] - t[ends[:-1] + 1]
        # a rest of at most one sample has duration 0 by this measure; a rest cut
        # short by a beam break is a stop if it has 3 samples
        n_brk_in = np.searchsorted(brk, starts[1:], side="left") - np.searchsorted(brk, ends[:-1], side="left")
        boundary = (rest_dur >= min_dwell) | ((n_brk_in > 0) & (starts[1:] - ends[:-1] - 1 >= 3))
        starts = starts[np.concatenate([[True], boundary])]
        ends = ends[np.concatenate([boundary, [True]])]
    if starts.size == 0:
        raise InsufficientDataError(
            f"no move found in the stream: the moving-average speed never exceeded "
            f"{v_rest:.3g} mm/s over a net {min_move_mm:g} mm (a held pose? `station analyze hold`)"
        )
    # speed peak of each move: the first sample of the run's largest moving-average speed
    # (the maximum over [start_r, start_r+1) is the run's: the rest after it is slower)
    u[np.isnan(u)] = -np.inf
    umax = np.maximum.reduceat(u, starts)
    lens = np.diff(np.append(starts, n))
    hits = np.flatnonzero(u[starts[0]:] == np.repeat(umax, lens)) + starts[0]
    peaks = hits[np.searchsorted(hits, starts, side="left")]
    moves_i = np.stack([starts, peaks, ends], axis=1)
    initial_rest = (0, int(starts[0]) - 1) if starts[0] > 0 else None
    trailing_motion = bool(ends[-1] >= n - 1)
    phase_start = peaks
    phase_end = np.concatenate([starts[1:] - 1, [n - 1]])
    return _Moves(noise, v_rest, u, starts, ends, moves_i, initial_rest, trailing_motion, phase_start, phase_end)


@dataclass
class _Horizons:
    """The least-velocity horizon of each phase (centre -1: none), the failed phases and the initial rest's."""

    center: np.ndarray
    wsum: np.ndarray
    wM: np.ndarray
    fallback: np.ndarray
    failed: list
    init: tuple | None


def _horizons(t, xyz, smp: _Sampling, opt: ExtractionOptions, mv: _Moves, brk, to_row) -> _Horizons:
    """Eq. (4) in each phase; phases with a beam break, a horizon not at rest or none get the best horizon
    at rest that fits (:func:`least_velocity_windows` per piece between breaks)."""
    n = t.size
    lag, M, Mp, min_dwell = smp.lag, smp.M, smp.Mp, smp.min_dwell
    v_rest, u, starts, ends = mv.v_rest, mv.u, mv.starts, mv.ends
    phase_start, phase_end, trailing_motion, initial_rest = mv.phase_start, mv.phase_end, mv.trailing_motion, \
        mv.initial_rest
    min_fallback_M, initial_rest_stop = opt.min_fallback_M, opt.initial_rest_stop
    R = starts.size
    # velocities whose step has no predecessor or crosses a beam break
    invalid = np.unique(np.concatenate([np.arange(min(lag, n))] + [np.arange(b + 1, min(b + 1 + lag, n))
                                                                      for b in brk])).astype(np.int64)
    v = sample_velocity(t, xyz, invalid, fill=0.0, lag=lag)
    # horizons centred in the final rest (their windows may reach M samples back into the motion before it):
    # the rest after the phase's move, judged by the moves themselves: a stir too small to be a move (less
    # than min_move_mm, e.g. the next move's onset dipping under v_rest once) does not end it early
    d = np.zeros(n + 1, dtype=np.int64)
    np.add.at(d, starts, 1)
    np.add.at(d, ends + 1, -1)
    in_move = np.cumsum(d[:n]) > 0
    search_start = np.maximum(phase_start, final_rest_start(in_move, phase_start, phase_end, M + Mp) - M)
    center, wsum = least_velocity_windows(v, M, Mp, search_start, phase_end, invalid)
    if trailing_motion:  # the last move never came to rest: its phase has no stop
        center[-1], wsum[-1] = -1, np.nan
    # Special phases, taken one by one (a loop over phases, few of them):
    # a beam break inside the phase, a least-velocity horizon not at rest, or
    # none at all.  The rest part of the phase is split at the breaks; each
    # piece gets the largest horizon M' <= M that fits with its centre at rest,
    # and the pieces compete on the mean velocity per sample (for equal M' the
    # seed's least sum).  Without a break this is the seed's choice restricted
    # to the rest with the largest horizon that fits.
    n_brk_phase = np.searchsorted(brk, phase_end, side="left") - np.searchsorted(brk, phase_start, side="left")
    in_motion = center >= 0
    in_motion[in_motion] = u[center[in_motion]] > v_rest
    special = (center < 0) | in_motion | (n_brk_phase > 0)
    if trailing_motion:
        special[-1] = False
    wM = np.where(center >= 0, M, 0)
    fallback = np.zeros(R, bool)
    failed: list[FailedPhase] = []

    def rest_horizon(rs: int, pe: int):
        """(mean, centre, sum, M') of the best horizon at rest in samples rs..pe, split at beam breaks; or None."""
        best = None
        cuts = brk[(brk >= rs) & (brk < pe)]
        for a, b in zip(np.concatenate([[rs], cuts + 1]), np.concatenate([cuts, [pe]])):  # pieces
            a, b = int(a), int(b)
            inv_local = invalid[(invalid >= a) & (invalid <= b)] - a
            for m in range(min(M, (b - a) // 2), min_fallback_M - 1, -1):
                mp = max(1, int(round(m * Mp / M)))
                c1, s1 = least_velocity_windows(v[a : b + 1], m, mp, np.array([0]), np.array([b - a]),
                                                inv_local, origin=a)
                if c1[0] >= 0 and not u[c1[0] + a] > v_rest:
                    mean = s1[0] / (2 * m + 1)
                    if best is None or mean < best[0]:
                        best = (mean, c1[0] + a, s1[0], m)
                    break
        return best

    for r in np.flatnonzero(special | (center < 0)):  # loop over the few special phases
        pe = int(phase_end[r])
        rs = int(max(phase_start[r], ends[r] + 1))  # the rest part of the phase
        center[r], wsum[r], wM[r] = -1, np.nan, 0
        best = rest_horizon(rs, pe) if special[r] else None
        if best is not None:
            _, center[r], wsum[r], wM[r] = best
            fallback[r] = True
            continue
        rest0 = int(ends[r]) + 1
        ps = int(phase_start[r])
        n_brk = int(n_brk_phase[r])
        if r == R - 1 and trailing_motion:
            reason = "the stream ends before the tool came to rest"
        elif n_brk:
            reason = f"beam break(s) ({n_brk}) leave no window of 3 valid samples at rest in the dwell"
        else:
            reason = f"the rest ({max(pe - rest0 + 1, 0)} samples) holds no window of 3 samples"
        failed.append(FailedPhase(ps, pe, int(to_row(ps)), int(to_row(pe)), float(t[ps]), float(t[pe]), reason))
    # the rest before the first move: a stop when it lasts a dwell and holds a horizon at rest
    init = None  # (centre, sum, M', fallback)
    if initial_rest_stop and initial_rest is not None and t[initial_rest[1]] - t[0] >= min_dwell:
        b0 = initial_rest[1]
        c0, s0 = least_velocity_windows(v, M, Mp, np.array([0]), np.array([b0]), invalid)
        if c0[0] >= 0 and not u[c0[0]] > v_rest and not np.any((brk >= 0) & (brk < b0)):
            init = (int(c0[0]), float(s0[0]), M, False)
        else:
            best = rest_horizon(0, b0)
            if best is not None:
                init = (int(best[1]), float(best[2]), int(best[3]), True)
    return _Horizons(center, wsum, wM, fallback, failed, init)


@dataclass
class _StopPoints:
    """The stops found (K,): centre sample, horizon, phase, move start, position and approach."""

    ci: np.ndarray
    mstart: np.ndarray
    ph_start: np.ndarray
    ph_end: np.ndarray
    wsum: np.ndarray
    wM: np.ndarray
    fallback: np.ndarray
    initial: np.ndarray
    pos: np.ndarray
    app_unit: np.ndarray
    app_len: np.ndarray
    gap_app: np.ndarray


def _stop_points(t, xyz, opt: ExtractionOptions, mv: _Moves, hz: _Horizons, brk) -> _StopPoints:
    """The phases with a horizon (and the initial rest, when it counts): attained position and approach."""
    center, wsum, wM, fallback, init = hz.center, hz.wsum, hz.wM, hz.fallback, hz.init
    starts, phase_start, phase_end, initial_rest = mv.starts, mv.phase_start, mv.phase_end, mv.initial_rest
    approach_final_mm = opt.approach_final_mm
    ok = center >= 0
    ci = center[ok]
    mstart = starts[ok]
    ph_start, ph_end = phase_start[ok], phase_end[ok]
    wsum_k, wM_k, fb_k = wsum[ok], wM[ok], fallback[ok]
    if init is not None:
        ci = np.concatenate([[init[0]], ci]).astype(np.int64)
        mstart = np.concatenate([[0], mstart]).astype(np.int64)
        ph_start = np.concatenate([[0], ph_start]).astype(np.int64)
        ph_end = np.concatenate([[initial_rest[1]], ph_end]).astype(np.int64)
        wsum_k = np.concatenate([[init[1]], wsum_k])
        wM_k = np.concatenate([[init[2]], wM_k])
        fb_k = np.concatenate([[init[3]], fb_k])
    initial = np.zeros(ci.size, bool)
    if init is not None:
        initial[0] = True
    pos = xyz[ci].copy()
    app_len = np.linalg.norm(pos - xyz[mstart], axis=1)
    app_from = final_approach_start(xyz, mstart, ci, approach_final_mm)
    app = pos - xyz[app_from]
    with np.errstate(invalid="ignore", divide="ignore"):
        n_app = np.linalg.norm(app, axis=1)
        app_unit = np.where(n_app[:, None] > 0, app / n_app[:, None], 0.0)
    app_unit[initial] = 0.0
    app_len[initial] = 0.0
    gap_app = (np.searchsorted(brk, ci, side="left") - np.searchsorted(brk, mstart, side="left")) > 0
    gap_app[initial] = False
    return _StopPoints(ci, mstart, ph_start, ph_end, wsum_k, wM_k, fb_k, initial, pos, app_unit, app_len, gap_app)


@dataclass
class _Assignment:
    """Commanded pose, order position and cycle of each stop, the stops missing from the order."""

    tol_mm: float
    nearest: np.ndarray
    dist: np.ndarray
    status: np.ndarray
    pose: np.ndarray
    seq: np.ndarray
    cycle: np.ndarray
    missing: list
    order_idx: list
    n_cycles: int


def _assignment(sp: _StopPoints, commanded, names, order, order_idx, opt: ExtractionOptions, noise, brk, t,
                failed) -> _Assignment:
    """Each stop to the nearest commanded pose within the tolerance, then walked along the commanded order."""
    pos, ci, initial = sp.pos, sp.ci, sp.initial
    assign_tol_mm = max(float(opt.assign_tol_mm), ASSIGN_NOISE_FACTOR * noise)
    d = np.linalg.norm(pos[:, None, :] - commanded[None, :, :], axis=2)  # (K, P)
    nearest = np.argmin(d, axis=1) if d.size else np.zeros(0, np.int64)
    dist = d[np.arange(d.shape[0]), nearest] if d.size else np.zeros(0)
    status = np.where(dist <= assign_tol_mm, STATUS_ASSIGNED, STATUS_UNASSIGNED).astype(np.int64)
    in_order = np.zeros(commanded.shape[0], bool)
    in_order[list(order_idx)] = True
    status[(status == STATUS_ASSIGNED) & ~in_order[nearest]] = STATUS_NOT_IN_ORDER
    if initial.any() and status[0] != STATUS_ASSIGNED:
        status[0] = STATUS_INITIAL_REST  # standing away from the poses (e.g. at home): not a stop of the order
    pose = np.where(status == STATUS_ASSIGNED, nearest, -1)
    t_stop = t[ci]
    moved = np.flatnonzero((pose >= 0) & ~initial)
    if order is None and moved.size:
        # default order: the poses as listed, one cycle starting at the first moved stop
        k0 = order_idx.index(int(pose[moved[0]]))
        order_idx = order_idx[k0:] + order_idx[:k0]
    count_initial = False
    if initial.any() and pose[0] >= 0:
        # the rest counts when the order puts its pose right before the first moved stop
        q = order_idx.index(int(pose[moved[0]])) if moved.size else 1
        count_initial = not moved.size or order_idx[(q - 1) % len(order_idx)] == pose[0]
        if not count_initial:
            status[0] = STATUS_INITIAL_REST
        pose_walk = pose.copy()
        pose_walk[0] = -1
    else:
        pose_walk = pose
    seq, cycle, missing, st2 = _walk_order(pose_walk, t_stop, order_idx, names, brk, t, failed)
    if count_initial:
        # the position before the first moved stop's: in the cycle before the first (-1) when that
        # stop opens a cycle, as the seed's rest at P1 before P2, P3, P4, P5, P1
        k1 = int(moved[0]) if moved.size else -1
        seq[0] = seq[k1] - 1 if k1 >= 0 and seq[k1] >= 0 else 0
        cycle[0] = seq[0] // len(order_idx)
    status = np.where((status == STATUS_ASSIGNED) & (st2 == STATUS_OUT_OF_SEQUENCE), STATUS_OUT_OF_SEQUENCE, status)
    pose = np.where(status == STATUS_ASSIGNED, pose, -1)
    L = len(order_idx)
    n_cycles = int(seq[seq >= 0].max() // L + 1) if np.any(seq >= 0) else 0
    return _Assignment(assign_tol_mm, nearest, dist, status, pose, seq, cycle, missing, order_idx, n_cycles)


def _walk_order(pose, t_stop, order_idx, names, brk, t, failed):
    """Walk the assigned stops through the commanded order.

    Each stop takes the next position of its pose in the unrolled order; the
    positions it skips are missing stops.  A stop that would skip more
    positions than the elapsed time allows (1.5x the median time per stop,
    plus a half) is out of sequence and left out.  Vectorised when no stop is
    out of sequence and no pose repeats within the order; otherwise a loop over
    stops.

    Returns seq (K,), cycle (K,), missing list, status (K,) with
    STATUS_OUT_OF_SEQUENCE where a stop does not fit the order.
    """
    K = pose.size
    L = len(order_idx)
    seq = np.full(K, -1, dtype=np.int64)
    status = np.zeros(K, dtype=np.int64)
    idx = np.flatnonzero(pose >= 0)
    if idx.size == 0:
        return seq, seq.copy(), [], status
    pos_in_order: dict[int, list[int]] = {}
    for k, p in enumerate(order_idx):
        pos_in_order.setdefault(p, []).append(k)
    ts = t_stop[idx]
    step_dt = float(np.median(np.diff(ts))) if idx.size > 1 else np.inf
    timed = np.isfinite(step_dt) and step_dt > 0

    done = False
    if all(len(v) == 1 for v in pos_in_order.values()):
        posmap = np.full(max(order_idx) + 1, -1, dtype=np.int64)
        posmap[list(order_idx)] = np.arange(L)
        kpos = posmap[pose[idx]]
        adv = (kpos[1:] - kpos[:-1]) % L
        adv[adv == 0] = L
        allowed = np.maximum(1.0, 1.5 * np.diff(ts) / step_dt + 0.5) if timed else np.full(adv.size, np.inf)
        if np.all(adv <= allowed):
            seq[idx] = kpos[0] + np.concatenate([[0], np.cumsum(adv)])
            done = True
    if not done:

        def next_ptr(e, p):
            return min(e + ((k - e) % L) for k in pos_in_order[p])

        e = None  # next expected position in the unrolled order
        prev_k = None
        for k in idx:  # loop over stops
            p = int(pose[k])
            if e is None:
                q = pos_in_order[p][0]
            else:
                q = next_ptr(e, p)
                adv1 = q - (e - 1)
                allowed1 = max(1.0, 1.5 * float(t_stop[k] - t_stop[prev_k]) / step_dt + 0.5) if timed else np.inf
                if adv1 > allowed1:
                    status[k] = STATUS_OUT_OF_SEQUENCE
                    continue
            seq[k] = q
            e, prev_k = q + 1, k

    # missing stops: positions skipped between consecutive accepted stops
    acc = idx[seq[idx] >= 0]
    sq = seq[acc]
    holes = np.flatnonzero(np.diff(sq) > 1)
    missing: list[MissingStop] = []
    failed_t = np.array([f.t_start_s for f in failed]) if failed else np.zeros(0)
    t_brk0, t_brk1 = t[brk], t[brk + 1]
    for h in holes:  # loop over holes
        t0, t1 = float(t_stop[acc[h]]), float(t_stop[acc[h + 1]])
        fin = (failed_t > t0) & (failed_t < t1)
        b = (t_brk1 > t0) & (t_brk0 < t1)
        if fin.any():
            reason = "stop not extracted: " + failed[int(np.argmax(fin))].reason
        elif b.any():
            j = int(np.argmax(b))
            reason = f"beam break {t_brk0[j]:.3f}-{t_brk1[j]:.3f} s hides the stop"
        else:
            reason = "no stop found near the pose (the robot did not come to rest there)"
        for s_ in range(int(sq[h]) + 1, int(sq[h + 1])):
            missing.append(MissingStop(s_ // L, names[order_idx[s_ % L]], s_, reason, t0, t1))
    cycle = np.where(seq >= 0, seq // L, -1)
    return seq, cycle, missing, status
