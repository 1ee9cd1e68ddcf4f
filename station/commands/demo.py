"""`station demo`: the whole ISO 9283 procedure on the fake station.

Starts a simulated cell (industrial arm with realistic errors, emScon
tracker fake, controller fake with FTP upload and Modbus TCP) on loopback,
runs the full procedure of seed 000 Table 3 (30 pose cycles P1..P5 at rated
speed, 30 multi-directional cycles, registration, analysis, report) through
the real drivers in accelerated time, prints the results table and the
report's path.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="ISO 9283 on the fake station, end to end, in accelerated time")
    p.add_argument("--out", default=None, help="directory for the store and the report (default: ./demo-runs)")
    p.add_argument("--cycles", type=int, default=30, help="pose cycles (ISO: 30)")
    p.add_argument("--vap-cycles", type=int, default=30, help="multi-directional cycles (ISO: 30)")
    p.add_argument("--time-scale", type=float, default=20.0, help="simulated seconds per real second")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated cell")
    p.add_argument("--rate", type=float, default=100.0, help="tracker rate, Hz (seed 000: 100)")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_demo)


def demo_config(out: Path, *, cycles: int, vap_cycles: int, rate_hz: float) -> dict:
    """The demo station's config; device URLs are replaced by the fakes' at start."""
    return {
        "station": {"name": "demo cell", "store_path": str(out / "station.sqlite"), "report_dir": str(out / "reports")},
        "devices": {"tracker": {"url": "fake://tracker-emscon"}, "controller": {"url": "fake://controller"}},
        "robots": {
            "r1": {
                "model": "industrial-3100", "serial": "DEMO-0001", "overhaul_state": "after", "payload_kg": 0.0,
                "controller": "controller",
                "workspace": {"min_mm": [-900.0, 800.0, 500.0], "max_mm": [900.0, 2600.0, 2300.0],
                              "max_tcp_speed_mm_s": 2000.0},
                "limits": {"rp_limit_mm": 0.5, "ap_limit_mm": 5.0, "vap_limit_mm": 2.0, "ad_limit_mm": 2.0},
            }
        },
        "iso9283": {"cycles": cycles, "vap_cycles": vap_cycles, "tracker_rate_hz": rate_hz},
    }


def _cmd_demo(args: argparse.Namespace) -> int:
    from station.commands.run import execute
    from station.config import config_from_dict

    out = Path(args.out) if args.out else Path.cwd() / "demo-runs"
    out.mkdir(parents=True, exist_ok=True)
    cfg = config_from_dict(demo_config(out.resolve(), cycles=args.cycles, vap_cycles=args.vap_cycles,
                                       rate_hz=args.rate), "demo config")
    print(f"demo: fake cell (seed {args.seed}, {args.time_scale:g}x real time), store {out / 'station.sqlite'}")
    return execute(cfg, procedure="iso9283", yes=True, time_scale=args.time_scale, seed=args.seed,
                   json_out=args.json, quiet=args.quiet, config_dir=out)
