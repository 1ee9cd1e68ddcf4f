"""`station analyze ...`: analyses of recorded data files (argument parsing; the work is in the modules named).

``station analyze iso9283 (--stream S | --stops S.csv) [--poses P.csv] [--frame F.json | --register R.csv]
[--rate-hz R] [--limit-mm L] [--limit KEY=VALUE] [--require-iso] [--json OUT]``
    ISO 9283 pose characteristics of a tracker stream in any format a lab
    exports, or of a stop list (:mod:`app.commands.analyze_iso`).

``station analyze path --stream S --path PATH [--limit KEY=VALUE] [--json OUT]``
    ISO 9283 path characteristics against a path file (:mod:`app.commands.analyze_path`).

``station analyze hold --stream S [--rate-hz R] [--window-s W] [--json OUT]``
    A held pose: noise, drift and the RP-style figure over windows
    (:mod:`app.commands.analyze_hold`).

Exit codes (:mod:`app.commands.analyze_outcome`): 0 every asked limit
decided and passed, 1 a limit failed, 2 bad input, 3 not decided, 4 not ISO
conformant with ``--require-iso``; the reasons on stderr.
"""

from __future__ import annotations

import argparse
import sys


def register(sub: argparse._SubParsersAction) -> None:
    from app.commands.analyze_hold import add_arguments as hold_arguments
    from app.commands.analyze_iso import add_arguments as iso_arguments

    p = sub.add_parser("analyze", help="analyse recorded data files")
    asub = p.add_subparsers(dest="analyze_cmd", metavar="ANALYSIS")
    s = asub.add_parser(
        "iso9283",
        help="ISO 9283 pose characteristics from a tracker stream or a stop list",
        description="Attained poses from a continuous tracker stream (seed 000 method), or one point per stop "
        "from a stop list, and the ISO 9283 characteristics AP, RP, POS, PST, vAP, AD, RD, MPT (+ orientation, "
        "drift, AT/RT where the data carry them), with verdicts. Exit 0 only when every asked limit was decided "
        "and passed; 1 a limit failed; 2 bad input; 3 not decided; 4 not ISO conformant with --require-iso.",
    )
    iso_arguments(s)
    s.set_defaults(func=_iso9283)
    from app.commands.analyze_path import add_arguments as path_arguments

    pth = asub.add_parser(
        "path",
        help="ISO 9283 path characteristics (AT, RT, CR, CO, AV, RV, FV, WS, WF) against a path file",
        description="Cycles of each commanded path of the path file found in the stream, and the figures of "
        "ISO 9283 clauses 8.2-8.5 and 11 with their u and U. Exit 0 only when every asked limit was decided "
        "and passed; 1 a limit failed; 2 bad input; 3 not decided.",
    )
    path_arguments(pth)
    pth.set_defaults(func=_path)
    h = asub.add_parser(
        "hold",
        help="a held pose: noise, drift and the RP-style figure over windows",
        description="A stream without moves (the robot stands still): per-axis and 3-D noise, drift per "
        "minute, and l_bar + 3 S_l (eq. (2)) of the window means about their barycentre.",
    )
    hold_arguments(h)
    h.set_defaults(func=_hold)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _iso9283(args: argparse.Namespace) -> int:
    from app.commands.analyze_iso import run_iso9283

    return run_iso9283(args)


def _path(args: argparse.Namespace) -> int:
    from app.commands.analyze_path import run_path

    return run_path(args)


def _hold(args: argparse.Namespace) -> int:
    from app.commands.analyze_hold import run_hold

    return run_hold(args)


if __name__ == "__main__":  # pragma: no cover
    from app.cli import main

    sys.exit(main(["analyze", *sys.argv[1:]]))
