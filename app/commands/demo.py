"""`station demo`: the whole ISO 9283 procedure on the fake station.

Starts a simulated cell (industrial arm with realistic errors, emScon
tracker fake, controller fake with FTP upload and Modbus TCP; with
``--robot ur5e`` a UR arm and the UR fake that ``ur_rtde`` talks to) on loopback,
runs the full procedure of seed 000 Table 3 (30 pose cycles P1..P5 at rated
speed, 30 multi-directional cycles, registration, analysis, report) through
the real drivers in accelerated time, prints the results table and the
report's path.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from station.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="ISO 9283 on the fake station, end to end, in accelerated time",
                       description="Run the whole ISO 9283 pose procedure (seed 000 Table 3: registration, pose "
                                   "cycles P1..P5, multi-directional cycles, analysis, report) through the real "
                                   "drivers against the fake cell on loopback, print the verdict, the figures "
                                   "and the report's path. Nothing real moves. The simulated cell runs in "
                                   "lockstep: one --seed gives the same figures at any pace or load.")
    p.add_argument("--out", default=None, help="directory for the store and the report (default: ./demo-runs)")
    p.add_argument("--cycles", type=int, default=30, help="pose cycles (ISO: 30)")
    p.add_argument("--vap-cycles", type=int, default=30, help="multi-directional cycles (ISO: 30)")
    p.add_argument("--time-scale", type=float, default=None,
                   help="simulated seconds per real second at most (default: full pace, as fast as the host goes; "
                        "the figures are the same at any pace; give e.g. 20 to watch it)")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated cell")
    p.add_argument("--rate", type=float, default=100.0, help="tracker rate, Hz (seed 000: 100)")
    p.add_argument("--robot", default="industrial-3100",
                   help="robot model of the fake cell (default industrial-3100 with the FTP+Modbus controller; "
                        "ur5e / ur10e: the UR fake through ur_rtde, the seed's cube scaled to the arm)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress line (the results are still printed)")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args: argparse.Namespace) -> int:
    from app.assemble import RunRequest, run_procedure
    from fakes.cells import demo_config
    from fakes.station import FULL_PACE
    from station.config import config_from_dict

    from station.readers.out_files import check_outputs, output_dir

    check_outputs(args, json="--json")
    out = output_dir(args.out if args.out else Path.cwd() / "demo-runs", "--out")
    cfg = config_from_dict(demo_config(out.resolve(), cycles=args.cycles, vap_cycles=args.vap_cycles,
                                       rate_hz=args.rate, robot=args.robot), "demo config")
    if args.time_scale is not None and not 0 < args.time_scale <= FULL_PACE:
        raise ConfigError(f"--time-scale must be > 0 and at most {FULL_PACE:g}, got {args.time_scale}")
    scale = FULL_PACE if args.time_scale is None else args.time_scale
    pace = "full pace" if args.time_scale is None else f"{scale:g}x real time"
    print(f"demo: fake cell (seed {args.seed}, {pace}), store {out / 'station.sqlite'}", file=sys.stderr)
    outcome = run_procedure(RunRequest(cfg, "iso9283", yes=True, time_scale=scale, seed=args.seed,
                                       json_out=args.json, quiet=args.quiet, config_dir=out))
    for line in outcome.lines():  # the verdict first (exit codes as `station run`'s)
        print(line)
    return outcome.exit_code
