"""`station calibrate ...`: calibrations from recorded data.

``station calibrate trailer --data T.csv [--method M] [--json OUT]``
    Link lengths L1, L2 of the two-link trailer (seed 003) from a CSV with
    a header and columns ``t,kappa,psi`` (s, 1/m, rad) and optionally ``v``
    (m/s) and ``kappa_cmd`` (1/m, the commanded curvature in force, which
    ``dynamic`` uses as an instrument when it explains the measured one);
    rows in time order; curvature and speed are averages over the interval
    ending at ``t`` as odometry reports them (``--sampling point`` for
    instantaneous values). Methods: ``M1``..``M24`` (seed Table 3),
    ``odr`` (orthogonal distance regression on eq. (23)), ``dynamic`` (the
    joint-angle dynamics; needs ``v``), ``auto`` (default: ``dynamic`` if the
    file has ``v``, else ``M17``). Prints the result; ``--json`` writes it
    with the keys ``method``, ``L1_m``, ``L2_m``, ``L1_sigma_m``,
    ``L2_sigma_m`` (standard uncertainties), ``L1_L2_corr``,
    ``condition_number``, ``n_samples``, ``details``, ``warnings``.
"""

from __future__ import annotations

import argparse
import json

from station.analysis.trailer.estimate import estimate_trailer
from station.errors import ConfigError, DataError
from station.readers.trailer_csv import (  # noqa: F401  (re-exported for callers of the command module)
    OPTIONAL_COLUMNS, TRAILER_COLUMNS, read_trailer_csv, write_trailer_csv)

TRAILER_METHODS = tuple(f"M{i}" for i in range(1, 25)) + ("odr", "dynamic", "auto")


def format_estimate(est) -> str:
    """Human-readable lines of a TrailerEstimate."""
    lines = [
        f"method            {est.method}" + (f"  ({est.details['label']})" if "label" in est.details else ""),
        f"L1                {est.L1_m:.4f} m  +- {est.L1_sigma_m:.4f} m (1 sigma)",
        f"L2                {est.L2_m:.4f} m  +- {est.L2_sigma_m:.4f} m (1 sigma)",
        f"correlation       {est.L1_L2_corr:+.3f}",
        f"condition number  {est.condition_number:.4g}",
        f"samples           {est.n_samples}",
    ]
    if "input" in est.details:
        lines.append(f"input             {est.details['input']}")
    for w in est.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def register(sub: argparse._SubParsersAction) -> None:
    from app.commands.help_text import plain

    p = sub.add_parser("calibrate", help="calibrations from recorded data")
    csub = p.add_subparsers(dest="calibrate_cmd", metavar="WHAT")
    t = csub.add_parser("trailer", help="link lengths of the two-link trailer (seed 003)",
                        description=plain(__doc__.split("\n\n")[1]))
    t.add_argument("--data", required=True, metavar="CSV", help="t,kappa,psi[,v] in s, 1/m, rad, m/s")
    t.add_argument("--method", default="auto", choices=TRAILER_METHODS,
                   help="M1..M24 (seed Table 3), odr, dynamic, or auto (default)")
    t.add_argument("--sampling", default="interval", choices=("interval", "point"),
                   help="curvature/speed rows are averages over the interval ending at t "
                        "(odometry, default) or instantaneous values (method dynamic)")
    t.add_argument("--no-command", action="store_true",
                   help="ignore a kappa_cmd column (method dynamic uses it as an instrument)")
    t.add_argument("--json", metavar="OUT", help="write the result as JSON")
    t.set_defaults(func=_trailer)
    from app.commands.calibrate_arm import add_parser as add_arm

    add_arm(csub)


def _trailer(args: argparse.Namespace) -> int:
    from station.readers.out_files import check_outputs

    check_outputs(args, json="--json")
    data = read_trailer_csv(args.data)
    method = args.method
    if method == "auto":
        method = "dynamic" if "v" in data else "M17"
    if method == "dynamic" and "v" not in data:
        raise DataError(f"{args.data}: method 'dynamic' needs the speed column v")
    if method not in TRAILER_METHODS:
        raise ConfigError(f"unknown method {method!r}")
    est = estimate_trailer(data, method, sampling=args.sampling, use_command=not args.no_command)
    print(format_estimate(est))
    if args.json:
        out = est.to_json()
        out["data"] = str(args.data)
        from station.readers.out_files import write_output

        write_output(args.json, json.dumps(out, indent=2) + "\n", "--json")
    return 0


__all__ = ["register", "read_trailer_csv", "write_trailer_csv", "format_estimate", "TRAILER_METHODS",
           "TRAILER_COLUMNS", "OPTIONAL_COLUMNS"]
