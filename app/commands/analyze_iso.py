"""``station analyze iso9283``: ISO 9283 pose characteristics of a stream or a stop list.

Inputs (see ``README.md``, "Analysing files you already have"):

* ``--stream S``: the project's CSV, a SpatialAnalyzer point export or a plain
  point list, chosen by sniffing (``--format`` overrides, ``--group`` picks an
  SA group); ``--rate-hz R`` makes the sample index the time base; stamps
  coarser than the samples are checked against the motion
  (:func:`station.analysis.iso9283.lab_files.coarse_clock`): on a clock that
  fails, ``--dwell-s W`` (the program's wait) gives the rate from the dwells,
  or else PST and MPT are refused (exit 3); so are those across a jump of
  the clock (:mod:`station.analysis.iso9283.clock_jumps`);
* ``--stops S.csv``: a stop list ``pose,cycle,x,y,z[,reflector][,approach]``; or
  ``--stops P1.txt P2.txt ...``: per-pose reflector lists ``reflector,x,y,z``
  (:mod:`station.readers.reflector_list`), the pose from the file name or ``--pose``;
  RP per reflector is printed beside the centroid's;
* ``--poses P.csv``: commanded poses ``name,x,y,z`` (required with a stream);
* ``--date-order mdy|dmy``: the day/month order of stamps like ``02/12/25`` when
  the file does not settle it (:mod:`station.readers.date_time`);
* ``--frame F.json`` or ``--register R.csv``: the poses are in the robot base
  frame; the measurements are carried into it (the registration's rms and
  residuals are printed).

Prints a table, writes the results JSON (``--json``) and exits with a code a
pipeline can trust (:mod:`app.commands.analyze_outcome`), the reasons on
stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import math
import sys
from contextlib import contextmanager

import numpy as np

from app.commands.analyze_inputs import (
    check_positive,
    load_stream,
    parse_limits,
    read_frame,
    window_parameters,
)
from app.commands.analyze_outcome import decide
from station.characteristics import limit_levels
from app.commands.analyze_table import format_stop_table, format_table
from station.errors import ConfigError, DataError
from station.readers.date_time import DATE_ORDERS
from station.verdict import Outcome, Verdict


def add_arguments(s: argparse.ArgumentParser) -> None:
    src = s.add_mutually_exclusive_group(required=True)
    src.add_argument("--stream", type=str, help="tracker stream: project CSV t,x,y,z[,status][,a,b,c], "
                                                "SpatialAnalyzer point export, or plain point list")
    src.add_argument("--stops", type=str, nargs="+", metavar="FILE",
                     help="a stop list CSV pose,cycle,x,y,z[,reflector][,approach], or per-pose reflector lists "
                          "(lines reflector,x,y,z, no header, ids repeating once per cycle), one file per pose")
    s.add_argument("--pose", type=str, nargs="+", default=None, metavar="NAME",
                   help="with per-pose reflector lists: the pose of each file, in order (default: from the file "
                        "name, e.g. P3.txt or list_pose3.txt)")
    s.add_argument("--poses", type=str, default=None,
                   help="commanded poses CSV name,x,y,z[,a,b,c] (required with --stream)")
    s.add_argument("--format", choices=("csv", "sa", "points"), default=None,
                   help="format of --stream (default: sniffed from its first lines)")
    s.add_argument("--group", default=None, help="SpatialAnalyzer group holding the stream")
    s.add_argument("--date-order", choices=DATE_ORDERS, default=None,
                   help="day/month order of A/B/Y dates in the stamps, when the file does not settle it and the "
                        "date changes during the run (mdy: month first, dmy: day first)")
    frame = s.add_mutually_exclusive_group()
    frame.add_argument("--frame", type=str, default=None,
                       help="JSON {R, t_mm}: p_tracker = R p_base + t (as station run journals it); --poses are then "
                            "in the robot base frame")
    frame.add_argument("--register", type=str, default=None,
                       help="CSV name,base_x,base_y,base_z,tracker_x,tracker_y,tracker_z (>= 3 pairs); --poses "
                            "are then in the robot base frame")
    s.add_argument("--register-max-rms-mm", type=float, default=None,
                   help="largest registration fit rms, mm (default: 10 x sqrt(3) x the tracker's noise, or the AP "
                        "limit when larger)")
    s.add_argument("--rate-hz", type=float, default=None,
                   help="sample rate, Hz: the sample index / rate is the time base (the file's stamps are not used)")
    s.add_argument("--dwell-s", type=float, default=None, metavar="W",
                   help="the program's wait at each stop, s: where the stamps are coarser than the samples and fail "
                        "their check against the motion, the dwells give the sample rate (emScon rates 1000/k Hz "
                        "preferred); --rate-hz overrides")
    s.add_argument("--window-samples", type=int, default=None,
                   help="with --rate-hz: horizon 2M+1 in samples (and every other sample count from it)")
    s.add_argument("--limit-mm", type=float, default=None,
                   help="manufacturer's position repeatability, mm: RP verdict and the POS/PST limit band")
    s.add_argument("--band", choices=("limit", "own"), default=None,
                   help="POS/PST limit band: the --limit-mm value (default when given) or each pose's own RP")
    s.add_argument("--limit", action="append", default=[], metavar="KEY=VALUE",
                   help="further limits, repeatable, e.g. AP_mm=5 PST_s=0.5; KEY one of "
                        + ", ".join(limit_levels()) + " (a station config's robots.<r>.limits take the same, "
                        "as ap_limit_mm, pst_limit_s, ...)")
    s.add_argument("--order", default=None, help="commanded order of one cycle, e.g. P2,P3,P4,P5,P1")
    s.add_argument("--distance", action="append", default=None, metavar="A,B",
                   help="pose pair for AD/RD (default P2,P4 when present); repeatable")
    s.add_argument("--linear-paths", action="store_true", help="moves are linear: compute AT/RT")
    s.add_argument("--window-s", type=float, default=0.1, help="moving horizon length 2M+1, s (default 0.1)")
    s.add_argument("--velocity-step-s", type=float, default=0.01,
                   help="interval of the velocity of eq. (3), s (default 0.01, the seed's sampling; "
                        "0 = successive samples at any rate)")
    s.add_argument("--assign-tol-mm", type=float, default=None,
                   help="largest distance from a stop to its commanded pose, mm (default 4 x (AP + RP limits) "
                        "within 5-25 with an AP limit, else 25)")
    s.add_argument("--initial-rest", choices=("count", "skip"), default="skip",
                   help="the rest before the first move: left out (skip, default: the seed's method, and the "
                        "files `station simulate` and `station run` write) or a stop of the pose it stands at "
                        "(count: a lab program that starts at rest at its first pose)")
    s.add_argument("--allow-other-stops", action="store_true",
                   help="stops far from every commanded pose are expected (via points): listed, not an error")
    s.add_argument("--require-iso", action="store_true",
                   help="exit 4 unless the run is ISO 9283 conformant (30 cycles, nothing missing, all decided)")
    s.add_argument("--json", type=str, default=None, help="write the results JSON here")
    u = s.add_argument_group("uncertainty and decision (ISO 14253-1)")
    u.add_argument("--decision-rule", choices=("simple", "guarded"), default="simple",
                   help="simple: the figure against the limit (default); guarded: pass only when figure + U is "
                        "within the limit, fail only when figure - U is beyond, else not decided (exit 3)")
    u.add_argument("--tracker-uncertainty", default=None, metavar="A+B/m",
                   help="the tracker's MPE per coordinate, um + um/m (k = 2 bound), e.g. 15+6/m, or a standard "
                        "deviation sd:7.5+3/m; states u and U of every figure (default with --decision-rule "
                        "guarded: 15+6/m)")
    u.add_argument("--tracker-noise", default=None, metavar="FILE",
                   help="the tracker's reading noise (a noise file, e.g. `analyze hold --noise-out`): the random "
                        "error of a reading is then its white and wander noise, and the MPE a systematic error of "
                        "the session (AP, AD); states u and U of every figure")
    u.add_argument("--temperature-u-k", type=float, default=0.0,
                   help="uncertainty of the air temperature of the tracker's compensation, K (default 0)")
    u.add_argument("--mc-trials", type=int, default=None, help="Monte Carlo trials (default 20000)")
    u.add_argument("--mc-seed", type=int, default=0, help="Monte Carlo seed (default 0)")


def _limits(args) -> tuple[dict, str]:
    from station.analysis.iso9283.characteristics import check_limits

    limits = parse_limits(args.limit)
    if args.limit_mm is not None:
        check_positive(args.limit_mm, "--limit-mm")
        limits.setdefault("RP_mm", args.limit_mm)
    limits = check_limits(limits)
    band = args.band or ("limit" if args.limit_mm is not None else "own")
    if band == "limit" and args.limit_mm is None:
        raise ConfigError("--band limit needs --limit-mm")
    return limits, band


def _pairs(args):
    if args.distance is None:
        return "auto"
    pairs = []
    for item in args.distance:
        ab = [s.strip() for s in item.split(",")]
        if len(ab) != 2 or not all(ab):
            raise ConfigError(f"--distance must be A,B, got {item!r}")
        pairs.append(tuple(ab))
    return pairs


def _tolerance(args, limits) -> float:
    from station.analysis.iso9283.characteristics import assignment_tolerance_mm

    if args.assign_tol_mm is not None:
        check_positive(args.assign_tol_mm, "--assign-tol-mm")
        return float(args.assign_tol_mm)
    return assignment_tolerance_mm(limits)


#: poses beyond which the JSON is written without indentation (json's C encoder: a stop list of 100,000 poses
#: spent most of its time in the indenting encoder written in Python)
INDENTED_POSES_MAX = 2000


def _write_json(path, d) -> None:
    """``d`` as JSON (indented up to :data:`INDENTED_POSES_MAX` poses); poses made in pieces
    (:class:`~station.json_pieces.Pieces`) are written a batch at a time."""
    from station.json_pieces import Pieces, dump_json
    from station.readers.out_files import output_file, write_output

    poses = d.get("poses") if isinstance(d, dict) else None
    if isinstance(poses, Pieces):
        with output_file(path, "--json") as fh:
            dump_json(fh, d)
            fh.write("\n")
    else:
        big = isinstance(poses, (dict, list)) and len(poses) > INDENTED_POSES_MAX
        write_output(path, (json.dumps(d) if big else json.dumps(d, indent=1)) + "\n", "--json")
    print(f"results written to {path}")


def _uncertainty(args, res, reg, points_by_row, rate_hz=None):
    """The result decided by the rule with every figure's uncertainty (unchanged when none is asked)."""
    if args.decision_rule == "simple" and args.tracker_uncertainty is None and args.tracker_noise is None:
        return res, None
    from station.analysis.iso9283.uncertainty import with_uncertainty
    from station.analysis.uncertainty import budget_from_options

    noise_um = None
    if args.tracker_noise is not None:
        from station.models.tracker_noise import read_tracker_noise

        noise_um = read_tracker_noise(args.tracker_noise, "--tracker-noise").total_um
    budget = budget_from_options(args.tracker_uncertainty, temperature_u_K=args.temperature_u_k,
                                 trials=args.mc_trials, seed=args.mc_seed, rate_hz=rate_hz, noise_um=noise_um)
    base = None
    if args.register is not None:
        from station.readers.registration_files import read_registration_csv

        base = read_registration_csv(args.register)[1]
    res, _, js, lines = with_uncertainty(res, budget.with_registration(reg, base), args.decision_rule,
                                         points_by_row)
    return res, (js, lines)


def _finish(res, d: dict, args, far: list[str], unc=None, time_refused: str = "") -> int:
    if unc is not None:
        print("\n".join(unc[1]))
        d.pop("uncertainty_figures", None)  # the same figures, in the block with the budget and the rule
        d["uncertainty"] = unc[0]
    out = decide(res, require_iso=args.require_iso, far_stops=far, allow_far=args.allow_other_stops)
    if time_refused:  # a time figure on a clock that failed its check is not stated: not decided
        out = Verdict(out.outcome if out.outcome is Outcome.FAIL else Outcome.NOT_DECIDED,
                      tuple(out.reasons) + (time_refused,))
    d["exit"] = {"code": out.exit_code, "reasons": list(out.reasons)}
    if args.json is not None:
        _write_json(args.json, d)
    for r in out.reasons:
        print(f"station: exit {out.exit_code}: {r}", file=sys.stderr)
    return out.exit_code


def run_iso9283(args: argparse.Namespace) -> int:
    from station.readers.out_files import check_outputs

    from station.analysis.uncertainty import MAX_TEMPERATURE_U_K

    check_outputs(args, json="--json")
    u_K = args.temperature_u_k
    if not (math.isfinite(u_K) and 0.0 <= u_K <= MAX_TEMPERATURE_U_K):
        raise ConfigError(f"--temperature-u-k must be within 0-{MAX_TEMPERATURE_U_K:g} K, got {u_K:g}")
    limits, band = _limits(args)
    if args.stops is not None:
        with _cycle_collection_paused():
            return _run_stops(args, limits)
    if args.poses is None:
        raise ConfigError("--poses is required with --stream (commanded poses name,x,y,z)")
    return _run_stream(args, limits, band)


@contextmanager
def _cycle_collection_paused():
    """Python's cycle collector paused (then as it was): a stop list of 100,000 poses makes millions of objects,
    none in a reference cycle, and the collector's full passes over them took seconds (a third of the analysis's
    time) and freed nothing."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _read_poses(args):
    from station.readers.stream_csv import read_poses_csv

    names, cmd, cori = read_poses_csv(args.poses)
    order = None
    if args.order:
        order = [s.strip() for s in args.order.split(",") if s.strip()]
        unknown = [s for s in order if s not in names]
        if unknown:
            raise ConfigError(f"--order names unknown pose(s) {', '.join(unknown)} (poses: {', '.join(names)})")
    return names, cmd, cori, order


def _run_stream(args, limits, band) -> int:
    from station.analysis.iso9283.lab_files import analyze_stream, rest_noise_mm

    if args.pose is not None:
        raise ConfigError("--pose applies to --stops (per-pose reflector lists), not to --stream")
    names, cmd, cori, order = _read_poses(args)
    extraction = dict(window_s=args.window_s, velocity_step_s=args.velocity_step_s,
                      assign_tol_mm=_tolerance(args, limits), initial_rest_stop=args.initial_rest == "count")
    extraction.update(window_parameters(args.window_samples, args.rate_hz))
    si = load_stream(args.stream, args.format, args.group, args.rate_hz, args.date_order,
                     command="analyze iso9283 --stream", wait_s=args.dwell_s)
    ps = si.points
    xyz = ps.xyz_mm.copy()
    valid = ps.valid
    ori = None if ps.abc_deg is None else np.radians(ps.abc_deg)
    if not valid.all():
        xyz[~valid] = 0.0  # rows left out by valid; never used
        if ori is not None:
            ori[~valid] = 0.0
    noise = rest_noise_mm(si.t_s[valid], xyz[valid])
    reg, reg_js = read_frame(args.frame, args.register, noise_mm=noise, robot_error_mm=limits.get("AP_mm"),
                             max_rms_mm=args.register_max_rms_mm, out=sys.stdout)
    if reg is not None:
        if ori is not None:
            raise DataError(f"{ps.source}: orientation a,b,c cannot be carried into the base frame here: drop the "
                            "columns, or give the poses in the tracker frame without --frame/--register")
        xyz = reg.to_base(xyz)
    lab = analyze_stream(
        si.t_s, xyz, valid, cmd, names=names, order=order,
        orientation_rad=ori, commanded_orientation_rad=None if cori is None else np.radians(cori),
        limits=limits, band_mm=args.limit_mm if band == "limit" else None, distance_pairs=_pairs(args),
        linear_paths=bool(args.linear_paths), extraction=extraction,
    )
    res, refused, why = _refuse_on_clock(lab.result, si)
    res, unc = _uncertainty(args, res, reg, xyz, None if si.refused else res.extraction.params.rate_hz)
    res, _, _ = _refuse_on_clock(res, si)  # the verdicts the uncertainty decided again: refused still
    print(format_table(res, ps.source, si.time_note, si.notes, estimated_rate=si.estimated_rate,
                       clock_refused=bool(si.refused)))
    d = res.to_dict()
    d["input"] = {"file": ps.source, "format": ps.fmt, "group": ps.group, "frame": ps.frame, "units": ps.units,
                  "notes": si.notes}
    d["time_base"] = dict(si.time_base)
    if si.estimated_rate:
        mark_estimated_times(d)
    if why:
        d["time_base"]["refused_figures"] = refused
        if si.refused:
            d["time_base"]["times_provisional"] = ("every t_s in this file is on the provisional rate that found "
                                                   "the stops, not a measured time")
    d["registration"] = reg_js
    return _finish(res, d, args, lab.far, unc, why)


def _refuse_on_clock(res, si):
    """PST and MPT refused on a clock that failed its check (every one) or across a jump of the clock.

    Returns ``(result, refused figures, reason for the exit code or "")``.
    """
    from station.analysis.iso9283.time_refusal import refuse_time_figures

    if si.refused:
        res, refused = refuse_time_figures(res, si.refused, short="the clock failed its check (see the time base)")
        return res, refused, f"time figures refused (PST, MPT): {si.refused}"
    if si.jumps:
        rows = [j.row for j in si.jumps]
        why = "; ".join(f"line {int(si.points.line[j.row])}: {j.text()}" for j in si.jumps) + \
            "; a time figure across a jump is not a measurement"
        res, refused = refuse_time_figures(res, why, jump_rows=rows, short="across a jump of the clock")
        return res, refused, (f"{', '.join(refused)} refused: {why}" if refused else "")
    return res, [], ""


def mark_estimated_times(d: dict) -> None:
    """Mark PST, MPT and drift in a results JSON as resting on a rate estimated from the stamps."""
    d["time_base"]["estimated_figures"] = ["PST_s", "MPT_s", "drift"]
    for pj in d.get("poses", {}).values():
        if isinstance(pj, dict):
            pj["PST_on_estimated_rate"] = True
    for m in d.get("MPT", []) or []:
        if isinstance(m, dict):
            m["on_estimated_rate"] = True


def _read_stops(args):
    """The stop list of ``--stops``: one CSV stop list, or per-pose reflector lists (one per pose)."""
    from station.readers.once import regular_file
    from station.readers.reflector_list import (
        combine_stop_lists,
        looks_like_reflector_list,
        pose_from_file_name,
        read_reflector_list,
    )
    from station.readers.stop_list import read_stop_list
    from station.readers.text import head_lines

    files = list(args.stops)
    if args.pose is not None and len(args.pose) != len(files):
        raise ConfigError(f"--pose names {len(args.pose)} pose(s) for {len(files)} file(s) of --stops: one per file")
    lists = []
    for k, f in enumerate(files):
        with regular_file(f) as (real, shown):
            try:
                if looks_like_reflector_list(head_lines(real)):
                    pose = args.pose[k] if args.pose is not None else pose_from_file_name(shown)
                    sl = read_reflector_list(real, pose)
                else:
                    if len(files) > 1:
                        raise DataError(f"{shown}: not a reflector list (reflector, x, y, z); several files are "
                                        "read as per-pose reflector lists, a stop list CSV comes alone")
                    if args.pose is not None:
                        raise ConfigError("--pose applies to per-pose reflector lists; a stop list CSV names its "
                                          "poses in its 'pose' column")
                    sl = read_stop_list(real)
            except DataError as exc:
                raise DataError(str(exc).replace(str(real), shown)) from None
        lists.append(dataclasses.replace(sl, source=shown))
    return combine_stop_lists(lists)


def _run_stops(args, limits) -> int:
    from station.analysis.iso9283.lab_files import analyze_stops, reflector_repeatability, stop_scatter_mm
    from station.analysis.iso9283.stop_list import POSES_PER_BATCH

    for opt in ("format", "group", "rate_hz", "dwell_s", "window_samples", "order", "linear_paths", "date_order"):
        if getattr(args, opt) not in (None, False):
            raise ConfigError(f"--{opt.replace('_', '-')} applies to --stream, not to --stops")
    sl = _read_stops(args)
    names = cmd = None
    if args.poses is not None:
        names, cmd, _, _ = _read_poses(args)
        known = set(names)
        for k, p in enumerate(sl.pose):
            if p not in known:
                raise DataError(f"{sl.source}: line {int(sl.lines[k].min())}, column 'pose': {p!r} is not in "
                                f"{args.poses} (poses: {', '.join(names)}; name each file's pose with --pose)")
    elif args.frame is not None or args.register is not None:
        raise ConfigError("--frame/--register need --poses (the commanded poses in the robot base frame)")
    pts = sl.points_mm
    noise = stop_scatter_mm(sl.centroid_mm, sl.pose)
    reg, reg_js = read_frame(args.frame, args.register, noise_mm=noise, robot_error_mm=limits.get("AP_mm"),
                             max_rms_mm=args.register_max_rms_mm, out=sys.stdout)
    if reg is not None:
        pts = reg.to_base(pts.reshape(-1, 3)).reshape(pts.shape)
    try:
        lab = analyze_stops(sl.pose, sl.cycle, pts, lines=sl.lines.min(axis=1), commanded_mm=cmd, names=names,
                            approach=sl.approach, reflectors=sl.reflectors, limits=limits,
                            distance_pairs=_pairs(args), assign_tol_mm=_tolerance(args, limits))
    except DataError as exc:
        if str(exc).startswith("line "):  # a stop of the file: say which file
            raise DataError(f"{sl.source}:{str(exc)[5:]}") from None
        raise
    res, unc = _uncertainty(args, lab.result, reg, None)
    per_refl = reflector_repeatability(sl.pose, pts, sl.reflectors) if len(sl.reflectors) > 1 else []
    print(format_stop_table(res, sl.source, reflector_rp=per_refl))
    # many poses: their JSON made as it is written (a batch at a time), never whole
    d = res.to_dict(poses_per_piece=POSES_PER_BATCH if len(res.poses) > INDENTED_POSES_MAX else None)
    d["input"] = {"file": sl.source, "format": "stops", "reflectors": [r for r in sl.reflectors if r]}
    d["stops"]["line"] = [int(x) for x in sl.lines.min(axis=1)]
    d["reflector_RP"] = [r.to_dict() for r in per_refl]
    d["time_base"] = None
    d["registration"] = reg_js
    return _finish(res, d, args, lab.far, unc)
