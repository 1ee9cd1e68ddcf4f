"""`station fakes serve NAME`: start one simulated device on loopback.

Prints the endpoint as one JSON line first (e.g. ``{"host": ..., "port": ...}``
or ``{"device": "/dev/pts/N"}``), then serves until interrupted.

The fakes are the table of :mod:`fakes.registry` (from the device table's
rows). Each fake module exposes ``start_fake(world, *, host=None, port=None,
faults=None) -> handle`` where ``handle.endpoint`` is a JSON-able dict and
``handle.close()`` stops its servers and joins their threads.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

from station.errors import ConfigError



def parse_faults(items: list[str]) -> dict[str, str]:
    """``["beam_break=2.0:0.3", "slow_reply_s=0.5"]`` -> dict; refuses malformed items."""
    faults: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--fault must be KEY=VALUE, got {item!r}")
        faults[key.strip()] = value.strip()
    return faults


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fakes", help="run simulated devices on loopback")
    fsub = p.add_subparsers(dest="fakes_cmd", metavar="ACTION")
    s = fsub.add_parser("serve", help="start one fake and serve until interrupted",
                        description="Start one simulator-backed fake (or the whole station's) on loopback and "
                                    "serve until interrupted; the device URLs it prints go into a config, so the "
                                    "station (with --arm) drives it as it would the real device.")
    from fakes.registry import SERVABLE

    s.add_argument("name", choices=sorted(SERVABLE), help="which fake (station: the whole cell)")
    s.add_argument("--host", default=None, help="loopback address to bind (default: the fake's own)")
    s.add_argument("--port", type=int, default=None, help="port (default: the fake's own or 0)")
    s.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per real second")
    s.add_argument("--seed", type=int, default=0, help="seed of the simulated world")
    s.add_argument("--robot", default=None,
                   help="robot model of the simulated arm (default: the fake's own, ur5e for ur, else industrial-3100)")
    s.add_argument("--fault", action="append", default=[], metavar="KEY=VALUE",
                   help="fault injection, repeatable (see the fake's docs)")
    s.add_argument("--motion-model", metavar="M.json", default=None,
                   help="a diagnosed motion model (station diagnose motion --model-out): the simulated arm moves "
                        "with its loop, and its creep, structural mode and the tracker's drift show in the readings")
    s.set_defaults(func=_serve)


def _serve(args: argparse.Namespace) -> int:
    from fakes.registry import fake_module
    from fakes.sim.world import make_world

    faults = parse_faults(args.fault)
    module = fake_module(args.name)
    world_kwargs = {"seed": args.seed, "time_scale": args.time_scale}
    if args.motion_model:
        from station.models.motion_model_file import read_motion_model

        world_kwargs["motion_model"] = read_motion_model(args.motion_model)
    # a fake simulates the robot its protocol belongs to unless told otherwise (a UR fake is a UR)
    robot = args.robot or getattr(module, "DEFAULT_ROBOT", None)
    if robot:
        world_kwargs["robot"] = robot
    world = make_world(**world_kwargs)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    handle = module.start_fake(world, host=args.host, port=args.port, faults=faults)
    try:
        print(json.dumps(handle.endpoint), flush=True)
        stop.wait()
    finally:
        handle.close()
        world.close()
    print("stopped", file=sys.stderr)
    return 0
