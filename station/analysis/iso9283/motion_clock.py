"""A clock coarser than the samples, checked against the motion; the sample rate from the motion.

A logger that stamps the tracker's samples with a PC clock of 1 s resolution
(many samples a stamp) may stamp them on receipt, in bursts, falling behind:
the stamps then say nothing of when the samples were taken, and a rate read
from them (samples per stamp second) gives wrong PST, MPT and drift. The
samples themselves keep time: the tracker samples at a fixed rate, so

* identical moves (the same start and end pose) take the same number of
  samples; their spread says whether the samples are evenly spaced;
* the stamps, if they are a clock, give every move and every dwell the
  duration its sample count gives at the stamps' rate (within the stamps'
  resolution);
* the dwells last the program's wait (plus a little: the approach inside the
  rest radius, the controller's overhead), which gives the rate when the
  stamps fail. A Leica tracker through emScon samples at ``1000 / k`` Hz: the
  rate is the one such rate the dwells allow, when there is exactly one.

Everything here works in samples (rows), never in the stamps' time, so that
the check does not rest on what it checks. Pure: arrays in, results out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import DataError

#: samples either side of a sample over which the tool must stay put for the sample to be still
STILL_HALF = 5
#: the still threshold over 2 * STILL_HALF samples is at least this many times the noise (3-D)
STILL_NOISE_FACTOR = 10.0
#: ... and at least this fraction of the stream's extent
STILL_EXTENT_FRACTION = 1e-4
#: the radius around a rest position (leaving it starts a move, entering it ends one), mm, at least
REST_RADIUS_MM = 0.5
#: ... and at least this many times the noise
REST_RADIUS_NOISE_FACTOR = 50.0
#: identical moves may differ by this many samples, or this fraction of their length when more
MOVE_SPREAD_SAMPLES = 3
MOVE_SPREAD_FRACTION = 0.02
#: a stamp duration may differ from samples / rate by the stamps' resolution plus this fraction
STAMP_TOLERANCE_FRACTION = 0.02
#: a dwell lasts the program's wait minus at most this (s) ...
DWELL_SHORT_S = 0.05
#: ... and plus at most this fraction of the wait (a controller's timer) plus this (s): the approach and the
#: departure inside the rest radius and the controller's overhead, which do not grow with the wait
DWELL_LONG_FRACTION = 0.02
DWELL_LONG_S = 0.4
#: emScon sampling rates are EMSCON_BASE_HZ / k, k = 1 .. EMSCON_MAX_K
EMSCON_BASE_HZ = 1000.0
EMSCON_MAX_K = 100
#: relative standard uncertainty of a tracker's sampling clock (a quartz), for a rate taken as an emScon rate
CLOCK_REL_U = 1e-4
#: a rate read from the dwells alone (no emScon rate fits) is used only when its half interval is within this
MAX_CONTINUOUS_HALF_FRACTION = 0.05


@dataclass(frozen=True)
class Moves:
    """The moves of a stream between rests, in rows (no time used).

    ``centres_mm`` (S, 3) the rest positions; ``leave_row``/``arrive_row`` (K,)
    the last row inside the start rest's radius and the first inside the end
    rest's; ``from_rest``/``to_rest`` (K,) indices into ``centres_mm``;
    ``still_rows`` (K,) the rows the tool stood still at the rest each move
    reaches (up to the next move; -1 where no move follows); ``noise_mm`` the
    3-D noise per sample, ``radius_mm`` the rest radius.
    """

    centres_mm: np.ndarray
    leave_row: np.ndarray
    arrive_row: np.ndarray
    from_rest: np.ndarray
    to_rest: np.ndarray
    noise_mm: float
    radius_mm: float
    still_rows: np.ndarray | None = None

    @property
    def samples(self) -> np.ndarray:
        """Samples each move takes (rows from leaving to arriving)."""
        return self.arrive_row - self.leave_row

    @property
    def dwell_rows(self) -> np.ndarray:
        """Rows the tool stands still at each stop between two moves (the program's wait and its overhead)."""
        if self.still_rows is None or self.still_rows.size < 2:
            return np.zeros(0, np.int64)
        d = self.still_rows[:-1]
        return d[d >= 0]


def noise_3d_mm(p: np.ndarray) -> float:
    """3-D noise per sample from robust second differences (a motion's acceleration is negligible in them)."""
    if p.shape[0] < 5:
        return 0.0
    d2 = p[2:] - 2.0 * p[1:-1] + p[:-2]
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) * 1.4826
    return float(np.sqrt(np.sum((mad / math.sqrt(6.0)) ** 2)))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of every run of True."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist()))


def find_moves(xyz_mm, valid=None) -> Moves:
    """The moves between rests of a stream (N, 3) mm, in rows; ``valid`` (N,) leaves flagged rows out.

    A sample is still when the tool moves less than a threshold (noise and
    extent) over the ``2 * STILL_HALF`` samples around it; runs of still
    samples are rests, clustered by position (within the rest radius). A move
    runs from the last sample inside its start rest's radius to the first
    inside the next rest's. Moves to the rest they left (a stir) are no moves.
    """
    xyz = np.asarray(xyz_mm, dtype=float)
    n = xyz.shape[0]
    ok = np.ones(n, bool) if valid is None else np.asarray(valid, bool)
    rows = np.flatnonzero(ok & np.all(np.isfinite(xyz), axis=1))
    p = xyz[rows]
    L = STILL_HALF
    empty = np.zeros(0, np.int64)
    if p.shape[0] < 4 * L + 2:
        return Moves(np.zeros((0, 3)), empty, empty, empty, empty, 0.0, REST_RADIUS_MM)
    sig = noise_3d_mm(p)
    extent = float(np.max(np.ptp(p, axis=0)))
    thr = max(STILL_NOISE_FACTOR * sig, STILL_EXTENT_FRACTION * extent, 1e-9)
    disp = np.linalg.norm(p[2 * L:] - p[:-2 * L], axis=1)
    still = np.zeros(p.shape[0], bool)
    still[L:-L] = disp <= thr
    radius = max(REST_RADIUS_MM, REST_RADIUS_NOISE_FACTOR * sig)
    centres: list[np.ndarray] = []
    seq = []  # (rest, first, last) in time order
    for a, b in _runs(still):
        if b - a + 1 < 2 * L + 1:
            continue
        c = np.median(p[(a + b) // 2: b + 1], axis=0)
        k = next((j for j, cj in enumerate(centres) if np.linalg.norm(cj - c) <= radius), None)
        if k is None:
            centres.append(c)
            k = len(centres) - 1
        if seq and seq[-1][0] == k:
            seq[-1] = (k, seq[-1][1], b)
        else:
            seq.append((k, a, b))
    leave, arrive, fr, to, reached = [], [], [], [], []
    for j, ((ka, a0, a1), (kb, b0, _)) in enumerate(zip(seq[:-1], seq[1:])):
        seg = np.arange(a0, b0 + 1)
        d_a = np.linalg.norm(p[seg] - centres[ka], axis=1)
        d_b = np.linalg.norm(p[seg] - centres[kb], axis=1)
        inside_b = np.flatnonzero(d_b <= radius)
        if not inside_b.size:
            continue
        first_b = int(inside_b[0])
        inside_a = np.flatnonzero(d_a[:first_b] <= radius)
        if not inside_a.size:
            continue
        leave.append(int(rows[seg[int(inside_a[-1])]]))
        arrive.append(int(rows[seg[first_b]]))
        fr.append(ka)
        to.append(kb)
        reached.append(j + 1)
    # the still run at a rest starts STILL_HALF samples after the tool stopped and ends as many before it moves
    still = [int(rows[seq[j][2]] - rows[seq[j][1]]) + 1 + 2 * L if nxt == j else -1
             for j, nxt in zip(reached, [r - 1 for r in reached[1:]] + [-1])]
    arr = lambda x: np.asarray(x, dtype=np.int64)  # noqa: E731
    return Moves(np.array(centres).reshape(-1, 3), arr(leave), arr(arrive), arr(fr), arr(to), sig, radius,
                 arr(still))


@dataclass(frozen=True)
class MoveGroup:
    """Identical moves (same start and end rest): their sample counts and, when stamps were given, durations."""

    from_rest: int
    to_rest: int
    samples: np.ndarray
    stamp_s: np.ndarray | None

    @property
    def spread(self) -> int:
        return int(self.samples.max() - self.samples.min())

    @property
    def steady(self) -> bool:
        return self.spread <= max(MOVE_SPREAD_SAMPLES, MOVE_SPREAD_FRACTION * float(np.median(self.samples)))

    def to_dict(self) -> dict:
        d = {"from_rest": self.from_rest, "to_rest": self.to_rest, "n": int(self.samples.size),
             "samples": [int(x) for x in self.samples], "samples_min": int(self.samples.min()),
             "samples_max": int(self.samples.max()), "spread_samples": self.spread, "steady": self.steady}
        if self.stamp_s is not None:
            d["stamp_duration_s"] = [float(x) for x in self.stamp_s]
        return d


def identical_moves(moves: Moves, t_stamps=None) -> list[MoveGroup]:
    """Moves grouped by (start, end) rest, groups of two or more, in order of first occurrence."""
    t = None if t_stamps is None else np.asarray(t_stamps, dtype=float)
    out = []
    keys = list(dict.fromkeys(zip(moves.from_rest.tolist(), moves.to_rest.tolist())))
    for a, b in keys:
        sel = np.flatnonzero((moves.from_rest == a) & (moves.to_rest == b))
        if sel.size < 2:
            continue
        st = None if t is None else t[moves.arrive_row[sel]] - t[moves.leave_row[sel]]
        out.append(MoveGroup(int(a), int(b), moves.samples[sel], st))
    return out


@dataclass(frozen=True)
class StampEventCheck:
    """The stamps against the samples at every move and dwell: ``worst`` the event furthest off (or None)."""

    rate_hz: float
    resolution_s: float
    n_events: int
    n_off: int
    worst: dict | None

    @property
    def ok(self) -> bool:
        return self.n_events > 0 and self.n_off == 0

    def to_dict(self) -> dict:
        return {"rate_hz": self.rate_hz, "stamp_resolution_s": self.resolution_s, "n_events": self.n_events,
                "n_disagreeing": self.n_off, "worst": self.worst}


def stamps_against_moves(t_stamps, moves: Moves, rate_hz: float, resolution_s: float) -> StampEventCheck:
    """Does every move and every dwell last, by the stamps, its sample count / ``rate_hz``?

    Allowed: the stamps' resolution (a stamp floors the time at each end)
    plus :data:`STAMP_TOLERANCE_FRACTION` of the duration.
    """
    t = np.asarray(t_stamps, dtype=float)
    a = np.concatenate([moves.leave_row, moves.arrive_row[:-1]])
    b = np.concatenate([moves.arrive_row, moves.leave_row[1:]])
    kind = ["move"] * moves.leave_row.size + ["dwell"] * max(moves.leave_row.size - 1, 0)
    d = t[b] - t[a]
    e = (b - a) / float(rate_hz)
    off = np.abs(d - e) - (resolution_s + STAMP_TOLERANCE_FRACTION * e)
    bad = np.flatnonzero(off > 0)
    worst = None
    if a.size:
        k = int(np.argmax(off))
        worst = {"kind": kind[k], "row_from": int(a[k]), "row_to": int(b[k]), "samples": int(b[k] - a[k]),
                 "stamp_duration_s": float(d[k]), "duration_at_rate_s": float(e[k])}
    return StampEventCheck(float(rate_hz), float(resolution_s), int(a.size), int(bad.size), worst)


@dataclass(frozen=True)
class DwellRate:
    """The sample rate the dwells allow with the program's wait ``wait_s``.

    ``interval_hz`` the rates every dwell allows; ``candidates_hz`` the
    emScon rates in it; ``rate_hz`` and ``u_rate_hz`` (standard uncertainty)
    when one rate follows, else None and ``reason``.
    """

    wait_s: float
    dwell_samples: np.ndarray
    interval_hz: tuple[float, float] | None
    candidates_hz: tuple[float, ...]
    rate_hz: float | None
    u_rate_hz: float | None
    basis: str
    reason: str

    def to_dict(self) -> dict:
        return {"wait_s": self.wait_s, "dwell_samples": [int(x) for x in self.dwell_samples],
                "interval_hz": None if self.interval_hz is None else [float(x) for x in self.interval_hz],
                "emscon_candidates_hz": [float(x) for x in self.candidates_hz], "rate_hz": self.rate_hz,
                "u_rate_hz": self.u_rate_hz, "basis": self.basis, "reason": self.reason}


def emscon_rates_hz(lo: float, hi: float) -> tuple[float, ...]:
    """The emScon rates ``1000 / k`` Hz within [lo, hi], highest first."""
    return tuple(EMSCON_BASE_HZ / k for k in range(1, EMSCON_MAX_K + 1) if lo <= EMSCON_BASE_HZ / k <= hi)


def rate_from_dwells(dwell_samples, wait_s: float) -> DwellRate:
    """The rate from dwells of ``dwell_samples`` rows each, the program waiting ``wait_s`` at every stop.

    Every dwell lasts between ``wait - DWELL_SHORT_S`` and ``wait * (1 +
    DWELL_LONG_FRACTION) + DWELL_LONG_S``; the rates that fit all dwells form
    an interval. One emScon rate in it: that rate (its uncertainty the
    tracker's clock). None: the middle of the interval when it is narrow
    (within :data:`MAX_CONTINUOUS_HALF_FRACTION`). Several, or a wide
    interval, or none at all: no rate, with the reason.
    """
    if not (isinstance(wait_s, (int, float)) and math.isfinite(wait_s) and wait_s > DWELL_SHORT_S):
        raise DataError(f"the program's wait (--dwell-s) must be a number > {DWELL_SHORT_S:g} s, got {wait_s!r}")
    D = np.asarray(dwell_samples, dtype=float)
    w = float(wait_s)
    if D.size == 0:
        return DwellRate(w, D, None, (), None, None, "", "no dwell between two moves in the stream")
    long_s = w * (1.0 + DWELL_LONG_FRACTION) + DWELL_LONG_S
    lo = float(np.max(D) / long_s)
    hi = float(np.min(D) / (w - DWELL_SHORT_S))
    span = f"dwells of {int(D.min())}-{int(D.max())} samples with a wait of {w:g} s"
    if lo > hi:
        return DwellRate(w, D, None, (), None, None, "",
                         f"{span} fit no one rate: they differ by more than the approach and the controller's "
                         f"overhead explain ({w - DWELL_SHORT_S:g}-{long_s:g} s a dwell)")
    cands = emscon_rates_hz(lo, hi)
    if len(cands) == 1:
        r = cands[0]
        k = round(EMSCON_BASE_HZ / r)
        return DwellRate(w, D, (lo, hi), cands, r, CLOCK_REL_U * r,
                         f"emScon rate 1000/{k} Hz, the only one in {lo:.4g}-{hi:.4g} Hz ({span})", "")
    if len(cands) > 1:
        return DwellRate(w, D, (lo, hi), cands, None, None, "",
                         f"{span} fit the emScon rates " + ", ".join(f"{c:.4g}" for c in cands)
                         + " Hz alike")
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    if half <= MAX_CONTINUOUS_HALF_FRACTION * mid:
        return DwellRate(w, D, (lo, hi), (), mid, half / math.sqrt(3.0),
                         f"the middle of {lo:.4g}-{hi:.4g} Hz ({span}; no emScon rate 1000/k in it)", "")
    return DwellRate(w, D, (lo, hi), (), None, None, "",
                     f"{span} allow {lo:.4g}-{hi:.4g} Hz, no emScon rate 1000/k among them and too wide to use")
