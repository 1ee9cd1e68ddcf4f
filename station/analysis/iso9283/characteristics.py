"""ISO 9283 pose characteristics, their verdicts, and the result object.

Formulas are those of seed 000 (section 3), equation numbers as there:

* AP, position accuracy, eq. (1): distance from the commanded position to the
  barycentre of the attained positions.
* RP, position repeatability, eq. (2): ``l_bar + 3 S_l``.
* POS, position overshoot, eq. (5), and PST, position stabilisation time,
  eq. (6), inside a limit band that is either the pose's own RP or a value of
  the manufacturer (seed 3.2.3: 0.5 mm for the NACHI 8608).
* vAP, multi-directional position accuracy variation, eq. (7).
* AD and RD, distance accuracy and repeatability, eqs. (8)-(9).
* MPT, minimum posing time, eq. (10).

Beyond the seed, where the data carry them (ISO 9283 clauses on the same
pattern): orientation accuracy and repeatability (a, b, c) from 6-DOF data
and the multi-directional orientation accuracy variation vAP_a, vAP_b, vAP_c
(eq. (7) per angle, :func:`multidirectional_orientation`);
drift of AP and RP over a long run; path accuracy AT and repeatability RT of
linear paths.

:func:`analyze_iso9283` runs the whole chain on a stream: extraction
(:mod:`station.analysis.iso9283.extraction`), every characteristic the data
allow, verdicts against limits.  Every number carries its ``n`` and the stream
rows it came from; what could not be computed is ``None`` with a reason in
``warnings`` and ``partial`` set, never a silent number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace

import numpy as np

from station import characteristics as table
from station.analysis.iso9283.extraction import (
    STATUS_ASSIGNED,
    StopStatus,
    STATUS_NAMES,
    Extraction,
    extract_validated,
    validate_stream,
)
from station.errors import ConfigError, DataError, InsufficientDataError
from station.numeric import finite_list, finite_or_none
from station.verdict import Outcome, combine

#: ISO 9283 prescribes 30 cycles for AP and RP
ISO_CYCLES = 30
#: a sentence names at most this many poses (a stop list may hold 100,000): the rest are counted
MOST_LISTED = 12


def listed(items, most: int = MOST_LISTED) -> str:
    """``items`` joined by commas, the first ``most`` of them and ``and N more`` beyond."""
    items = list(items)
    if len(items) <= most:
        return ", ".join(items)
    return ", ".join(items[:most]) + f" and {len(items) - most} more"


def fold_warnings(warnings: list, flagged: list, summary: str, most: int = MOST_LISTED) -> list:
    """``warnings`` with the entries at the indices ``flagged`` (one per pose, of one kind) replaced by one
    ``summary`` where there are more than ``most`` of them: a stop list of 100,000 poses of 3 cycles gave 100,000
    lines of "3 cycles; ISO 9283 prescribes 30"."""
    if len(flagged) <= most:
        return warnings
    drop = set(flagged)
    out = [w for i, w in enumerate(warnings) if i not in drop]
    out.insert(flagged[0], summary)
    return out



# --------------------------------------------------------------------------
# result types
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class PoseAccuracy:
    """Eq. (1).  ``rows``: stream rows of the n attained poses used."""

    AP_mm: float
    APx_mm: float
    APy_mm: float
    APz_mm: float
    mean_mm: np.ndarray  # (3,)
    n: int
    rows: np.ndarray  # (n,)


@dataclass(frozen=True)
class PoseRepeatability:
    """Eq. (2): ``RP = l_bar + 3 S_l``; ``l_mm`` (n,) distances to the barycentre."""

    RP_mm: float
    l_bar_mm: float
    S_l_mm: float
    l_mm: np.ndarray
    n: int
    rows: np.ndarray


@dataclass(frozen=True)
class OvershootSettling:
    """Eqs. (5)-(6) for one pose over its n stops.

    ``POS_j_mm``/``PST_j_s`` per stop; ``row_entry`` first entry into the
    band, ``row_settled`` the entry after which the tool stays inside,
    ``row_max`` the sample of the largest excursion (-1 if none).
    ``incomplete`` marks stops whose approach has a beam break after the move's
    speed peak, and the rest before the first move (no approach in the
    stream); they are left out of POS and PST.
    """

    POS_mm: float | None
    PST_s: float | None
    band_mm: float
    band_source: str  # "own_RP" or "limit"
    POS_j_mm: np.ndarray
    PST_j_s: np.ndarray
    row_entry: np.ndarray
    row_settled: np.ndarray
    row_max: np.ndarray
    rows: np.ndarray  # attained pose of each stop
    incomplete: np.ndarray
    n: int  # complete stops used

    @property
    def approach(self) -> str | None:
        """``"overshoot"`` when POS > 0, ``"overdamped"`` when 0 (seed 3.2.3)."""
        if self.POS_mm is None:
            return None
        return "overshoot" if self.POS_mm > 0 else "overdamped"


@dataclass(frozen=True)
class ApproachGroup:
    """Attained poses of one pose approached from one direction."""

    label: str
    direction: np.ndarray  # (3,) mean unit approach vector
    mean_mm: np.ndarray  # (3,)
    n: int
    rows: np.ndarray
    #: (n, 3) the tool's angles a, b, c of the stops less the pose's reference orientation, rad (6-DOF data)
    angles_rad: np.ndarray | None = None


@dataclass(frozen=True)
class MultiDirectional:
    """Eq. (7): largest distance between the barycentres of the approach directions.

    ``vAP_mm`` is None with fewer than three directions (the seed's '-');
    ``vAP_any_mm`` is the same formula over whatever directions exist (>= 2).
    """

    vAP_mm: float | None
    vAP_any_mm: float | None
    groups: tuple[ApproachGroup, ...]
    pair: tuple[str, str] | None
    #: (3,) vAP_a, vAP_b, vAP_c of 6-DOF data with three directions or more, rad (else None)
    vAP_rad: np.ndarray | None = None

    @property
    def n_directions(self) -> int:
        return len(self.groups)


@dataclass(frozen=True)
class OrientationAR:
    """Orientation accuracy and repeatability about a, b, c (rad inside)."""

    AP_rad: np.ndarray | None  # (3,) mean minus commanded, None without commanded orientation
    RP_rad: np.ndarray  # (3,) 3 S per angle
    mean_rad: np.ndarray
    S_rad: np.ndarray
    n: int
    rows: np.ndarray


@dataclass(frozen=True)
class Drift:
    """AP and RP in consecutive blocks of cycles; drift = last block vs first."""

    dAP_mm: float
    dRP_mm: float
    shift_mm: float  # distance between the first and last block barycentres
    block_t_s: np.ndarray  # (B,) mean time of each block
    AP_mm: np.ndarray  # (B,)
    RP_mm: np.ndarray  # (B,)
    n_per_block: np.ndarray  # (B,)


@dataclass(frozen=True)
class DistanceAR:
    """Eqs. (8)-(9) between the attained poses of two poses in the same cycle."""

    pose_a: str
    pose_b: str
    Dc_mm: float
    AD_mm: float
    RD_mm: float | None  # +/- 3 S_D, given as the positive half width
    D_mm: np.ndarray  # (n,)
    cycles: np.ndarray
    rows_a: np.ndarray
    rows_b: np.ndarray
    n: int


@dataclass(frozen=True)
class PosingTime:
    """Eq. (10): mean of the first ``n_repeats`` posing times of one move.

    A posing time runs from the last sample inside the start pose's band
    before the move to the sample after which the tool stays inside the end
    pose's band.
    """

    from_pose: str
    to_pose: str
    MPT_s: float | None
    times_s: np.ndarray  # (n_available,)
    row_leave: np.ndarray
    row_settled: np.ndarray
    n: int  # used
    n_available: int


@dataclass(frozen=True)
class PathAR:
    """Path accuracy AT and repeatability RT of a linear move (ISO 9283 path clauses).

    The attained paths are cut by ``m`` planes normal to the commanded line at
    ``plane_s_mm`` from its start; AT_i is the distance of the barycentre of the
    n crossing points from the commanded point, RT_i = l_bar + 3 S_l of the
    crossing points about their barycentre; AT and RT are the largest.
    """

    from_pose: str
    to_pose: str
    AT_mm: float
    RT_mm: float | None
    plane_s_mm: np.ndarray
    AT_i_mm: np.ndarray
    RT_i_mm: np.ndarray
    n: int
    rows_from: np.ndarray
    rows_to: np.ndarray
    #: (n, m, 3) the traversals' crossing points of the planes (for the uncertainty of AT and RT)
    crossings_mm: np.ndarray | None = None


@dataclass(frozen=True)
class LeftOut:
    """A stop left out of one or more statistics, and why.

    ``row``/``t_s``: the stop's attained sample; ``pose``: its pose (the
    nearest one when it has none); ``cycle`` -1 when it has none;
    ``statistics``: what it is left out of (``"all"`` or e.g. ``"POS, PST"``).
    """

    row: int
    t_s: float
    pose: str
    cycle: int
    statistics: str
    reason: str


@dataclass(frozen=True)
class LimitCheck:
    """One characteristic of one subject judged against its limit (its outcome a :class:`station.verdict.Outcome`)."""

    characteristic: str  # a key of the characteristics table (station.characteristics)
    subject: str  # pose name, "P2-P4", "P1->P2"
    value: float | None
    limit: float
    #: PASS, FAIL, or NOT_DECIDED (not computed, or, under the guarded rule, in the guard band)
    outcome: Outcome
    note: str = ""
    #: the figure's uncertainty (:class:`station.analysis.uncertainty.FigureUncertainty`) when one was asked
    uncertainty: object | None = None
    #: the decision rule that set ``outcome`` ("simple" or "guarded"; None: the plain comparison, no budget)
    rule: str | None = None
    #: under "guarded": (limit - U, limit + U)
    guard_band: tuple[float, float] | None = None

    @property
    def passed(self) -> bool | None:
        """As the JSON's and the store's ``passed``: True, False, None (not decided)."""
        return self.outcome.passed


@dataclass(frozen=True)
class PoseResult:
    """Everything about one commanded pose."""

    name: str
    commanded_mm: np.ndarray
    attained_mm: np.ndarray  # (n, 3) primary-direction attained poses, time order
    attained_t_s: np.ndarray
    attained_row: np.ndarray
    attained_cycle: np.ndarray
    accuracy: PoseAccuracy | None
    repeatability: PoseRepeatability | None
    overshoot: OvershootSettling | None
    multidirectional: MultiDirectional
    orientation: OrientationAR | None
    drift: Drift | None

    @property
    def n_cycles(self) -> int:
        return int(self.attained_row.size)


class Judged:
    """A result whose ``verdicts`` (:class:`LimitCheck`) judge it: their one outcome, and as ``passed``."""

    verdicts: tuple[LimitCheck, ...]

    @property
    def outcome(self) -> Outcome | None:
        """The outcome of every limit asked (None: no limits given)."""
        return overall_outcome(self.verdicts)

    @property
    def passed(self) -> bool | None:
        """All verdicts passed (None: no limits given, or one could not be evaluated)."""
        return None if self.outcome is None else self.outcome.passed


@dataclass(frozen=True)
class Iso9283Result(Judged):
    """The results of one ISO 9283 analysis; :meth:`to_dict` gives the JSON."""

    poses: dict[str, PoseResult]
    distances: tuple[DistanceAR, ...]
    posing_times: tuple[PosingTime, ...]
    paths: tuple[PathAR, ...]
    extraction: Extraction
    verdicts: tuple[LimitCheck, ...]
    limits: dict[str, float]
    warnings: tuple[str, ...]
    partial: bool
    iso_conformant: bool  # every pose has >= 30 cycles, nothing missing, every limit decided
    stream_span_s: tuple[float, float] = field(default=(math.nan, math.nan))
    #: why the run is not ISO conformant, one sentence each (empty when it is)
    iso_reasons: tuple[str, ...] = ()
    #: every stop left out of a statistic, with the reason, in time order
    left_out: tuple[LeftOut, ...] = ()
    #: {(characteristic, subject): FigureUncertainty} when a budget was stated (station.analysis.iso9283.uncertainty)
    uncertainties: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-able dict with stable keys (units in the key names: mm, s, deg)."""
        return _result_to_dict(self)


# --------------------------------------------------------------------------
# the formulas (pure, validated)
# --------------------------------------------------------------------------


def _as_points(a, name):
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise DataError(f"{name} must have shape (n, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{name} contains NaN or inf")
    return a


def position_accuracy(attained_mm, commanded_mm, rows=None) -> PoseAccuracy:
    """Position accuracy AP, seed eq. (1).

    Parameters
    ----------
    attained_mm : array_like, shape (n, 3)
    commanded_mm : array_like, shape (3,)
    rows : array_like of int, shape (n,), optional
        Stream rows of the attained poses (carried into the result).
    """
    a = _as_points(attained_mm, "attained_mm")
    c = np.asarray(commanded_mm, dtype=float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise DataError(f"commanded_mm must be 3 finite numbers, got {c!r}")
    if a.shape[0] < 1:
        raise InsufficientDataError("AP needs at least 1 attained pose, got 0")
    m = a.mean(axis=0)
    d = m - c
    return PoseAccuracy(float(np.linalg.norm(d)), float(d[0]), float(d[1]), float(d[2]), m, a.shape[0],
                        _rows(rows, a.shape[0]))


def position_repeatability(attained_mm, rows=None) -> PoseRepeatability:
    """Position repeatability RP = l_bar + 3 S_l, seed eq. (2); needs n >= 2."""
    a = _as_points(attained_mm, "attained_mm")
    n = a.shape[0]
    if n < 2:
        raise InsufficientDataError(f"RP needs at least 2 attained poses, got {n}")
    l = np.linalg.norm(a - a.mean(axis=0), axis=1)
    lb = float(l.mean())
    S = float(np.sqrt(np.sum((l - lb) ** 2) / (n - 1)))
    return PoseRepeatability(lb + 3.0 * S, lb, S, l, n, _rows(rows, n))


def multidirectional_accuracy(means_mm) -> tuple[float, tuple[int, int]]:
    """vAP, seed eq. (7): largest distance between direction barycentres (k >= 2).

    Returns (vAP_mm, (h, k)) with the pair of directions that gives it.
    """
    m = _as_points(means_mm, "means_mm")
    if m.shape[0] < 2:
        raise InsufficientDataError(f"vAP needs at least 2 approach directions, got {m.shape[0]}")
    d = np.linalg.norm(m[:, None, :] - m[None, :, :], axis=2)
    h, k = np.unravel_index(int(np.argmax(d)), d.shape)
    return float(d[h, k]), (int(min(h, k)), int(max(h, k)))


def multidirectional_orientation(group_means_rad) -> np.ndarray:
    """Orientation vAP per angle: eq. (7) applied to the angles a, b, c (ISO 9283 7.2.2), the largest
    difference between the directions' mean angles, ``vAP_a = max_h a_bar_h - min_h a_bar_h`` (so for b, c).

    ``group_means_rad`` (k, 3): the mean angles of k >= 2 directions, as deviations from one reference (so
    that no difference wraps); returns (3,) rad.
    """
    m = np.asarray(group_means_rad, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or not np.all(np.isfinite(m)):
        raise DataError(f"group_means_rad must be finite with shape (k, 3), got {m.shape}")
    if m.shape[0] < 2:
        raise InsufficientDataError(f"orientation vAP needs at least 2 approach directions, got {m.shape[0]}")
    return m.max(axis=0) - m.min(axis=0)


def distance_accuracy(D_mm, Dc_mm) -> tuple[float, float | None]:
    """AD = mean(D) - Dc, eq. (8), and RD = 3 S_D, eq. (9) (None for n < 2)."""
    D = np.asarray(D_mm, dtype=float)
    if D.ndim != 1 or D.size < 1 or not np.all(np.isfinite(D)):
        raise InsufficientDataError(f"AD needs at least 1 finite attained distance, got {D.size}")
    AD = float(D.mean() - float(Dc_mm))
    RD = float(3.0 * np.std(D, ddof=1)) if D.size >= 2 else None
    return AD, RD


def minimum_posing_time(times_s, n_repeats: int = 3) -> float:
    """MPT, eq. (10): the mean of the first ``n_repeats`` posing times."""
    x = np.asarray(times_s, dtype=float)
    if x.ndim != 1 or x.size < n_repeats:
        raise InsufficientDataError(f"MPT needs {n_repeats} posing times, got {x.size}")
    return float(np.mean(x[:n_repeats]))


class _BandRegion:
    """Distance of every sample to the attained pose of the stop that owns it.

    Stop k owns the samples ``owner_start[k] .. owner_start[k+1]-1`` (the last
    one up to ``region_end``); a sample is inside when ``D <= band[k]``.  The
    band is entered and left at few samples, so the sorted lists of entries and
    exits turn "first entry after s", "last entry before e" and "first exit
    after c" into one ``searchsorted`` each for all stops.  Indices in and out
    are stream indices.
    """

    def __init__(self, t, xyz, owner_start, region_end, ref_mm, band_mm):
        owner_start = np.asarray(owner_start, dtype=np.int64)
        if owner_start.size and (np.any(np.diff(owner_start) <= 0) or owner_start[-1] > region_end):
            raise DataError("stops must be in time order with disjoint sample ranges")
        self.t = t
        self.r0 = r0 = int(owner_start[0]) if owner_start.size else 0
        r1 = int(region_end) + 1
        lens = np.diff(np.append(owner_start, r1))
        self.lens = lens
        D = np.repeat(ref_mm[:, 0], lens)
        np.subtract(xyz[r0:r1, 0], D, out=D)
        D *= D
        for k in (1, 2):
            tmp = np.repeat(ref_mm[:, k], lens)
            np.subtract(xyz[r0:r1, k], tmp, out=tmp)
            tmp *= tmp
            D += tmp
            del tmp
        np.sqrt(D, out=D)
        self.D = D
        inside = D <= np.repeat(np.asarray(band_mm, dtype=float), lens)
        change = np.flatnonzero(inside[1:] != inside[:-1]) + 1
        self.enters = change[inside[change]]  # first sample inside after outside
        self.exits = change[~inside[change]]  # first sample outside after inside
        self.inside = inside

    def approach(self, owner, i_from, i_to):
        """Eqs. (5)-(6) on each range ``i_from[k] .. i_to[k]`` (inside the range of ``owner[k]``).

        ``i_to`` must be inside the band (the attained pose is).  Returns dict
        of (K,) arrays: POS_mm, PST_s, i_entry, i_settled, i_max (-1 where
        nothing left the band after the entry).
        """
        s = np.asarray(i_from, dtype=np.int64) - self.r0
        e = np.asarray(i_to, dtype=np.int64) - self.r0
        K = s.size
        en = self.enters
        if K and not self.inside[e].all():
            raise DataError("approach: an attained pose lies outside its own band")
        nxt = np.searchsorted(en, s, side="left")
        entry = np.where(self.inside[s], s, en[np.minimum(nxt, max(en.size - 1, 0))] if en.size else s)
        last = np.searchsorted(en, e, side="right") - 1  # last entry at or before e
        last_en = np.where(last >= 0, en[np.maximum(last, 0)] if en.size else -1, -1)
        has_ex = last_en > entry
        settled = np.where(has_ex, last_en, entry)
        pos = np.zeros(K)
        i_max = np.full(K, -1, dtype=np.int64)
        k = np.flatnonzero(has_ex)
        if k.size:
            # between the entry and the settling every sample outside the band is
            # farther than any inside it, so the plain maximum is the overshoot
            bounds = np.empty(2 * k.size, dtype=np.int64)
            bounds[0::2] = entry[k]
            bounds[1::2] = settled[k]
            pos[k] = np.maximum.reduceat(self.D, bounds)[0::2]
            # sample of the largest excursion: the first hit of that value after the entry
            per_owner = np.full(self.lens.size, np.nan)
            per_owner[np.asarray(owner)[k]] = pos[k]
            hits = np.flatnonzero(self.D == np.repeat(per_owner, self.lens))
            i_max[k] = hits[np.searchsorted(hits, entry[k], side="left")] + self.r0
        return dict(
            POS_mm=pos,
            PST_s=self.t[settled + self.r0] - self.t[entry + self.r0],
            i_entry=entry + self.r0,
            i_settled=settled + self.r0,
            i_max=i_max,
        )

    def leave(self, i_from, i_until):
        """Last sample inside the band before the tool first leaves it after ``i_from``.

        -1 where it does not leave before ``i_until``.
        """
        c = np.asarray(i_from, dtype=np.int64) - self.r0
        u = np.asarray(i_until, dtype=np.int64) - self.r0
        ex = self.exits
        if ex.size == 0:
            return np.full(c.size, -1, dtype=np.int64)
        j = np.searchsorted(ex, c, side="right")
        f = ex[np.minimum(j, ex.size - 1)]
        ok = (j < ex.size) & (f <= u)
        return np.where(ok, f - 1 + self.r0, -1)


def overshoot_settling_stops(t, xyz, i_from, i_attained, band_mm):
    """Per-stop overshoot and settling, eqs. (5)-(6), vectorised over K stops.

    For stop k the samples ``i_from[k] .. i_attained[k]`` (the deceleration
    phase up to the attained pose) are compared with the attained position
    within the band ``band_mm[k]``: the first sample inside the band is the
    entry ``m``; every later sample outside it counts for the overshoot
    ``POS_k = max D`` (0 if none leaves); the settling time runs from the entry
    to the sample after the last one outside (``PST_k = t_n - t_m``).

    Parameters
    ----------
    t : ndarray (N,), xyz : ndarray (N, 3)
    i_from, i_attained : ndarray of int, (K,)
        In time order, ``i_from[k] <= i_attained[k] < i_from[k+1]``.
    band_mm : ndarray (K,)

    Returns
    -------
    dict of (K,) arrays: POS_mm, PST_s, i_entry, i_settled, i_max (-1 if none)
    """
    i_from = np.asarray(i_from, dtype=np.int64)
    i_att = np.asarray(i_attained, dtype=np.int64)
    K = i_att.size
    if K == 0:
        z = np.zeros(0)
        zi = np.zeros(0, np.int64)
        return dict(POS_mm=z, PST_s=z, i_entry=zi, i_settled=zi, i_max=zi)
    if np.any(i_from > i_att) or np.any(i_att[:-1] >= i_from[1:]):
        raise DataError("overshoot: each range must start at or before its attained pose, ranges in time order")
    reg = _BandRegion(t, xyz, i_from, int(i_att[-1]), xyz[i_att], band_mm)
    return reg.approach(np.arange(K), i_from, i_att)


def path_crossings(xyz, i_from, i_to, start_mm, unit, s_planes):
    """Where each attained path first crosses the planes normal to its commanded line.

    Parameters
    ----------
    xyz : ndarray (N, 3)
    i_from, i_to : ndarray of int (K,)
        Sample range of each traversal, in time order and disjoint.
    start_mm : ndarray (K, 3), unit : ndarray (K, 3)
        Commanded line start and unit direction of each traversal.
    s_planes : ndarray (m,) or (K, m)
        Plane positions along the line, mm from its start.

    Returns
    -------
    ndarray (K, m, 3): crossing points (linear interpolation between the two
    samples either side), NaN where the path never reaches a plane.
    """
    i_from = np.asarray(i_from, dtype=np.int64)
    i_to = np.asarray(i_to, dtype=np.int64)
    K = i_from.size
    sp = np.asarray(s_planes, dtype=float)
    sp = np.broadcast_to(sp, (K, sp.shape[-1])) if sp.ndim == 1 else sp
    m = sp.shape[1]
    if K == 0:
        return np.zeros((0, m, 3))
    if np.any(i_to < i_from) or np.any(i_to[:-1] >= i_from[1:]):
        raise DataError("path_crossings: traversals must be in time order and disjoint")
    r0, r1 = int(i_from[0]), int(i_to[-1]) + 1
    lens = np.diff(np.append(i_from, r1))
    # s = (p - A).u = p.u - A.u: positions are ~1e3 mm, s needs ~1e-6 mm, no cancellation issue
    s = np.repeat(unit[:, 0], lens)
    s *= xyz[r0:r1, 0]
    for k in (1, 2):
        tmp = np.repeat(unit[:, k], lens)
        tmp *= xyz[r0:r1, k]
        s += tmp
        del tmp
    s -= np.repeat(np.einsum("ij,ij->i", start_mm, unit), lens)
    span = 2.0 * float(np.max(np.abs(s))) + 2.0 * float(np.max(np.abs(sp))) + 1.0
    # samples after a traversal's end (until the next one starts) take no part
    active = np.repeat(np.tile(np.array([True, False]), K),
                       np.stack([i_to - i_from + 1, lens - (i_to - i_from + 1)], axis=1).ravel())
    s[~active] = -np.inf
    del active
    # running maximum per traversal: shift each traversal above the previous one
    s += np.repeat(np.arange(K) * span, lens)
    np.maximum.accumulate(s, out=s)
    targets = (sp + (np.arange(K) * span)[:, None]).ravel()
    pos = np.searchsorted(s, targets, side="left")  # first sample whose running max reaches the plane
    del s
    kk = np.repeat(np.arange(K), m)
    ok = (pos > i_from[kk] - r0) & (pos <= i_to[kk] - r0)
    out = np.full((K * m, 3), np.nan)
    # j1 reaches the plane first, so the sample before it lies below the plane
    j1 = pos[ok] + r0
    j0 = j1 - 1
    kok = kk[ok]
    p0, p1 = xyz[j0], xyz[j1]
    s0 = np.einsum("ij,ij->i", p0 - start_mm[kok], unit[kok])
    s1 = np.einsum("ij,ij->i", p1 - start_mm[kok], unit[kok])
    w = np.where(s1 != s0, (sp.ravel()[ok] - s0) / np.where(s1 != s0, s1 - s0, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)
    out[ok] = p0 + w[:, None] * (p1 - p0)
    return out.reshape(K, m, 3)


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------


def _rows(rows, n):
    if rows is None:
        return np.full(n, -1, dtype=np.int64)
    r = np.asarray(rows, dtype=np.int64)
    if r.shape != (n,):
        raise DataError(f"rows must have shape ({n},), got {r.shape}")
    return r


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def _direction_label(u):
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) >= math.cos(math.radians(20.0)):
        return ("+" if u[k] > 0 else "-") + "xyz"[k]
    return "(" + ",".join(f"{x:+.2f}" for x in u) + ")"


def _group_directions(units, clean, cos_tol):
    """Cluster approach unit vectors (loop over clusters): labels (n,), -1 if none."""
    n = units.shape[0]
    lab = np.full(n, -1, dtype=np.int64)
    reps = []
    todo = np.flatnonzero(clean)
    while todo.size:
        rep = units[todo[0]]
        member = units[todo] @ rep >= cos_tol
        member[0] = True  # a zero vector still ends the loop
        lab[todo[member]] = len(reps)
        reps.append(rep)
        todo = todo[~member]
    if reps:
        rest = np.flatnonzero(~clean)
        if rest.size:
            cosr = units[rest] @ np.array(reps).T
            lab[rest] = np.argmax(cosr, axis=1)
    return lab, len(reps)


def check_limits(limits) -> dict[str, float]:
    """Validate a ``{key: limit}`` mapping against the characteristics table (:func:`table.limit_levels`)."""
    out = {}
    known = table.limit_levels()
    for k, v in (limits or {}).items():
        if k not in known:
            raise ConfigError(f"unknown limit {k!r}; known: {', '.join(sorted(known))}")
        try:
            fv = float(v)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"limit {k} must be a number, got {v!r}") from exc
        if not (math.isfinite(fv) and fv >= 0):
            raise ConfigError(f"limit {k} must be finite and >= 0, got {v!r}")
        out[k] = fv
    return out


#: assignment tolerance without an AP limit, mm (a robot's uncompensated accuracy is a few mm)
DEFAULT_ASSIGN_TOL_MM = 25.0


def assignment_tolerance_mm(limits) -> float:
    """Largest distance from a stop to the commanded pose it is assigned to, from the limits, mm.

    With an AP limit (and an RP limit, 0 without): a robot within its limits
    puts every stop within ``AP + RP`` of the commanded pose (the barycentre
    lies within AP of it, eq. (1), and the stops within RP of the barycentre,
    eq. (2)); four times that still assigns the stops of a robot that fails
    by that much, so that it is judged FAIL rather than left undecided. Kept
    between 5 mm and :data:`DEFAULT_ASSIGN_TOL_MM` (the default without an AP
    limit): above it lie via points and pre-positions, which must not be taken
    for the pose. The extraction keeps at least 20 times the tracker's noise.
    """
    lim = check_limits(limits)
    if "AP_mm" not in lim:
        return DEFAULT_ASSIGN_TOL_MM
    return float(min(DEFAULT_ASSIGN_TOL_MM, max(5.0, 4.0 * (lim["AP_mm"] + lim.get("RP_mm", 0.0)))))


# --------------------------------------------------------------------------
# the whole analysis
# --------------------------------------------------------------------------


def analyze_iso9283(
    t_s,
    xyz_mm,
    commanded_mm,
    *,
    names=None,
    order=None,
    valid=None,
    orientation_rad=None,
    commanded_orientation_rad=None,
    limits=None,
    band_mm=None,
    distance_pairs="auto",
    linear_paths=False,
    n_planes: int = 9,
    mpt_repeats: int = 3,
    drift_block: int = 10,
    direction_tol_deg: float = 30.0,
    extraction: dict | None = None,
) -> Iso9283Result:
    """Every ISO 9283 pose characteristic of a tracker stream, with verdicts.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Device timestamps, s.
    xyz_mm : array_like, shape (N, 3)
        Tool positions in the frame of ``commanded_mm``, mm.
    commanded_mm : array_like, shape (P, 3)
        Commanded positions, mm.
    names, order, valid
        As in :func:`~station.analysis.pose_extraction.extract_attained_poses`.
    orientation_rad : array_like, shape (N, 3), optional
        Tool orientation angles a, b, c of 6-DOF data, rad.
    commanded_orientation_rad : array_like, shape (P, 3), optional
        Commanded a, b, c, rad (for orientation accuracy).
    limits : dict, optional
        ``{key: limit}`` with keys of the characteristics table (e.g. ``{"RP_mm": 0.5}``);
        each computed characteristic with a limit gets a verdict ``|value| <= limit``.
    band_mm : None, float or dict
        Limit band of POS/PST: None = each pose's own RP; a float = one value
        for every pose (the manufacturer's RP); a dict name -> value (poses
        not in it use their own RP).
    distance_pairs : "auto", None or sequence of (name, name)
        Pose pairs for AD/RD; "auto" = (P2, P4) when both exist.
    linear_paths : bool or sequence of (name, name)
        Moves whose commanded path is a straight line: AT/RT for them
        (True: every move between consecutive poses of the order).
    n_planes : int
        Planes normal to a path at which AT/RT are evaluated.
    mpt_repeats : int
        Repetitions averaged by eq. (10) (3 in ISO 9283).
    drift_block : int
        Cycles per block for the drift (needs at least two blocks).
    direction_tol_deg : float
        Approach directions closer than this are one direction (vAP).
    extraction : dict, optional
        Keyword options for the extraction (``window_s``, ``M``, ``Mp``, ...).

    Returns
    -------
    Iso9283Result
    """
    lim = check_limits(limits)
    if not (isinstance(n_planes, (int, np.integer)) and n_planes >= 1):
        raise ConfigError(f"n_planes must be an integer >= 1, got {n_planes!r}")
    if not (isinstance(mpt_repeats, (int, np.integer)) and mpt_repeats >= 1):
        raise ConfigError(f"mpt_repeats must be an integer >= 1, got {mpt_repeats!r}")
    if not (isinstance(drift_block, (int, np.integer)) and drift_block >= 2):
        raise ConfigError(f"drift_block must be an integer >= 2, got {drift_block!r}")
    n_rows = int(np.shape(t_s)[0]) if np.ndim(t_s) else 0
    extra = {} if orientation_rad is None else {"orientation_rad": orientation_rad}
    t, xyz, rows_used, extra = validate_stream(t_s, xyz_mm, valid, extra=extra)
    ori = extra.get("orientation_rad")
    if ori is not None and ori.shape != (t.size, 3):
        raise DataError(f"orientation_rad must have shape (N, 3), got {ori.shape}")
    ex = extract_validated(t, xyz, rows_used, n_rows, commanded_mm, names=names, order=order,
                           **(extraction or {}))
    P = len(ex.names)
    cori = None
    if commanded_orientation_rad is not None:
        cori = np.asarray(commanded_orientation_rad, dtype=float)
        if cori.shape != (P, 3) or not np.all(np.isfinite(cori)):
            raise DataError(f"commanded_orientation_rad must be finite with shape ({P}, 3), got {cori.shape}")
    run = _Stages(t, xyz, ex)
    bands = _limit_bands(band_mm, ex.names)
    pose_info = _stage_accuracy_repeatability(run, math.cos(math.radians(direction_tol_deg)))
    settle = _stage_settling(run, pose_info, bands)
    poses = _stage_pose_results(run, pose_info, settle, ori, cori, drift_block)
    dists = _stage_distances(run, pose_info, distance_pairs)
    k0, k1 = _consecutive_stops(run, settle)
    mts = _stage_posing_times(run, settle, k0, k1, mpt_repeats)
    paths = _stage_paths(run, k0, k1, linear_paths, n_planes)
    _stage_extraction_problems(run)
    left_out = _stage_left_out(run, pose_info, settle, dists)
    verdicts = _verdicts(lim, SimpleNamespace(poses=poses, distances=dists, posing_times=mts, paths=paths))
    if any(v.outcome is Outcome.NOT_DECIDED for v in verdicts):
        run.partial = True
    reasons = iso_conformance_reasons(poses, ex, verdicts, lim)
    return Iso9283Result(
        poses=poses, distances=tuple(dists), posing_times=tuple(mts), paths=tuple(paths), extraction=ex,
        verdicts=tuple(verdicts), limits=lim, warnings=tuple(run.warnings), partial=bool(run.partial),
        iso_conformant=not reasons, stream_span_s=(float(t[0]), float(t[-1])), iso_reasons=tuple(reasons),
        left_out=tuple(left_out),
    )


# --------------------------------------------------------------------------
# the stages of the analysis
# --------------------------------------------------------------------------


class _Stages:
    """What every stage reads (the stream and its extraction) and adds to (warnings, partial)."""

    def __init__(self, t: np.ndarray, xyz: np.ndarray, ex: Extraction) -> None:
        self.t, self.xyz, self.ex, self.st = t, xyz, ex, ex.stops
        self.names = ex.names
        self.cmd = ex.commanded_mm
        self.P = len(ex.names)
        self.warnings: list[str] = list(ex.warnings)
        self.partial = False
        self.breaks = _break_indices(ex)

    def warn(self, message: str, *, partial: bool = False) -> None:
        self.warnings.append(message)
        self.partial = self.partial or partial


def _limit_bands(band_mm, names) -> dict:
    """The POS/PST limit band per pose given as a limit (``{}``: every pose uses its own RP)."""
    if band_mm is None or isinstance(band_mm, dict):
        bdict = dict(band_mm or {})
        unknown = set(bdict) - set(names)
        if unknown:
            raise ConfigError(f"band_mm names unknown poses {sorted(unknown)}")
        for k, v in bdict.items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"band_mm[{k!r}] must be finite and > 0, got {v!r}")
        return bdict
    bv = float(band_mm)
    if not (math.isfinite(bv) and bv > 0):
        raise ConfigError(f"band_mm must be finite and > 0, got {band_mm!r}")
    return {n: bv for n in names}


def _stage_accuracy_repeatability(run: _Stages, cos_tol: float) -> dict:
    """Per pose: approach-direction groups, and AP (eq. (1)), RP (eq. (2)) of the main group."""
    st, cmd = run.st, run.cmd
    pose_info = {}
    for p, name in enumerate(run.names):  # loop over poses
        k_all = run.ex.assigned(p)
        init = st.initial[k_all]
        lab, ng = _group_directions(st.approach_unit[k_all], ~st.gap_in_approach[k_all] & ~init, cos_tol)
        lab[init] = -1
        groups = []
        for g in range(ng):
            kg = k_all[lab == g]
            u = st.approach_unit[kg].mean(axis=0)
            u /= max(np.linalg.norm(u), 1e-12)
            groups.append((kg, u))
        if groups:
            sizes = [kg.size for kg, _ in groups]
            gp = int(np.argmax(sizes))  # ties: the earliest group
        elif init.any():
            groups, gp = [(np.zeros(0, np.int64), np.zeros(3))], 0
        else:
            gp = -1
        if init.any():
            # the rest before the first move: no approach in the stream; it counts with the pose's main direction
            kg, u = groups[gp]
            groups[gp] = (np.sort(np.concatenate([k_all[init], kg])), u)
            lab[init] = gp
        kp = groups[gp][0] if groups else np.zeros(0, np.int64)
        a = st.position_mm[kp]
        rows = st.row[kp]
        moved = ~st.initial[kp]
        if moved.sum() >= 2 and not moved.all():
            # the rest's approach is unknown: say so when it does not look like the other stops
            others = position_repeatability(a[moved])
            d0 = float(np.linalg.norm(a[~moved][0] - a[moved].mean(axis=0)))
            if d0 > others.RP_mm:
                run.warn(f"{name}: the rest before the first move lies {d0:.3f} mm from the barycentre of the other "
                         f"{int(moved.sum())} stops, outside their RP {others.RP_mm:.3f} mm: it may have been "
                         "approached from another side (leave it out with initial_rest_stop=False, "
                         "--initial-rest skip)")
        acc = rep = None
        if kp.size >= 1:
            acc = position_accuracy(a, cmd[p], rows)
        else:
            run.warn(f"{name}: no attained pose, AP and RP not computed", partial=True)
        if kp.size >= 2:
            rep = position_repeatability(a, rows)
        elif kp.size == 1:
            run.warn(f"{name}: RP needs at least 2 attained poses, got 1", partial=True)
        if 0 < kp.size < ISO_CYCLES:
            run.warn(f"{name}: {kp.size} cycles; ISO 9283 prescribes {ISO_CYCLES}")
        pose_info[name] = dict(p=p, k_all=k_all, lab=lab, groups=groups, gp=gp, kp=kp, acc=acc, rep=rep)
    return pose_info


def _stage_settling(run: _Stages, pose_info: dict, bdict: dict) -> dict:
    """Every assigned stop gets its limit band, its overshoot and settling (POS/PST, needed for MPT too)."""
    st, t, xyz = run.st, run.t, run.xyz
    ka = np.flatnonzero(st.status == STATUS_ASSIGNED)
    band_of_pose = np.full(run.P, np.nan)
    band_src = {}
    for name, info in pose_info.items():
        if name in bdict:
            band_of_pose[info["p"]] = bdict[name]
            band_src[name] = "limit"
        elif info["rep"] is not None:
            band_of_pose[info["p"]] = info["rep"].RP_mm
            band_src[name] = "own_RP"
        else:
            band_src[name] = "own_RP"
    kb = ka[np.isfinite(band_of_pose[st.pose[ka]])]
    band_k = np.full(st.n, np.nan)
    band_k[kb] = band_of_pose[st.pose[kb]]
    reg = _BandRegion(t, xyz, st.i_phase_start, t.size - 1, st.position_mm, band_k) if st.n else None
    os_ = reg.approach(kb, st.i_phase_start[kb], st.i_center[kb]) if st.n else None
    brk_i = run.breaks
    first_brk = np.searchsorted(brk_i, st.i_phase_start[kb])
    inc = (np.searchsorted(brk_i, st.i_center[kb]) - first_brk) > 0
    if st.n and inc.any():
        # a break after the tool settled in the band lies inside the rest (the tool is in the band from the
        # settling to the attained pose): the approach was seen whole (a resumed run's stream starts again there)
        k = np.flatnonzero(inc)
        inc[k] = brk_i[first_brk[k]] < os_["i_settled"][k]
    noapp = st.initial[kb]  # the rest before the first move: no approach to judge
    settled_i = np.full(st.n, -1, np.int64)
    if st.n:
        settled_i[kb] = np.where(inc | noapp, -1, os_["i_settled"])
    return dict(band_of_pose=band_of_pose, band_src=band_src, kb=kb, os=os_, inc=inc, noapp=noapp,
                settled_i=settled_i,
                region=reg)


def _stage_pose_results(run: _Stages, pose_info: dict, settle: dict, ori, cori, drift_block: int) -> dict:
    """Per pose: POS/PST (eqs. (4)-(5)), vAP (eq. (3)), orientation, drift."""
    st, cmd, ex = run.st, run.cmd, run.ex
    kb, os_, inc, band_of_pose = settle["kb"], settle["os"], settle["inc"], settle["band_of_pose"]
    poses: dict[str, PoseResult] = {}
    for name, info in pose_info.items():
        p, kp = info["p"], info["kp"]
        sel = np.flatnonzero(np.isin(kb, kp))
        ovs = None
        if sel.size:
            good = ~(inc[sel] | settle["noapp"][sel])
            POS = float(np.max(os_["POS_mm"][sel][good])) if good.any() else None
            PST = float(np.mean(os_["PST_s"][sel][good])) if good.any() else None
            if inc[sel].any():
                run.warn(f"{name}: {int(inc[sel].sum())} approach(es) with a beam break left out of POS/PST")
            ovs = OvershootSettling(
                POS, PST, float(band_of_pose[p]), settle["band_src"][name], os_["POS_mm"][sel], os_["PST_s"][sel],
                ex.to_rows(os_["i_entry"][sel]), ex.to_rows(os_["i_settled"][sel]),
                np.where(os_["i_max"][sel] >= 0, ex.to_rows(np.maximum(os_["i_max"][sel], 0)), -1),
                st.row[kb[sel]], ~good, int(good.sum()),
            )
        elif kp.size:
            run.warn(f"{name}: no limit band (own RP not available), POS/PST not computed", partial=True)
        # vAP (and per angle with 6-DOF data: deviations from the commanded orientation or the first stop's)
        gl = []
        ref_o = None
        if ori is not None and kp.size:
            ref_o = cori[p] if cori is not None else ori[st.i_center[kp[0]]]
        for kg, u in info["groups"]:
            if not kg.size:
                continue
            ga = None if ref_o is None else _wrap(ori[st.i_center[kg]] - ref_o)
            gl.append(ApproachGroup(_direction_label(u) if np.any(u) else "start", u,
                                    st.position_mm[kg].mean(axis=0), int(kg.size), st.row[kg], ga))
        vap = vany = pair = vap_o = None
        if len(gl) >= 2:
            vany, (h, k) = multidirectional_accuracy(np.array([g.mean_mm for g in gl]))
            pair = (gl[h].label, gl[k].label)
            if len(gl) >= 3:
                vap = vany
                if ref_o is not None:
                    vap_o = multidirectional_orientation(np.array([g.angles_rad.mean(axis=0) for g in gl]))
        md = MultiDirectional(vap, vany, tuple(gl), pair, vap_o)
        # orientation
        oar = None
        if ori is not None and kp.size >= 2:
            ang = ori[st.i_center[kp]]
            ref = cori[p] if cori is not None else ang[0]
            dev = _wrap(ang - ref)
            mdev = dev.mean(axis=0)
            S = dev.std(axis=0, ddof=1)
            oar = OrientationAR(mdev if cori is not None else None, 3.0 * S, _wrap(ref + mdev), S, int(kp.size),
                                st.row[kp])
        # drift
        dr = None
        if kp.size >= 2 * drift_block:
            nb = kp.size // drift_block
            kblk = kp[: nb * drift_block].reshape(nb, drift_block)
            a = st.position_mm[kblk]  # (nb, block, 3): eqs. (1) and (2) per block
            mb = a.mean(axis=1)
            apb = np.linalg.norm(mb - cmd[p], axis=1)
            lb = np.linalg.norm(a - mb[:, None, :], axis=2)
            rpb = lb.mean(axis=1) + 3.0 * lb.std(axis=1, ddof=1)
            tb = st.t_s[kblk].mean(axis=1)
            shift = float(np.linalg.norm(mb[-1] - mb[0]))
            dr = Drift(float(abs(apb[-1] - apb[0])), float(abs(rpb[-1] - rpb[0])), shift, tb, apb, rpb,
                       np.full(nb, drift_block))
        poses[name] = PoseResult(
            name, cmd[p].copy(), st.position_mm[kp], st.t_s[kp], st.row[kp], st.cycle[kp],
            info["acc"], info["rep"], ovs, md, oar, dr,
        )
    return poses


def _stage_distances(run: _Stages, pose_info: dict, distance_pairs) -> list:
    """AD and RD (eqs. (8)-(9)) between the pose pairs, over the cycles where both were attained."""
    st, cmd, names = run.st, run.cmd, run.names
    dists = []
    if distance_pairs == "auto":
        distance_pairs = [("P2", "P4")] if {"P2", "P4"} <= set(names) else []
    for pa, pb in distance_pairs or []:
        for q in (pa, pb):
            if q not in names:
                raise ConfigError(f"distance pair names unknown pose {q!r}")
        ia, ib = names.index(pa), names.index(pb)
        ka_, kb_ = pose_info[pa]["kp"], pose_info[pb]["kp"]
        ca, cb = st.cycle[ka_], st.cycle[kb_]
        common, ja, jb = np.intersect1d(ca, cb, return_indices=True)
        Dc = float(np.linalg.norm(cmd[ia] - cmd[ib]))
        if common.size < 1:
            run.warn(f"AD/RD {pa}-{pb}: no cycle with both poses attained", partial=True)
            continue
        D = np.linalg.norm(st.position_mm[ka_[ja]] - st.position_mm[kb_[jb]], axis=1)
        AD, RD = distance_accuracy(D, Dc)
        if RD is None:
            run.warn(f"RD {pa}-{pb}: needs at least 2 cycles with both poses, got 1", partial=True)
        dists.append(DistanceAR(pa, pb, Dc, AD, RD, D, common, st.row[ka_[ja]], st.row[kb_[jb]], int(D.size)))
    return dists


def _consecutive_stops(run: _Stages, settle: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of assigned stops consecutive in the commanded order and in time, with no beam break between them
    but inside a rest (with ``settle``, :func:`_stage_settling`'s): in the first stop's rest before the tool
    leaves its band, or in the second's after the tool settled in its band. Such a break hides no part of the
    move: a dwell the beam missed part of, or a resumed run's stream, which starts again at the pose its last
    finished cycle ended at (the arm brought back there, unmeasured, before the cycle is redone)."""
    st = run.st
    ka = np.flatnonzero(st.status == STATUS_ASSIGNED)
    kseq = ka[np.argsort(st.seq[ka], kind="stable")]
    consec = np.flatnonzero((np.diff(st.seq[kseq]) == 1) & (np.diff(kseq) == 1))
    k0, k1 = kseq[consec], kseq[consec + 1]
    brk = run.breaks
    ok = (np.searchsorted(brk, st.i_center[k1]) - np.searchsorted(brk, st.i_center[k0])) == 0
    across = np.flatnonzero(~ok)
    if settle is not None and settle["region"] is not None and across.size:
        c0, c1 = st.i_center[k0[across]], st.i_center[k1[across]]
        left = settle["region"].leave(c0, c1)  # the last sample in the first pose's band before the tool leaves it
        arrived = settle["settled_i"][k1[across]]  # the tool settled in the second pose's band (-1: not seen)
        lo, hi = np.where(left >= 0, left, c0), np.where(arrived >= 0, arrived, c1)
        # no break in the move itself: between leaving the first band and settling in the second
        ok[across] = (left >= 0) & (hi >= lo) & (np.searchsorted(brk, hi) == np.searchsorted(brk, lo))
    return k0[ok], k1[ok]


def _stage_posing_times(run: _Stages, settle: dict, k0, k1, mpt_repeats: int) -> list:
    """Minimum posing time per move (eq. (10)): leaving the band of one pose to settling at the next."""
    st, t, ex, P, names = run.st, run.t, run.ex, run.P, run.names
    settled_i, band_of_pose = settle["settled_i"], settle["band_of_pose"]
    mts = []
    if not k0.size:
        return mts
    bprev = band_of_pose[st.pose[k0]]
    okb = np.isfinite(bprev) & (settled_i[k1] >= 0)
    k0b, k1b = k0[okb], k1[okb]
    leave = settle["region"].leave(st.i_center[k0b], st.i_phase_start[k1b] - 1)
    okl = leave >= 0
    k0b, k1b, leave = k0b[okl], k1b[okl], leave[okl]
    times = t[settled_i[k1b]] - t[leave]
    pairs = st.pose[k0b] * P + st.pose[k1b]
    for pr in np.unique(pairs):  # loop over moves
        sel = np.flatnonzero(pairs == pr)
        fa, fb = names[pr // P], names[pr % P]
        mpt = float(np.mean(times[sel[:mpt_repeats]])) if sel.size >= mpt_repeats else None
        if mpt is None:
            run.warn(f"MPT {fa}->{fb}: needs {mpt_repeats} posing times, got {sel.size}")
        mts.append(PosingTime(fa, fb, mpt, times[sel], ex.to_rows(leave[sel]),
                              ex.to_rows(settled_i[k1b[sel]]), min(sel.size, mpt_repeats), int(sel.size)))
    return mts


def _stage_paths(run: _Stages, k0, k1, linear_paths, n_planes: int) -> list:
    """Path accuracy and repeatability AT/RT of the moves commanded as straight lines."""
    st, cmd, xyz, P, names = run.st, run.cmd, run.xyz, run.P, run.names
    paths = []
    if not linear_paths:
        return paths
    if linear_paths is True:
        want = None
    else:
        want = set()
        for fa, fb in linear_paths:
            for q in (fa, fb):
                if q not in names:
                    raise ConfigError(f"linear path names unknown pose {q!r}")
            want.add(names.index(fa) * P + names.index(fb))
    if not k0.size:
        return paths
    pairs = st.pose[k0] * P + st.pose[k1]
    ok = np.ones(k0.size, bool) if want is None else np.isin(pairs, list(want))
    upairs = np.unique(pairs[ok])
    A = cmd[st.pose[k0[ok]]]
    B = cmd[st.pose[k1[ok]]]
    L = np.linalg.norm(B - A, axis=1)
    unit = (B - A) / np.maximum(L, 1e-12)[:, None]
    frac = np.arange(1, n_planes + 1) / (n_planes + 1)
    s_pl_all = L[:, None] * frac[None, :]
    # the traversals: from the start of the move to the attained end pose
    kk1 = k1[ok]
    cross = path_crossings(xyz, st.i_move_start[kk1], st.i_center[kk1], A, unit, s_pl_all)
    for pr in upairs:  # loop over moves
        m = np.flatnonzero(pairs[ok] == pr)
        s_pl = s_pl_all[m[0]]
        good = ~np.isnan(cross[m]).any(axis=(1, 2))
        fa, fb = names[pr // P], names[pr % P]
        if good.sum() < 1:
            run.warn(f"AT/RT {fa}->{fb}: no traversal crosses every plane", partial=True)
            continue
        cm = cross[m][good]
        bary = cm.mean(axis=0)  # (m, 3)
        cpt = A[m[0]][None, :] + s_pl[:, None] * unit[m[0]][None, :]
        at_i = np.linalg.norm(bary - cpt, axis=1)
        if cm.shape[0] >= 2:
            l = np.linalg.norm(cm - bary[None], axis=2)  # (n, m)
            rt_i = l.mean(axis=0) + 3 * l.std(axis=0, ddof=1)
            RT = float(rt_i.max())
        else:
            rt_i = np.full(n_planes, np.nan)
            RT = None
            run.warn(f"RT {fa}->{fb}: needs 2 traversals, got 1", partial=True)
        paths.append(PathAR(fa, fb, float(at_i.max()), RT, s_pl, at_i, rt_i, int(cm.shape[0]),
                            st.row[k0[ok][m][good]], st.row[k1[ok][m][good]], cm))
    return paths


def _stage_left_out(run: _Stages, pose_info: dict, settle: dict, dists) -> list[LeftOut]:
    """Every stop that some statistic does not use, with the reason (item by item, time order)."""
    st, ex, names = run.st, run.ex, run.names
    tol = ex.params.assign_tol_mm
    out: list[LeftOut] = []

    def add(k, stats, reason):
        out.append(LeftOut(int(st.row[k]), float(st.t_s[k]), names[int(st.nearest_pose[k])] if st.pose[k] < 0
                           else names[int(st.pose[k])], int(st.cycle[k]), stats, reason))

    in_order = set(ex.order)
    first_moved = np.flatnonzero((st.status == STATUS_ASSIGNED) & ~st.initial)
    for k in np.flatnonzero(st.status != STATUS_ASSIGNED):  # loop over the stops left out of everything
        near, d = names[int(st.nearest_pose[k])], float(st.distance_to_pose_mm[k])
        code = int(st.status[k])
        if code == StopStatus.UNASSIGNED:
            why = f"{d:.3f} mm from the nearest commanded pose {near}, farther than the assignment tolerance {tol:g} mm"
        elif code == StopStatus.OUT_OF_SEQUENCE:
            why = f"{d:.3f} mm from {near}, but not where the commanded order and the elapsed time allow"
        elif code == StopStatus.NOT_IN_ORDER:
            why = f"{d:.3f} mm from {near}, which the commanded order does not visit"
        elif d <= tol and int(st.nearest_pose[k]) in in_order and first_moved.size:
            nxt = names[int(st.pose[first_moved[0]])]
            why = (f"the rest before the first move, at {near}: the commanded order does not put {near} right "
                   f"before the first stop ({nxt})")
        else:
            why = f"the rest before the first move, {d:.3f} mm from the nearest commanded pose {near}"
        add(k, "all", why)
    kb, inc, noapp = settle["kb"], settle["inc"], settle["noapp"]
    for name, info in pose_info.items():  # loop over poses
        kp, groups, gp = info["kp"], info["groups"], info["gp"]
        main = groups[gp][1] if gp >= 0 else None
        main_label = _direction_label(main) if main is not None and np.any(main) else "-"
        for g, (kg, u) in enumerate(groups):
            if g == gp:
                continue
            for k in kg:
                add(k, "AP, RP, POS, PST, AD, RD, drift, orientation",
                    f"approached from {_direction_label(u)} ({kg.size} stop(s)); {name}'s main direction is "
                    f"{main_label} ({kp.size} stops); vAP uses it")
        sel = np.isin(kb, kp)
        for k in kb[sel & inc]:
            add(k, "POS, PST, MPT into it", "a beam break between the move's speed peak and the attained pose")
        for k in kb[sel & noapp]:
            add(k, "POS, PST", "the rest before the first move: its approach is not in the stream")
    for d in dists:  # stops of a distance pair whose partner is missing in their cycle
        for a, b in ((d.pose_a, d.pose_b), (d.pose_b, d.pose_a)):
            kp = pose_info[a]["kp"]
            for k in kp[~np.isin(st.cycle[kp], d.cycles)]:
                add(k, f"AD, RD {d.pose_a}-{d.pose_b}", f"{b} has no attained pose in cycle {int(st.cycle[k])}")
    out.sort(key=lambda x: (x.row, x.statistics))
    return out


def _stage_extraction_problems(run: _Stages) -> None:
    """Missing stops, failed phases and out-of-order stops make the result partial."""
    ex, st = run.ex, run.st
    if ex.missing:
        run.warn(f"{len(ex.missing)} commanded stop(s) missing (see extraction.missing)", partial=True)
    if ex.failed_phases:
        run.warn(f"{len(ex.failed_phases)} deceleration phase(s) gave no attained pose", partial=True)
    n_oos = int(np.count_nonzero(st.status == StopStatus.OUT_OF_SEQUENCE))
    if n_oos:
        run.warn(f"{n_oos} stop(s) near a pose but out of the commanded order (left out)", partial=True)
    if ex.gaps.n:
        run.warn(f"{ex.gaps.n} gap(s) in the stream, {int(ex.gaps.splits.sum())} beam break(s)")


def conformance_text(reasons) -> str:
    """``ISO 9283 conformant: yes``, or ``... no: `` and every reason."""
    return "ISO 9283 conformant: " + ("yes" if not reasons else "no: " + "; ".join(reasons))


def iso_conformance_reasons(poses: dict, ex: Extraction, verdicts, limits: dict | None = None) -> list[str]:
    """Why a run is not ISO 9283 conformant, one sentence each (empty: it is).

    Conformant means: every pose attained in at least :data:`ISO_CYCLES`
    cycles, no commanded stop missing, no stop out of the commanded order,
    and every asked limit decided (a limit of a characteristic that was not
    computed at all, e.g. AT without a linear path, is named too).
    """
    reasons = []
    short = [f"{n} {pr.n_cycles}" for n, pr in poses.items() if pr.n_cycles < ISO_CYCLES]
    if short:
        reasons.append(f"fewer than {ISO_CYCLES} cycles at {listed(short)}")
    if ex.missing:
        by_pose: dict[str, list[int]] = {}
        for m in ex.missing:
            by_pose.setdefault(m.pose, []).append(m.cycle)
        reasons.append("missing stops: " + "; ".join(
            f"{pose} in cycle(s) {', '.join(str(c) for c in cycles)}" for pose, cycles in sorted(by_pose.items()))
            + " (cycles counted from 0, as in the stop table)")
    n_oos = int(np.count_nonzero(ex.stops.status == StopStatus.OUT_OF_SEQUENCE))
    if n_oos:
        reasons.append(f"{n_oos} stop(s) out of the commanded order")
    if ex.failed_phases:
        reasons.append(f"{len(ex.failed_phases)} deceleration phase(s) gave no attained pose")
    undecided = [f"{v.characteristic} {v.subject}" + (f" ({v.note})" if v.note else "")
                 for v in verdicts if v.outcome is Outcome.NOT_DECIDED]
    if undecided:
        reasons.append("limit(s) not decided: " + "; ".join(undecided))
    unevaluated = sorted(set(limits or {}) - {v.characteristic for v in verdicts})
    if unevaluated:
        reasons.append("limit(s) given for characteristics this analysis did not compute: " + ", ".join(unevaluated))
    return reasons


def _break_indices(ex: Extraction) -> np.ndarray:
    """Used-sample index i of each beam break (between i and i+1), sorted."""
    rb = ex.gaps.row_before[ex.gaps.splits]
    if ex.rows_used is None:
        return rb
    return np.searchsorted(ex.rows_used, rb)


def _verdict(key, subject, value, lim, why=""):
    if key not in lim:
        return None
    if value is None:
        return LimitCheck(key, subject, None, lim[key], Outcome.NOT_DECIDED, why or "not computed")
    return LimitCheck(key, subject, float(value), lim[key], Outcome.PASS if abs(value) <= lim[key] else Outcome.FAIL)


def _verdicts(lim, result) -> list[LimitCheck]:
    """Every limited characteristic of the table judged for every subject of its level in ``result``
    (anything with ``poses``, ``distances``, ``posing_times``, ``paths``)."""
    return [_verdict(c.key, name, c.figure(subject), lim, c.why_missing(subject))
            for c, name, subject in table.figures(result, lambda c: c.key in lim)]


# --------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------


def _il(a):
    a = np.asarray(a).ravel()
    if a.dtype.kind in "iub":  # integers (and bools) as Python ints without a numpy scalar each
        return a.astype(np.int64).tolist()
    return [int(x) for x in a]


def pose_to_dict(pr: PoseResult) -> dict:
    """The JSON of one pose's results (keys shared by the stream and the stop-list analyses)."""
    acc, rep, ovs, md, o, dr = (pr.accuracy, pr.repeatability, pr.overshoot, pr.multidirectional,
                                pr.orientation, pr.drift)
    return _with_figures({
        "commanded_mm": None if pr.commanded_mm is None else finite_list(pr.commanded_mm),
        "n_cycles": pr.n_cycles,
        "AP_mm": finite_or_none(acc.AP_mm, 6) if acc else None,
        "APx_mm": finite_or_none(acc.APx_mm, 6) if acc else None,
        "APy_mm": finite_or_none(acc.APy_mm, 6) if acc else None,
        "APz_mm": finite_or_none(acc.APz_mm, 6) if acc else None,
        "mean_mm": finite_list(acc.mean_mm) if acc else (None if rep is None else finite_list(pr.attained_mm.mean(axis=0))),
        "RP_mm": finite_or_none(rep.RP_mm, 6) if rep else None,
        "l_bar_mm": finite_or_none(rep.l_bar_mm, 6) if rep else None,
        "S_l_mm": finite_or_none(rep.S_l_mm, 6) if rep else None,
        "POS_mm": finite_or_none(ovs.POS_mm, 6) if ovs else None,
        "PST_s": finite_or_none(ovs.PST_s, 6) if ovs else None,
        "band_mm": finite_or_none(ovs.band_mm, 6) if ovs else None,
        "band_source": ovs.band_source if ovs else None,
        "approach": ovs.approach if ovs else None,
        "overshoot_per_cycle": None if ovs is None else {
            "POS_mm": finite_list(ovs.POS_j_mm), "PST_s": finite_list(ovs.PST_j_s), "row_entry": _il(ovs.row_entry),
            "row_settled": _il(ovs.row_settled), "row_max": _il(ovs.row_max), "row": _il(ovs.rows),
            "incomplete": [bool(x) for x in ovs.incomplete], "n": ovs.n,
        },
        "vAP_mm": finite_or_none(md.vAP_mm, 6),
        "n_directions": md.n_directions,
        "directions": [
            {"label": g.label, "direction": finite_list(g.direction, 4), "mean_mm": finite_list(g.mean_mm), "n": g.n,
             "rows": _il(g.rows)} for g in md.groups
        ],
        "attained": {
            "x_mm": finite_list(pr.attained_mm[:, 0]), "y_mm": finite_list(pr.attained_mm[:, 1]),
            "z_mm": finite_list(pr.attained_mm[:, 2]), "t_s": finite_list(pr.attained_t_s),
            "row": _il(pr.attained_row), "cycle": _il(pr.attained_cycle),
        },
        "orientation": None if o is None else orientation_to_dict(o, md),
        "drift": None if dr is None else {
            "dAP_mm": finite_or_none(dr.dAP_mm, 6), "dRP_mm": finite_or_none(dr.dRP_mm, 6), "shift_mm": finite_or_none(dr.shift_mm, 6),
            "block_t_s": finite_list(dr.block_t_s), "AP_mm": finite_list(dr.AP_mm), "RP_mm": finite_list(dr.RP_mm),
            "n_per_block": _il(dr.n_per_block),
        },
    }, pr, "pose")


def orientation_to_dict(o: OrientationAR, md: MultiDirectional) -> dict:
    """The JSON of a pose's orientation figures (``vAPa``... from its approach groups ``md``)."""
    return {
        "APa_deg": None if o.AP_rad is None else finite_or_none(math.degrees(o.AP_rad[0]), 6),
        "APb_deg": None if o.AP_rad is None else finite_or_none(math.degrees(o.AP_rad[1]), 6),
        "APc_deg": None if o.AP_rad is None else finite_or_none(math.degrees(o.AP_rad[2]), 6),
        "RPa_deg": finite_or_none(math.degrees(o.RP_rad[0]), 6), "RPb_deg": finite_or_none(math.degrees(o.RP_rad[1]), 6),
        "RPc_deg": finite_or_none(math.degrees(o.RP_rad[2]), 6), "n": o.n,
        **{f"vAP{ax}_deg": None if md.vAP_rad is None else finite_or_none(math.degrees(md.vAP_rad[j]), 6)
           for j, ax in enumerate("abc")},
    }


def _with_figures(d: dict, subject, level: str) -> dict:
    """``d`` and, after its own keys, every figure of the table at ``level`` that ``d`` does not hold yet
    (a characteristic whose formula has no block of its own in the JSON)."""
    for c in table.characteristics():
        if c.level == level and c.in_json and c.key not in d:
            d[c.key] = finite_or_none(c.value(subject), 6)
    return d


def distance_to_dict(d: DistanceAR) -> dict:
    return _with_figures({"pose_a": d.pose_a, "pose_b": d.pose_b, "Dc_mm": finite_or_none(d.Dc_mm, 6), "AD_mm": finite_or_none(d.AD_mm, 6),
            "RD_mm": finite_or_none(d.RD_mm, 6), "n": d.n, "D_mm": finite_list(d.D_mm), "cycle": _il(d.cycles),
            "row_a": _il(d.rows_a), "row_b": _il(d.rows_b)}, d, "pair")


def verdict_to_dict(v: LimitCheck) -> dict:
    d = {"characteristic": v.characteristic, "subject": v.subject, "value": finite_or_none(v.value, 6), "limit": finite_or_none(v.limit, 6),
         "passed": v.passed, "note": v.note}
    if v.rule is not None:
        from station.analysis.iso9283.uncertainty import verdict_uncertainty_dict

        d.update(verdict_uncertainty_dict(v))
    return d


def left_out_to_dict(x: LeftOut) -> dict:
    return {"row": x.row, "t_s": finite_or_none(x.t_s, 6), "pose": x.pose, "cycle": x.cycle, "statistics": x.statistics,
            "reason": x.reason}


def overall_outcome(verdicts) -> Outcome | None:
    """The outcome of all checks (:func:`station.verdict.combine`: FAIL over NOT DECIDED over PASS); None without any."""
    return combine(v.outcome for v in verdicts) if verdicts else None


def _result_to_dict(r: Iso9283Result) -> dict:
    d = _result_dict(r)
    if r.uncertainties:
        d["uncertainty_figures"] = [fu.to_dict() for fu in r.uncertainties.values()]
    return d


def figures_dict(r, rows: str, poses=None, **head) -> dict:
    """The JSON keys the stream and the stop-list analyses share (``head`` after the schema), in their order;
    ``rows``: what a row number of the result counts; ``poses``: the poses' JSON when made elsewhere (else one
    :func:`pose_to_dict` each)."""
    d = {
        "schema": "station.iso9283/1", **head,
        "units": {"position": "mm", "time": "s", "angle": "deg", "row": rows},
        "poses": {name: pose_to_dict(pr) for name, pr in r.poses.items()} if poses is None else poses,
        "distance": [distance_to_dict(x) for x in r.distances],
        "MPT": [
            _with_figures({"from": m.from_pose, "to": m.to_pose, "MPT_s": finite_or_none(m.MPT_s, 6), "n": m.n,
                           "n_available": m.n_available, "times_s": finite_list(m.times_s),
                           "row_leave": _il(m.row_leave), "row_settled": _il(m.row_settled)}, m, "move")
            for m in getattr(r, "posing_times", ())
        ],
        "paths": [
            _with_figures({"from": pa.from_pose, "to": pa.to_pose, "AT_mm": finite_or_none(pa.AT_mm, 6),
                           "RT_mm": finite_or_none(pa.RT_mm, 6), "n": pa.n, "plane_s_mm": finite_list(pa.plane_s_mm),
                           "AT_i_mm": finite_list(pa.AT_i_mm), "RT_i_mm": finite_list(pa.RT_i_mm)}, pa, "path")
            for pa in getattr(r, "paths", ())
        ],
    }
    run = _with_figures({}, r, "run")
    if run:
        d["run"] = run
    return {
        **d,
        "verdicts": [verdict_to_dict(v) for v in r.verdicts],
        "limits": {k: finite_or_none(v, 6) for k, v in r.limits.items()},
        "passed": r.passed,
        "partial": r.partial,
        "iso_conformant": r.iso_conformant,
        "iso_reasons": list(r.iso_reasons),
        "left_out": [left_out_to_dict(x) for x in r.left_out],
        "warnings": list(r.warnings),
    }


def _result_dict(r: Iso9283Result) -> dict:
    ex = r.extraction
    st = ex.stops
    p = ex.params
    return {
        **figures_dict(r, "0-based data row of the stream"),
        "stream": {
            "n_rows": ex.n_rows, "n_used": ex.n_used, "n_invalid": ex.n_rows - ex.n_used,
            "rate_hz": finite_or_none(p.rate_hz, 3), "t_start_s": finite_or_none(r.stream_span_s[0], 6), "t_end_s": finite_or_none(r.stream_span_s[1], 6),
            "gaps": [
                {"row_before": int(a), "row_after": int(b), "t_start_s": finite_or_none(c, 6), "t_end_s": finite_or_none(d_, 6),
                 "lost_samples": int(e), "beam_break": bool(f)}
                for a, b, c, d_, e, f in zip(ex.gaps.row_before, ex.gaps.row_after, ex.gaps.t_start_s,
                                             ex.gaps.t_end_s, ex.gaps.lost_samples, ex.gaps.splits)
            ],
        },
        "extraction": {
            "M": p.M, "Mp": p.Mp, "h": p.h, "noise_mm": finite_or_none(p.noise_mm, 6), "v_rest_mm_s": finite_or_none(p.v_rest_mm_s, 4),
            "assign_tol_mm": finite_or_none(p.assign_tol_mm, 6), "order": [ex.names[k] for k in ex.order],
            "n_cycles": ex.n_cycles, "n_stops": st.n,
            "n_assigned": int(np.count_nonzero(st.status == STATUS_ASSIGNED)),
            "missing": [
                {"cycle": m.cycle, "pose": m.pose, "reason": m.reason, "t_after_s": finite_or_none(m.t_after_s, 6),
                 "t_before_s": finite_or_none(m.t_before_s, 6)} for m in ex.missing
            ],
            "other_stops": [
                {"row": int(st.row[k]), "t_s": finite_or_none(st.t_s[k], 6), "position_mm": finite_list(st.position_mm[k]),
                 "status": STATUS_NAMES[int(st.status[k])], "nearest_pose": ex.names[int(st.nearest_pose[k])],
                 "distance_mm": finite_or_none(st.distance_to_pose_mm[k], 6)}
                for k in np.flatnonzero(st.status != STATUS_ASSIGNED)
            ],
            "failed_phases": [
                {"row_start": f.row_start, "row_end": f.row_end, "t_start_s": finite_or_none(f.t_start_s, 6),
                 "t_end_s": finite_or_none(f.t_end_s, 6), "reason": f.reason} for f in ex.failed_phases
            ],
            "trailing_motion": ex.trailing_motion,
            "initial_rest": None if ex.initial_rest_i is None else {
                "row_start": int(ex.to_rows(ex.initial_rest_i[0])), "row_end": int(ex.to_rows(ex.initial_rest_i[1])),
                "stop": bool(st.n and st.initial[0]),
                "counted": bool(st.n and st.initial[0] and st.status[0] == STATUS_ASSIGNED)},
        },
    }
