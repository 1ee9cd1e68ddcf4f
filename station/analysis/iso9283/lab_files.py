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

#: stamps repeat on at least this fraction of the rows: the clock is coarser than the sampling
COARSE_REPEAT_FRACTION = 0.5
#: places where the estimated rate varies, named one by one before "... more"
SHOW_VARYING = 5


@dataclass
class TimeBase:
    """``t_s`` (N,) and how it was made: ``info`` (JSON), ``note`` (one console line), ``notes`` (warnings)."""

    t_s: np.ndarray
    info: dict
    note: str
    notes: list[str] = field(default_factory=list)

    @property
    def estimated(self) -> bool:
        """Times rest on a rate estimated from the stamps (PST, MPT and drift are marked so)."""
        return self.info.get("source") == "estimated_rate"


def stream_time_base(t_stamps, n: int, rate_hz: float | None = None, *, line=None, source: str = "",
                     tcol: str = "t") -> TimeBase:
    """The time base of a stream of ``n`` samples whose stamps are ``t_stamps`` (N,) s or None.

    * ``rate_hz`` given: the sample index / rate (a note when the stamps step otherwise);
    * stamps that can be the time base (:func:`~station.analysis.time_base.check_time_stamps`): the stamps;
    * stamps that repeat on most rows (a clock coarser than the sampling): the sample index / a rate
      estimated from them, said so, with a warning for every place where the rate varies;
    * otherwise a DataError naming the row (``line`` (N,) gives file lines) and asking for ``--rate-hz``.
    """
    from station.analysis.iso9283.time_base import check_time_stamps, estimate_rate_from_stamps, sample_index_time

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
        return TimeBase(t_stamps, {"source": "stamps", "rate_hz": None}, "time base: the file's time stamps")
    if not chk.n_backwards and chk.n_repeats >= COARSE_REPEAT_FRACTION * (n - 1):
        try:
            est = estimate_rate_from_stamps(t_stamps)
        except DataError as exc:
            raise DataError(f"{source}: column {tcol!r}: the stamps repeat ({chk.n_repeats} of {n} rows) and "
                            f"{exc}; give the sample rate with --rate-hz R") from None
        r = est.rate_hz
        for k in est.varies[:SHOW_VARYING]:
            row = int(est.first_row[k])
            notes.append(f"{where(row)}column {tcol!r}: the rate varies here: {est.per_interval_hz[k]:.4g} "
                         f"samples/s in the stamp interval starting at this row, against {r:.4g} Hz overall")
        if est.varies.size > SHOW_VARYING:
            notes.append(f"the rate varies in {est.varies.size - SHOW_VARYING} more stamp interval(s) (see the JSON)")
        info = {"source": "estimated_rate", "rate_hz": r, "estimate": est.to_dict(),
                "varying_rows": [int(line[est.first_row[k]]) if line is not None else int(est.first_row[k])
                                 for k in est.varies]}
        note = (f"time base: sample index / {r:.4f} Hz, the rate ESTIMATED from the coarse stamps ({chk.n_repeats} "
                f"of {n} stamps repeat; {est.n_intervals} whole interval(s) of {est.resolution_s:g} s, "
                f"{r:.4f} +/- {est.spread_hz:.3g} Hz); PST, MPT and every time rest on this estimate "
                "(give --rate-hz R when the rate is known)")
        return TimeBase(sample_index_time(n, r), info, note, notes)
    msgs = []
    for prob in chk.problems:
        w = where(prob.row) if prob.row is not None else ""
        msgs.append(f"{source}: {w}column {tcol!r}: {prob.text}")
    raise DataError("; ".join(msgs) + "; these time stamps cannot be the time base: give the sample rate "
                    "with --rate-hz R to take the sample index instead")


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
    pose = np.array(pose, dtype=object)
    dev, dof = 0.0, 0
    for p in set(pose.tolist()):
        m = pose == p
        if m.sum() >= 2:
            dev += float(np.sum((c[m] - c[m].mean(axis=0)) ** 2))
            dof += 3 * (int(m.sum()) - 1)
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
