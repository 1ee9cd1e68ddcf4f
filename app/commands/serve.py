"""`station serve --config C`: the operator's page for one station (issue 16).

Serves on loopback by default; never on every interface (decided by the
address the socket binds). Every request needs the access token printed at
start, on loopback too (the printed URL carries it; the browser keeps it in
a cookie). Without
``--arm`` every run uses the procedure's fake cell, as ``station run`` does;
with ``--arm`` the configured devices, after the operator confirms on the
page. ``--demo`` serves the demo station (the config of ``station demo``,
store and reports under ``--out``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from station.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="the operator's page: watch and steer runs from a browser",
                       description="Serve the operator's page on this host: start, watch, pause, abort and resume "
                                   "runs, answer their prompts and read their reports from a browser. Dry runs "
                                   "use the fake cell; with --arm the configured devices move and the page's "
                                   "button is the person's answer.")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--config", help="station config (TOML or JSON)")
    src.add_argument("--demo", action="store_true", help="serve the demo station (fake cell, as `station demo`)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; never every interface)")
    p.add_argument("--port", type=int, default=8700, help="port (default 8700; 0: any free port)")
    p.add_argument("--arm", action="store_true", help="runs use the configured devices: real hardware moves")
    p.add_argument("--time-scale", type=float, default=20.0, help="fake cell: simulated s per real s (default 20)")
    p.add_argument("--out", default=None, help="--demo: directory for the store and reports (default ./demo-runs)")
    p.add_argument("--cycles", type=int, default=30, help="--demo: pose cycles (ISO: 30)")
    p.add_argument("--vap-cycles", type=int, default=30, help="--demo: multi-directional cycles (ISO: 30)")
    p.add_argument("--rate", type=float, default=100.0, help="--demo: tracker rate, Hz")
    p.set_defaults(func=_cmd_serve)


def _cmd_serve(args: argparse.Namespace) -> int:
    from station.config import config_from_dict, load_config
    from app.web.server import WebServer

    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port must be 0..65535, got {args.port}")
    if not args.time_scale > 0:
        raise ConfigError(f"--time-scale must be > 0, got {args.time_scale}")
    from app.web.security import listen_problem

    problem = listen_problem(args.host)
    if problem:
        raise ConfigError(problem)
    if args.demo:
        from fakes.cells import demo_config

        if args.arm:
            raise ConfigError("--demo runs on the fake cell; --arm makes no sense with it")
        from station.readers.out_files import output_dir

        out = output_dir(args.out if args.out else Path.cwd() / "demo-runs", "--out").resolve()
        cfg = config_from_dict(demo_config(out, cycles=args.cycles, vap_cycles=args.vap_cycles, rate_hz=args.rate),
                               "demo config")
        base = out
    else:
        cfg = load_config(args.config)
        base = Path(args.config).resolve().parent
    server = WebServer(cfg, base, host=args.host, port=args.port, arm=args.arm, time_scale=args.time_scale)
    mode = "ARMED: configured devices, real hardware moves" if args.arm else "dry runs on the fake cell"
    print(f"station {cfg.station.name!r} ({mode}); store {cfg.station.store_file(base)}")
    print(f"open {server.url}", flush=True)
    print("every request needs the access token in that URL (keep it to yourself; the browser keeps it in a "
          "cookie)")
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    return 0
