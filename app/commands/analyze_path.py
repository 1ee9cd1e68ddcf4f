"""``station analyze path``: ISO 9283 path characteristics of a stream against a path file.

``station analyze path --stream S --path PATH [--json OUT] [--limit KEY=V ...]``: the stream in any format
a lab exports (:func:`app.commands.analyze_inputs.load_stream`: its clock checked against its motion), the
commanded paths from the path file (README, "File formats"), the figures of
:mod:`station.analysis.path` with u and U, verdicts against ``--limit FIG=V`` (every path giving FIG) or
``--limit NAME.FIG=V`` (one path). Exit 0 every limit decided and passed, 1 one failed, 2 bad input, 3 not
decided (a figure refused: the reason is printed).
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from app.commands.analyze_inputs import load_stream, parse_limits
from station.errors import ConfigError


def add_arguments(s: argparse.ArgumentParser) -> None:
    s.add_argument("--stream", required=True, help="tracker stream: project CSV t,x,y,z[,status][,a,b,c], "
                                                  "SpatialAnalyzer point export, or plain point list")
    s.add_argument("--path", required=True, help="path file (JSON, or TOML by its .toml suffix)")
    s.add_argument("--format", choices=("csv", "sa", "points"), default=None, help="format of --stream")
    s.add_argument("--group", default=None, help="SpatialAnalyzer group holding the stream")
    s.add_argument("--rate-hz", type=float, default=None, help="the sample index is the time base at this rate")
    s.add_argument("--date-order", choices=("mdy", "dmy"), default=None, help="day/month order of the stamps")
    s.add_argument("--tracker-uncertainty", default=None, metavar="A+B/m",
                   help="the tracker's MPE (um + um/m), or sd:A+B/m (default 15+6/m MPE)")
    s.add_argument("--limit", action="append", default=None, metavar="KEY=VALUE",
                   help="FIG=V for every path giving FIG (e.g. AT_mm=0.5) or NAME.FIG=V for one path")
    s.add_argument("--seed", type=int, default=0, help="seed of the uncertainty's draws")
    s.add_argument("--json", default=None, help="write the results JSON here")


def run_path(args: argparse.Namespace) -> int:
    from station.analysis.path.analysis import analyze_paths, check_limits, verdicts
    from station.analysis.path.path_file import parse_path_text
    from station.analysis.uncertainty import budget_from_options
    from station.readers.out_files import check_outputs, write_output
    from station.verdict import EXIT_FAIL, EXIT_PASS, EXIT_UNDECIDED

    check_outputs(args, json="--json")
    try:
        text = open(args.path, encoding="utf-8").read()
    except OSError as exc:
        raise ConfigError(f"--path {args.path}: cannot read it: {exc.strerror or exc}") from None
    specs = parse_path_text(text, args.path)
    limits = check_limits(parse_limits(args.limit), specs)
    budget = budget_from_options(args.tracker_uncertainty, seed=args.seed)
    si = load_stream(args.stream, args.format, args.group, args.rate_hz, args.date_order, command="analyze path")
    ps = si.points
    refused = si.refused
    jump_rows = [int(getattr(j, "row", j)) for j in si.jumps]
    res = analyze_paths(specs, si.t_s, ps.xyz_mm, ps.valid, abc_deg=ps.abc_deg, noise_sd_mm=budget.instrument_sd_mm,
                        clock_refused=refused, jump_rows=jump_rows, seed=args.seed, k=budget.k)
    vs = verdicts(res, limits)
    lines = [f"paths of {ps.source}: {ps.n} samples ({int(np.count_nonzero(~ps.valid))} flagged invalid)",
             si.time_note, *[f"note: {x}" for x in si.notes]]
    for name, r in res.items():  # loop over paths
        lines.append(f"{name} ({r.kind}): {r.n_cycles} cycles")
        for fig, v in r.figures.items():  # loop over figures
            fu = r.uncertainty.get(fig)
            if v is None:
                lines.append(f"  {fig:<11} REFUSED: {r.refused.get(fig, 'not computed')}")
            else:
                lines.append(f"  {fig:<11} {v:10.4f}  u {fu.u:.4f}  U {fu.U:.4f}" if fu else f"  {fig:<11} {v:10.4f}")
        lines += [f"  note: {x}" for x in r.notes]
    for v in vs:  # loop over verdicts
        lines.append(f"verdict {v['path']}.{v['characteristic']} <= {v['limit']:g}: {v['outcome']}"
                     + (f" ({v['reason']})" if v["reason"] else ""))
    print("\n".join(x for x in lines if x))
    if args.json is not None:
        d = {"input": {"stream": ps.source, "format": ps.fmt, "path_file": args.path, "n": int(ps.n),
                       "n_invalid": int(np.count_nonzero(~ps.valid)), "notes": si.notes},
             "time_base": dict(si.time_base), "budget": budget.to_dict() if hasattr(budget, "to_dict") else None,
             "paths": {n: r.to_dict() for n, r in res.items()}, "verdicts": vs}
        write_output(args.json, json.dumps(d, indent=1, default=float) + "\n", "--json")
        print(f"results written to {args.json}")
    outs = {v["outcome"] for v in vs}
    if "FAIL" in outs:
        return EXIT_FAIL
    if "NOT DECIDED" in outs:
        print("station: exit 3: " + "; ".join(f"{v['path']}.{v['characteristic']}: {v['reason']}" for v in vs
                                             if v["outcome"] == "NOT DECIDED"), file=sys.stderr)
        return EXIT_UNDECIDED
    return EXIT_PASS
