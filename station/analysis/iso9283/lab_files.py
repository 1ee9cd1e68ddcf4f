"""Lab-file analysis as a service: the data of a lab's files in, results out (no I/O).

``station analyze`` reads the files (:mod:`station.readers`), hands their
contents here and prints what comes back:

* :func:`stream_time_base`: the time base of a stream, from its stamps, from
  the sample rate given, or from a rate estimated from coarse stamps
  (:func:`station.analysis.time_base.estimate_rate_from_stamps`), with the
  sentences that say which;
* :func:`rest_noise_mm`, :func:`stop_scatter_mm`: the noise the registration's
  fit is judged against;
* :func:`analyze_stream`, :func:`analyze_stops`: the ISO 9283 analysis of a
  stream or of a stop list, and the stops no commanded pose explains;
* :func:`reflector_repeatability`: RP of each reflector of a stop list beside
  the centroid's (eq. (2)), as labs report multi-reflector measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from station.errors import DataError
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

#: stamps repeat on at least this fraction of the rows: the clock is coarser than the sampling
COARSE_REPEAT_FRACTION = 0.5
#: places where the estimated rate varies, named one by one before "... more"
SHOW_VARYING = 5
#: coarse stamps of a stream without moves pass when at most this fraction of their intervals hold another rate
MAX_VARYING_FRACTION = 0.05
#: the provisional rate that finds the stops on a refused clock is kept within the extraction's range, Hz
RATE_FLOOR_HZ, RATE_CEIL_HZ = TRACKER_RATE_RANGE_HZ


@dataclass
class TimeBase:
    """``t_s`` (N,) and how it was made: ``info`` (JSON), ``note`` (one console line), ``notes`` (warnings).

    ``refused``: why no time figure may be stated on this clock ("" when they may; ``t_s`` is then a
    provisional time base for finding the stops only); ``jumps``: rows where the clock jumped (time figures
    across them are refused).
    """

    t_s: np.ndarray
    info: dict
    note: str
    notes: list[str] = field(default_factory=list)
    refused: str = ""
    jumps: tuple = ()

    @property
    def estimated(self) -> bool:
        """Times rest on a rate estimated from the stamps or inferred from the motion (PST, MPT, drift marked so)."""
        return self.info.get("source") in ("estimated_rate", "motion_rate")


def stream_time_base(t_stamps, n: int, rate_hz: float | None = None, *, line=None, source: str = "",
                     tcol: str = "t", xyz_mm=None, valid=None, wait_s: float | None = None) -> TimeBase:
    """The time base of a stream of ``n`` samples whose stamps are ``t_stamps`` (N,) s or None.

    * ``rate_hz`` given: the sample index / rate (a note when the stamps step otherwise);
    * stamps that can be the time base (:func:`~station.analysis.time_base.check_time_stamps`): the stamps,
      with the places where the clock jumped (:func:`~station.analysis.iso9283.clock_jumps.clock_jumps`,
      needs ``xyz_mm``);
    * stamps that repeat on most rows (a clock coarser than the sampling): checked against the motion
      ``xyz_mm`` (:func:`coarse_clock`); the sample index / the rate the stamps give when they pass, or the
      rate the dwells give with the program's wait ``wait_s``, or else a provisional time base with every time
      figure refused (``refused``);
    * otherwise a DataError naming the row (``line`` (N,) gives file lines) and asking for ``--rate-hz``.
    """
    from station.analysis.iso9283.time_base import check_time_stamps, sample_index_time

    where = (lambda r: f"line {int(line[r])}, ") if line is not None else (lambda r: f"row {r + 1}, ")
    notes: list[str] = []
    if rate_hz is not None:
        t = sample_index_time(n, rate_hz)
        if t_stamps is not None and n >= 2:
            chk = check_time_stamps(t_stamps)
            if chk.ok and abs(chk.median_step_s * rate_hz - 1.0) > 0.05:
                notes.append(f"the file's time stamps step by {chk.median_step_s:.6g} s, not 1/{rate_hz:g} Hz "
                             f"= {1.0 / rate_hz:.6g} s: is --rate-hz right?")
        return TimeBase(t, {"source": "sample_index", "rate_hz": float(rate_hz)},
                        f"time base: sample index / {rate_hz:g} Hz (time stamps not used); PST, MPT and every "
                        f"time are sample counts / {rate_hz:g} Hz", notes)
    if t_stamps is None:
        raise DataError(f"{source} has no time stamps: give the sample rate with --rate-hz R to take the sample "
                        "index as the time base")
    t_stamps = np.asarray(t_stamps, dtype=float)
    if n < 2:
        return TimeBase(t_stamps, {"source": "stamps", "rate_hz": None}, "time base: the file's time stamps")
    chk = check_time_stamps(t_stamps)
    if chk.ok:
        return _fine_stamps(t_stamps, xyz_mm, valid, where, tcol)
    if not chk.n_backwards and chk.n_repeats >= COARSE_REPEAT_FRACTION * (n - 1):
        return coarse_clock(t_stamps, chk.n_repeats, xyz_mm, valid, wait_s, where=where, line=line,
                            source=source, tcol=tcol)
    msgs = []
    for prob in chk.problems:
        w = where(prob.row) if prob.row is not None else ""
        msgs.append(f"{source}: {w}column {tcol!r}: {prob.text}")
    raise DataError("; ".join(msgs) + "; these time stamps cannot be the time base: give the sample rate "
                    "with --rate-hz R to take the sample index instead")


def _fine_stamps(t_stamps, xyz_mm, valid, where, tcol) -> TimeBase:
    """Stamps that can be the time base, with the jumps of the clock the motion shows."""
    from station.analysis.iso9283.clock_jumps import clock_jumps

    jumps = () if xyz_mm is None else clock_jumps(t_stamps, xyz_mm, valid)
    info = {"source": "stamps", "rate_hz": None}
    notes = []
    if jumps:
        info["jumps"] = [j.to_dict() for j in jumps]
        notes = [f"{where(j.row)}column {tcol!r}: {j.text()}; PST and MPT across it are refused" for j in jumps]
    return TimeBase(t_stamps, info, "time base: the file's time stamps", notes, jumps=jumps)


def coarse_clock(t_stamps, n_repeats: int, xyz_mm, valid, wait_s, *, where, line, source, tcol) -> TimeBase:
    """The time base of stamps coarser than the samples, checked against the motion.

    The rate the stamps give (samples per stamp second,
    :func:`~station.analysis.time_base.estimate_rate_from_stamps`) is used when
    the stamps agree with the motion: every move and dwell lasts, by the
    stamps, its sample count at that rate
    (:func:`~station.analysis.iso9283.motion_clock.stamps_against_moves`);
    with no move in the stream (a held pose), when at most
    :data:`MAX_VARYING_FRACTION` of the stamp intervals hold another rate.
    Identical moves must take the same number of samples (evenly spaced
    samples) for any rate to be used. When the stamps fail, the program's wait
    ``wait_s`` gives the rate from the dwells
    (:func:`~station.analysis.iso9283.motion_clock.rate_from_dwells`); without
    it every time figure is refused.
    """
    from station.analysis.iso9283.motion_clock import (
        find_moves,
        identical_moves,
        rate_from_dwells,
        stamps_against_moves,
    )
    from station.analysis.iso9283.time_base import estimate_rate_from_stamps, sample_index_time

    n = t_stamps.size

    def lines_of(a, b):
        return f"lines {int(line[a])}-{int(line[b])}" if line is not None else f"rows {a + 1}-{b + 1}"

    try:
        est = estimate_rate_from_stamps(t_stamps)
    except DataError as exc:
        raise DataError(f"{source}: column {tcol!r}: the stamps repeat ({n_repeats} of {n} rows) and "
                        f"{exc}; give the sample rate with --rate-hz R") from None
    r = est.rate_hz
    span = est.span_s
    moves = find_moves(xyz_mm, valid) if xyz_mm is not None else None
    groups = identical_moves(moves, t_stamps) if moves is not None else []
    check = {"n_moves": 0 if moves is None else int(moves.leave_row.size),
             "identical_moves": [g.to_dict() for g in groups]}
    unsteady = [g for g in groups if not g.steady]
    info = {"stamp_estimate": est.to_dict(), "motion_check": check}
    varying = [int(line[est.first_row[k]]) if line is not None else int(est.first_row[k]) for k in est.varies]
    info["varying_rows"] = varying
    notes = []
    for k in est.varies[:SHOW_VARYING]:
        row = int(est.first_row[k])
        notes.append(f"{where(row)}column {tcol!r}: the rate varies here: {est.per_interval_hz[k]:.4g} "
                     f"samples/s in the stamp interval starting at this row, against {r:.4g} Hz overall")
    if est.varies.size > SHOW_VARYING:
        notes.append(f"the rate varies in {est.varies.size - SHOW_VARYING} more stamp interval(s) (see the JSON)")
    if moves is not None and moves.leave_row.size:
        ev = stamps_against_moves(t_stamps, moves, r, est.resolution_s)
        check["stamps_against_moves"] = ev.to_dict()
        stamps_ok = ev.ok
        why_not = "" if stamps_ok else (
            f"the stamps disagree with the motion: {ev.n_off} of {ev.n_events} moves and dwells last another time "
            f"by the stamps than their samples give at the stamps' {r:.4g} Hz (worst: a {ev.worst['kind']} of "
            f"{ev.worst['samples']} samples, {lines_of(ev.worst['row_from'], ev.worst['row_to'])}, "
            f"{ev.worst['stamp_duration_s']:.3g} s by the stamps, {ev.worst['duration_at_rate_s']:.3g} s at the rate)")
    else:
        stamps_ok = est.varies.size <= MAX_VARYING_FRACTION * est.n_intervals
        why_not = "" if stamps_ok else (
            f"{est.varies.size} of {est.n_intervals} stamp intervals hold another rate than {r:.4g} Hz "
            f"({est.per_interval_hz.min():.4g}-{est.per_interval_hz.max():.4g} samples/s) and no move in the "
            "stream can check the stamps")
    if unsteady:
        g = unsteady[0]
        why_not = (f"identical moves (rest {g.from_rest} -> rest {g.to_rest}) take {g.samples.min()}-"
                   f"{g.samples.max()} samples: the samples are not evenly spaced in time, no rate holds for them")
    evidence = "; ".join(f"{g.samples.size} identical moves rest {g.from_rest} -> rest {g.to_rest} take "
                         f"{g.samples.min()}-{g.samples.max()} samples (spread {g.spread})"
                         + ("" if g.stamp_s is None else f", {g.stamp_s.min():g}-{g.stamp_s.max():g} s by the stamps")
                         for g in groups)
    if stamps_ok and not unsteady:
        # whole intervals give the rate to a sample over their span; intervals that disagree (samples lost in
        # one, a stalled logger) move it by their spread over the square root of their number
        u = max(1.0 / span, est.spread_hz / math.sqrt(est.n_intervals)) if span > 0 else math.inf
        info.update({"source": "estimated_rate", "rate_hz": r, "u_rate_hz": u, "estimate": est.to_dict()})
        note = (f"time base: sample index / {r:.4f} Hz, the rate ESTIMATED from the coarse stamps ({n_repeats} "
                f"of {n} stamps repeat; {est.n_intervals} whole interval(s) of {est.resolution_s:g} s, "
                f"{r:.4f} +/- {u:.2g} Hz), checked against the motion"
                + (f" ({evidence}; every move and dwell agrees)" if groups else
                   f" ({check['n_moves']} move(s) agree)" if check["n_moves"] else " (no move: the stamp intervals "
                   "agree among themselves)")
                + "; PST, MPT and every time rest on this estimate (give --rate-hz R when the rate is known)")
        return TimeBase(sample_index_time(n, r), info, note, notes)
    if wait_s is not None and not unsteady and moves is not None:
        dr = rate_from_dwells(moves.dwell_rows, wait_s)
        info["dwell_rate"] = dr.to_dict()
        if dr.rate_hz is not None:
            info.update({"source": "motion_rate", "rate_hz": dr.rate_hz, "u_rate_hz": dr.u_rate_hz})
            note = (f"time base: sample index / {dr.rate_hz:.4f} +/- {dr.u_rate_hz:.2g} Hz, the rate INFERRED from "
                    f"the motion: {dr.basis}" + (f"; {evidence}" if evidence else "")
                    + f". The stamps were not used: {why_not}")
            return TimeBase(sample_index_time(n, dr.rate_hz), info, note, notes)
        why_not += f"; the dwells give no rate: {dr.reason}"
    reason = (f"the clock failed its check against the motion: {why_not}"
              + (f" ({evidence})" if evidence and not unsteady else "")
              + "; give the sample rate with --rate-hz R"
              + ("" if unsteady or moves is None or not moves.leave_row.size
                 else ", or the program's wait at each stop with --dwell-s W"))
    info.update({"source": "refused", "rate_hz": None, "provisional_rate_hz": r, "refused": reason})
    note = (f"time base: NONE for time figures; the stops found on the sample index / {r:.4g} Hz (the stamps' "
            "rate, provisional); PST, MPT and drift per minute are refused")
    return TimeBase(sample_index_time(n, min(max(r, RATE_FLOOR_HZ), RATE_CEIL_HZ)), info, note, notes,
                    refused=reason)


def rest_noise_mm(t, xyz) -> float:
    """The tracker's per-axis noise from the quietest fifth of the samples (the robot at rest), mm."""
    from station.analysis.iso9283.extraction import estimate_noise_mm

    if t.size < 50:
        return estimate_noise_mm(xyz, t) if t.size >= 3 else 0.0
    v = np.linalg.norm(xyz[2:] - xyz[:-2], axis=1) / (t[2:] - t[:-2])
    quiet = np.flatnonzero(v <= np.quantile(v, 0.2)) + 1
    return estimate_noise_mm(xyz, t, at=quiet)


def stop_scatter_mm(centroid_mm, pose) -> float:
    """Per-axis scatter of the stops (K, 3) about their pose's mean, pooled, mm (bounds the points' noise)."""
    c = np.asarray(centroid_mm, dtype=float)
    ids: dict[str, int] = {}
    label = np.fromiter((ids.setdefault(p, len(ids)) for p in pose), np.int64, len(pose))  # poses by first appearance
    order = np.argsort(label, kind="stable")  # each pose's stops together, in their order
    sizes = np.bincount(label, minlength=len(ids))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    # each pose's sum of squares, computed for the poses of one number of stops at once (100,000 poses took
    # seconds one by one), then added in the poses' order as before
    ss = np.zeros(len(ids))
    for n in np.unique(sizes[sizes >= 2]).tolist():  # loop over the numbers of stops
        idx = np.flatnonzero(sizes == n)
        X = c[order[starts[idx][:, None] + np.arange(n)]]                    # (G, n, 3)
        ss[idx] = np.sum(((X - X.mean(axis=1)[:, None, :]) ** 2).reshape(len(idx), -1), axis=1)
    dev, dof = 0.0, 0
    for n, s in zip(sizes.tolist(), ss.tolist()):  # loop over poses (floats): the pooled sum in their order
        if n >= 2:
            dev += s
            dof += 3 * (n - 1)
    return math.sqrt(dev / dof) if dof else 0.0


@dataclass
class LabResult:
    """An analysis of a lab's file: the ISO 9283 result and the stops no commanded pose explains (sentences)."""

    result: object
    far: list[str]


def analyze_stream(t_s, xyz_mm, valid, cmd_mm, *, names, order=None, orientation_rad=None,
                   commanded_orientation_rad=None, limits=None, band_mm=None, distance_pairs="auto",
                   linear_paths=False, extraction=None) -> LabResult:
    """ISO 9283 of a stream (:func:`station.analysis.iso9283.analyze_iso9283`) and its unexplained stops."""
    from station.analysis.iso9283.characteristics import analyze_iso9283
    from station.analysis.iso9283.extraction import STATUS_UNASSIGNED

    res = analyze_iso9283(t_s, xyz_mm, cmd_mm, names=names, order=order, valid=valid,
                          orientation_rad=orientation_rad, commanded_orientation_rad=commanded_orientation_rad,
                          limits=limits, band_mm=band_mm, distance_pairs=distance_pairs,
                          linear_paths=linear_paths, extraction=extraction)
    st = res.extraction.stops
    far_k = np.flatnonzero(st.status == STATUS_UNASSIGNED)
    far = []
    if far_k.size:
        near = [f"row {int(st.row[k])} {float(st.distance_to_pose_mm[k]):.1f} mm from "
                f"{res.extraction.names[int(st.nearest_pose[k])]}" for k in far_k[:5]]
        far.append(f"{far_k.size} stop(s) lie farther than {res.extraction.params.assign_tol_mm:g} mm from every "
                   f"commanded pose ({'; '.join(near)}{', ...' if far_k.size > 5 else ''})"
                   + ("; no stop is near a pose: are the poses in another frame? give --frame or --register"
                      if not np.any(st.status == 0) else "")
                   + " (via points: --allow-other-stops)")
    return LabResult(res, far)


def analyze_stops(pose, cycle, points_mm, *, lines, commanded_mm=None, names=None, approach=None,
                  reflectors=None, limits=None, distance_pairs="auto", assign_tol_mm=None) -> LabResult:
    """ISO 9283 of a stop list (:func:`station.analysis.stop_list.analyze_stop_list`) and its far stops.

    ``lines`` (K,) the file line of each stop, for the sentences.
    """
    from station.analysis.iso9283.stop_list import analyze_stop_list

    _refuse_collinear_sets(points_mm, lines, pose, cycle)
    res = analyze_stop_list(pose, cycle, points_mm, commanded_mm=commanded_mm, names=names, approach=approach,
                            reflectors=reflectors, limits=limits, distance_pairs=distance_pairs,
                            assign_tol_mm=assign_tol_mm)
    far = []
    if res.n_far:
        kf = np.flatnonzero(res.stop_far)
        far.append(f"{kf.size} stop(s) lie farther than {res.assign_tol_mm:g} mm from their commanded pose ("
                   + "; ".join(f"line {int(lines[k])} {pose[k]} {res.stop_distance_mm[k]:.1f} mm"
                               for k in kf[:5]) + (", ..." if kf.size > 5 else "") + ")"
                   + ("; are the poses in another frame? give --frame or --register" if kf.size == len(pose) else ""))
    return LabResult(res, far)


def _refuse_collinear_sets(points_mm, lines, pose, cycle) -> None:
    """A stop whose three or more reflectors lie on one line gives no orientation: refused naming its line."""
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 3 or pts.shape[1] < 3:
        return
    centred = pts - pts.mean(axis=1, keepdims=True)
    sv = np.linalg.svd(centred, compute_uv=False)  # (K, 3), descending
    bad = np.flatnonzero(sv[:, 1] <= 1e-9 * np.maximum(sv[:, 0], 1e-300))
    if bad.size:
        k = int(bad[0])
        raise DataError(f"line {int(lines[k])} ({pose[k]}, cycle {cycle[k]}): the reflectors lie on one line: their "
                        "set gives no orientation (a reflector measured twice, or one left off the flange?)")


@dataclass(frozen=True)
class ReflectorRP:
    """RP (eq. (2)) of one pose from each reflector alone and from the reflectors' centroid, mm."""

    pose: str
    n: int
    reflectors: tuple[str, ...]
    RP_mm: tuple[float, ...]
    centroid_RP_mm: float

    def to_dict(self) -> dict:
        return {"pose": self.pose, "n": self.n, "centroid_RP_mm": self.centroid_RP_mm,
                "RP_mm": dict(zip(self.reflectors, self.RP_mm))}


def _rp(points) -> float:
    """Eq. (2): l_bar + 3 S_l of the points about their barycentre."""
    c = points.mean(axis=0)
    dist = np.linalg.norm(points - c, axis=1)
    return float(dist.mean() + 3.0 * dist.std(ddof=1))


def reflector_repeatability(pose, points_mm, reflectors) -> list[ReflectorRP]:
    """RP of every pose from each reflector's points and from their centroid (K stops, ``points_mm`` (K, R, 3)).

    Poses with fewer than 2 stops are left out (eq. (2) needs a spread).
    """
    pts = np.asarray(points_mm, dtype=float)
    pose = np.array(pose, dtype=object)
    out = []
    for p in dict.fromkeys(pose.tolist()):
        m = pose == p
        if m.sum() < 2:
            continue
        sel = pts[m]
        out.append(ReflectorRP(str(p), int(m.sum()), tuple(reflectors),
                               tuple(_rp(sel[:, r]) for r in range(sel.shape[1])), _rp(sel.mean(axis=1))))
    return out


def repeating_ids(names, max_period: int = 12) -> tuple[str, ...] | None:
    """The ids a per-pose reflector list repeats (``1, 2, 3, 1, 2, 3, ...``), or None for anything else.

    ``names`` are the first column of a point list; a cycle of 2 to ``max_period``
    distinct ids, repeated at least twice over the whole list (the last block may
    be cut short), marks a list of reflectors measured cycle by cycle, not a stream.
    """
    if names is None or len(names) < 4:
        return None
    names = list(names)
    try:
        k = names.index(names[0], 1)
    except ValueError:
        return None
    if not 2 <= k <= max_period or len(set(names[:k])) != k or len(names) < 2 * k:
        return None
    if any(names[j] != names[j % k] for j in range(len(names))):
        return None
    return tuple(names[:k])
