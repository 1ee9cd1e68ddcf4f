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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="ISO 9283 on the fake station, end to end, in accelerated time")
    p.add_argument("--out", default=None, help="directory for the store and the report (default: ./demo-runs)")
    p.add_argument("--cycles", type=int, default=30, help="pose cycles (ISO: 30)")
    p.add_argument("--vap-cycles", type=int, default=30, help="multi-directional cycles (ISO: 30)")
    p.add_argument("--time-scale", type=float, default=20.0, help="simulated seconds per real second")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated cell")
    p.add_argument("--rate", type=float, default=100.0, help="tracker rate, Hz (seed 000: 100)")
    p.add_argument("--robot", default="industrial-3100",
                   help="robot model of the fake cell (default industrial-3100 with the FTP+Modbus controller; "
                        "ur5e / ur10e: the UR fake through ur_rtde, the seed's cube scaled to the arm)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args: argparse.Namespace) -> int:
    from fakes.cells import demo_config
    from app.assemble import run_procedure
    from station.config import config_from_dict

    out = Path(args.out) if args.out else Path.cwd() / "demo-runs"
    out.mkdir(parents=True, exist_ok=True)
    cfg = config_from_dict(demo_config(out.resolve(), cycles=args.cycles, vap_cycles=args.vap_cycles,
                                       rate_hz=args.rate, robot=args.robot), "demo config")
    print(f"demo: fake cell (seed {args.seed}, {args.time_scale:g}x real time), store {out / 'station.sqlite'}",
          file=sys.stderr)
    outcome = run_procedure(cfg, "iso9283", yes=True, time_scale=args.time_scale, seed=args.seed,
                            json_out=args.json, quiet=args.quiet, config_dir=out)
    for line in outcome.lines():  # the verdict first (exit codes as `station run`'s)
        print(line)
    return outcome.exit_code
