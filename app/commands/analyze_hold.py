"""``station analyze hold --stream S``: a held pose (:mod:`station.analysis.iso9283.hold`).

The stream in any format ``analyze iso9283`` reads (sniffed, ``--format``,
``--group``), with its time stamps or ``--rate-hz``. Prints noise, drift and
the RP-style window figure; ``--json`` writes them. Exit 0, 2 on bad input
(a stream with a move in it included), or 3 when the clock failed its check
(coarse stamps that disagree among themselves) or jumped during the hold:
drift per minute and the windows are then refused, with the reason.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from app.commands.analyze_inputs import check_positive, load_stream
from station.readers.date_time import DATE_ORDERS


def add_arguments(h: argparse.ArgumentParser) -> None:
    h.add_argument("--stream", required=True, help="the held pose's stream (project CSV, SpatialAnalyzer export, "
                                                   "plain point list)")
    h.add_argument("--format", choices=("csv", "sa", "points"), default=None, help="format (default: sniffed)")
    h.add_argument("--group", default=None, help="SpatialAnalyzer group holding the stream")
    h.add_argument("--date-order", choices=DATE_ORDERS, default=None,
                   help="day/month order of A/B/Y dates in the stamps, when the file does not settle it")
    h.add_argument("--rate-hz", type=float, default=None, help="sample rate: the sample index / rate is the time base")
    h.add_argument("--window-s", type=float, default=1.0, help="window of the RP-style figure, s (default 1)")
    h.add_argument("--json", default=None, help="write the results JSON here")
    h.add_argument("--noise-out", default=None, metavar="FILE",
                   help="write the tracker's reading noise fitted from the hold (white sd, wander sd and its time "
                        "constant; the file `simulate ... --tracker-noise` reads)")


def run_hold(args: argparse.Namespace) -> int:
    from station.analysis.iso9283.hold import analyze_hold
    from station.analysis.iso9283.tracker_noise_fit import MIN_FIT_SAMPLES

    from station.readers.out_files import check_outputs

    check_positive(args.window_s, "--window-s")
    check_outputs(args, json="--json", noise_out="--noise-out")
    si = load_stream(args.stream, args.format, args.group, args.rate_hz, args.date_order,
                     command="analyze hold")
    ps = si.points
    xyz = ps.xyz_mm.copy()
    xyz[~ps.valid] = 0.0  # flagged rows: never used
    res = analyze_hold(si.t_s, xyz, ps.valid, window_s=args.window_s)
    refused = _refused(si)
    ax = "xyz"
    span = "samples" if refused else f"samples over {res.duration_s:.3f} s"
    lines = [f"held pose in {ps.source}: {res.n} {span} ({int((~ps.valid).sum())} flagged invalid)", si.time_note]
    lines += [f"note: {x}" for x in si.notes]
    lines += [
        "mean        " + "  ".join(f"{a} {v:.4f}" for a, v in zip(ax, res.mean_mm)) + " mm",
        "noise       " + "  ".join(f"{a} {v:.4f}" for a, v in zip(ax, res.noise_mm))
        + f" mm;  3-D {res.noise_3d_mm:.4f} mm (about the drift line)",
    ]
    if refused:
        lines += [f"drift       REFUSED: {refused}", "windows     REFUSED: they are windows of time on the same clock"]
    else:
        lines += [
            "drift       " + "  ".join(f"{a} {v:+.4f}+/-{s:.4f}" for a, v, s in
                                       zip(ax, res.drift_mm_per_min, res.drift_sd_mm_per_min))
            + f" mm/min;  3-D {res.drift_3d_mm_per_min:.4f} mm/min",
            f"windows     {res.l_mm.size} of {res.window_s:g} s: RP-style l_bar + 3 S_l = {res.RP_mm:.4f} mm "
            f"(l_bar {res.l_bar_mm:.4f}, S_l {res.S_l_mm:.4f})"
            + (f"; {res.n_dropped} samples of short windows left out" if res.n_dropped else ""),
        ]
    fit = res.noise_fit
    if fit is None:
        lines.append(f"tracker noise: not fitted (fewer than {MIN_FIT_SAMPLES} valid samples)")
    elif refused:
        lines.append("tracker noise: REFUSED: its wander's time constant is on the same clock")
    else:
        tau = "no wander resolved" if fit.wander_tau_s is None else \
            f"wander {fit.wander_um:.3f} um, time constant {fit.wander_tau_s:.3f} s"
        lines.append(f"tracker noise: white {fit.white_um:.3f} um per axis, {tau} ({fit.note})")
    if si.estimated_rate:
        lines.append("drift per minute and the windows rest on the rate estimated from the stamps")
    print("\n".join(lines))
    if args.json is not None:
        d = res.to_dict()
        d["input"] = {"file": ps.source, "format": ps.fmt, "group": ps.group, "units": ps.units, "notes": si.notes,
                      "n_invalid": int(np.count_nonzero(~ps.valid))}
        d["time_base"] = dict(si.time_base)
        if si.estimated_rate:
            d["time_base"]["estimated_figures"] = ["drift", "windows"]
        if refused:
            for k in ("duration_s", "drift_mm_per_min", "drift_sd_mm_per_min", "drift_3d_mm_per_min", "windows"):
                d[k] = None
            d["tracker_noise"] = None
            d["time_base"]["refused_figures"] = ["duration_s", "drift", "windows", "tracker_noise"]
            d["time_base"]["refused"] = refused
        from station.readers.out_files import write_output

        write_output(args.json, json.dumps(d, indent=1, allow_nan=False) + "\n", "--json")  # never NaN in JSON
        print(f"results written to {args.json}")
    if args.noise_out is not None:
        from station.errors import InsufficientDataError
        from station.readers.out_files import write_output

        if fit is None:
            raise InsufficientDataError(f"--noise-out: the hold has {res.n} valid samples; the noise fit needs at "
                                        f"least {MIN_FIT_SAMPLES}")
        if refused:
            raise InsufficientDataError(f"--noise-out: the wander's time constant would rest on a clock that "
                                        f"failed its check: {refused}")
        write_output(args.noise_out, json.dumps(fit.to_dict(f"fit of the held pose {ps.source}"), indent=1)
                     + "\n", "--noise-out")
        print(f"tracker noise written to {args.noise_out}")
    if refused:
        from station.verdict import EXIT_UNDECIDED

        print(f"station: exit {EXIT_UNDECIDED}: drift per minute and the windows refused: {refused}", file=sys.stderr)
        return EXIT_UNDECIDED
    return 0


def _refused(si) -> str:
    """Why no time figure of the hold may be stated: a clock that failed its check, or one that jumped."""
    if si.refused:
        return si.refused
    if si.jumps:
        return ("; ".join(f"line {int(si.points.line[j.row])}: {j.text()}" for j in si.jumps)
                + "; a drift per minute across a jump is not a measurement")
    return ""
