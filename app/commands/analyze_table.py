"""The console tables of ``station analyze iso9283``: stream results and stop-list results."""

from __future__ import annotations

import math

from station import characteristics as table
from station.verdict import Outcome

#: lines of a list (missing, left out) shown before "... more (see the JSON)"
SHOW = 20


def _n(x, fmt="{:.3f}"):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def _pose_rows(res, estimated_rate: bool = False) -> list[str]:
    """One line per pose: its cycles, every pose figure of the table it states (those of one approach, the
    limit band, those of several approaches and the directions), ``*`` on a time that rests on an estimated
    rate."""
    chars = [c for c in table.characteristics()
             if c.level == "pose" and c.unit != "1" and (c.stated or c.key in res.limits)]
    one = [c for c in chars if not c.several_approaches]
    several = [c for c in chars if c.several_approaches]

    def head(c):
        return c.key + ("*" if estimated_rate and c.unit == "s" else "")

    def cells(cs, text):
        return "".join(f"{text(c):>{max(9, len(head(c)) + 2)}}" for c in cs)

    lines = [f"{'pose':<6}{'n':>5}" + cells(one, head) + f"{'band_mm':>9} {'src':<7}" + cells(several, head)
             + f"{'dirs':>5}"]
    # each figure's cell format, made once (100,000 poses: a line each)
    w_one = [(c.value, f"{{:>{max(9, len(head(c)) + 2)}}}".format) for c in one]
    w_several = [(c.value, f"{{:>{max(9, len(head(c)) + 2)}}}".format) for c in several]
    for name, pr in res.poses.items():  # loop over poses: a line each
        ovs = pr.overshoot
        lines.append(
            f"{name:<6}{pr.n_cycles:>5}" + "".join([cell(_n(value(pr))) for value, cell in w_one])
            + f"{_n(ovs.band_mm if ovs else None):>9} {(ovs.band_source if ovs else '-'):<7}"
            + "".join([cell(_n(value(pr))) for value, cell in w_several]) + f"{pr.multidirectional.n_directions:>5}"
        )
    return lines


def _tail(res, estimated_rate: bool = False, clock_refused: bool = False) -> list[str]:
    """Distances, orientation, verdicts, the overall line, left-out stops, warnings, conformance."""
    from station.analysis.iso9283.characteristics import conformance_text

    lines = []
    for d in res.distances:
        lines.append(f"distance {d.pose_a}-{d.pose_b}: Dc {_n(d.Dc_mm)} mm, AD {_n(d.AD_mm, '{:+.3f}')} mm, "
                     f"RD +/-{_n(d.RD_mm)} mm (n={d.n})")
    for m in getattr(res, "posing_times", ()):
        lines.append(f"MPT {m.from_pose}->{m.to_pose}: {_n(m.MPT_s)} s{'*' if estimated_rate else ''} "
                     f"(mean of {m.n} of {m.n_available})")
    for pa in getattr(res, "paths", ()):
        lines.append(f"path {pa.from_pose}->{pa.to_pose}: AT {pa.AT_mm:.3f} mm, RT {_n(pa.RT_mm)} mm (n={pa.n})")
    for name, pr in res.poses.items():
        if pr.orientation is not None:
            o = pr.orientation
            ap = "-" if o.AP_rad is None else ", ".join(f"{math.degrees(v):+.4f}" for v in o.AP_rad)
            rp = ", ".join(f"{math.degrees(v):.4f}" for v in o.RP_rad)
            vap = pr.multidirectional.vAP_rad
            vtxt = "" if vap is None else ", vAP(a,b,c) " + ", ".join(f"{math.degrees(v):.4f}" for v in vap) + " deg"
            lines.append(f"orientation {name}: AP(a,b,c) {ap} deg, RP(a,b,c) {rp} deg (n={o.n}){vtxt}")
        if pr.drift is not None:
            lines.append(f"drift {name}: dAP {pr.drift.dAP_mm:.4f} mm, dRP {pr.drift.dRP_mm:.4f} mm "
                         f"over {pr.drift.AP_mm.size} blocks")
    if res.verdicts:
        lines.append("")
        for v in res.verdicts:
            mark = str(v.outcome)
            if v.outcome is Outcome.NOT_DECIDED:  # in the guard band, or not computed
                mark = "UND " if v.value is not None and getattr(v, "rule", None) == "guarded" else "N/A "
            fu = getattr(v, "uncertainty", None)
            unc = "" if fu is None else f" +/- {fu.U:.2g} (k={fu.k:g})"
            lines.append(f"{mark} {v.characteristic:<8} {v.subject:<8} {_n(v.value, '{:.4f}'):>9}{unc} <= {v.limit:g}"
                         + (f"  ({v.note})" if v.note else ""))
        word = res.outcome.word if res.outcome is Outcome.NOT_DECIDED else str(res.outcome)
        iso = "ISO 9283 conformant" if res.iso_conformant else "NOT ISO 9283 conformant (see below)"
        lines.append(f"overall: {word} on the limits asked; {iso}")
    for x in res.left_out[:SHOW]:
        where = f"row {x.row}" + ("" if clock_refused or not math.isfinite(x.t_s) else f" ({x.t_s:.3f} s)")
        cyc = f" cycle {x.cycle}" if x.cycle != -1 or x.statistics != "all" else ""
        lines.append(f"left out: {where} {x.pose}{cyc} from {x.statistics}: {x.reason}")
    if len(res.left_out) > SHOW:
        lines.append(f"left out: ... {len(res.left_out) - SHOW} more (see the JSON)")
    for w in res.warnings:
        lines.append(f"warning: {w}")
    if res.partial:
        lines.append("PARTIAL RESULT: some characteristics or stops are missing (see warnings)")
    lines.append(conformance_text(res.iso_reasons))
    return lines


def format_table(res, stream_name="stream", time_note: str | None = None, notes=(),
                 estimated_rate: bool = False, clock_refused: bool = False) -> str:
    """Human-readable summary of an :class:`~station.analysis.iso9283.Iso9283Result`; ``estimated_rate``
    marks PST and MPT (``*``) as resting on a rate estimated from the stamps or inferred from the motion;
    ``clock_refused``: the clock failed its check, no rate or time is shown."""
    ex = res.extraction
    st = ex.stops
    rate = "an unknown rate (the clock refused)" if clock_refused else f"{ex.params.rate_hz:.1f} Hz"
    lines = [
        f"ISO 9283 analysis of {stream_name}: {ex.n_rows} rows ({ex.n_rows - ex.n_used} flagged invalid) at "
        f"{rate}, {ex.n_cycles} cycles, {st.n} stops, {len(ex.missing)} missing, "
        f"{ex.gaps.n} gaps ({int(ex.gaps.splits.sum())} beam breaks)",
        f"window 2M+1 = {2 * ex.params.M + 1} samples, step Mp = {ex.params.Mp}; order "
        f"{','.join(ex.names[k] for k in ex.order)}; assignment tolerance {ex.params.assign_tol_mm:g} mm",
    ]
    if time_note:
        lines.append(time_note)
    lines += [f"note: {n}" for n in notes]
    lines.append("")
    lines += _pose_rows(res, estimated_rate)
    if estimated_rate:
        lines.append("* PST and MPT on a sample rate ESTIMATED from the stamps or INFERRED from the motion (see the "
                     "time base above)")
    tail = _tail(res, estimated_rate, clock_refused)
    k = next((i for i, line in enumerate(tail) if line.startswith(("left out:", "warning:", "PARTIAL", "ISO 9283"))),
             len(tail))
    miss = [f"missing: cycle {m.cycle} {m.pose}: {m.reason}" for m in ex.missing[:SHOW]]
    if len(ex.missing) > SHOW:
        miss.append(f"missing: ... {len(ex.missing) - SHOW} more (see the JSON)")
    return "\n".join(lines + tail[:k] + miss + tail[k:])


def format_stop_table(res, source="stop list", notes=(), reflector_rp=()) -> str:
    """Human-readable summary of a :class:`~station.analysis.stop_list.StopListResult`; ``reflector_rp``
    (:class:`~station.analysis.lab_files.ReflectorRP` per pose) adds RP per reflector beside the centroid's."""
    n = len(res.stop_pose)
    refl = [r for r in res.reflectors if r]
    lines = [f"ISO 9283 analysis of the stop list {source}: {n} stops of {len(res.poses)} poses"
             + (f", {len(refl)} reflectors ({', '.join(refl)}) per stop" if refl else "")
             + f", assignment tolerance {res.assign_tol_mm:g} mm"]
    lines += [f"note: {x}" for x in notes]
    lines.append("")
    lines += _pose_rows(res)
    if refl and len(refl) >= 3 and n:
        rms = res.stop_fit_rms_mm[~(res.stop_fit_rms_mm != res.stop_fit_rms_mm)]
        if rms.size:
            lines.append(f"reflector sets: rigid fit rms up to {float(rms.max()):.4f} mm")
    if reflector_rp:
        refl_names = reflector_rp[0].reflectors
        lines.append("")
        lines.append(f"{'pose':<8}{'n':>4}{'RP centroid':>13}" + "".join(f"{'RP refl ' + r:>13}" for r in refl_names)
                     + "  (mm, eq. (2))")
        for rr in reflector_rp:
            lines.append(f"{rr.pose:<8}{rr.n:>4}{rr.centroid_RP_mm:>13.4f}" + "".join(f"{v:>13.4f}" for v in rr.RP_mm))
    lines += _tail(res)
    return "\n".join(lines)
