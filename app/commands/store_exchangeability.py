"""`station store exchangeability`: ISO 9283 7.8 over the stored ISO runs of robots of one model.

    station store exchangeability --config C --model M [--central] [--json]
    station store exchangeability --config C --serials A,B,C [--central] [--json]

Refused (exit 2, with the reason) when fewer than two robots have finished ISO 9283 runs, when their runs
are not one test programme (poses, payload, speed, dwell, cycles, model), or not on one mounting in one frame
(a run without a mounting frame, different mountings, frames that are not one, a base too far from the frame).
"""

from __future__ import annotations

import json

from app.commands.store_open import CENTRAL_HELP, CONFIG_HELP, JSON_HELP, open_store


def register(s) -> None:
    x = s.add_parser("exchangeability", help="ISO 9283 7.8: how far apart robots of one model put the same poses "
                                             "(from their latest ISO 9283 runs)")
    x.add_argument("--config", required=True, help=CONFIG_HELP)
    x.add_argument("--central", action="store_true", help=CENTRAL_HELP)
    who = x.add_mutually_exclusive_group(required=True)
    who.add_argument("--model", default=None, help="every robot of this model")
    who.add_argument("--serials", default=None, help="these robots, comma-separated serials")
    x.add_argument("--json", action="store_true", help=JSON_HELP)
    x.set_defaults(func=_exchangeability)


def _exchangeability(args) -> int:
    from station.fleet.exchangeability import fleet_exchangeability

    serials = None if args.serials is None else args.serials.split(",")
    with open_store(args.config, args.central) as store:
        result, runs = fleet_exchangeability(store, model=args.model, serials=serials)
    if args.json:
        print(json.dumps({**result.to_dict(), "runs": runs}, indent=2))
        return 0
    print(f"exchangeability (ISO 9283 7.8) of {len(runs)} robots: E = {result.exchangeability_mm:.4f} mm "
          f"+/- {result.U_mm:.2g} mm (U, k = 2) at {result.pose}, in the frame of mounting {result.mounting}")
    for pose, p in result.per_pose.items():
        print(f"  {pose:<6} E = {p['exchangeability_mm']:.4f} mm  U = {p['U_mm']:.2g} mm  between "
              f"{' and '.join(p['between'])}")
    for serial, run_id in runs.items():
        print(f"  {serial}: run {run_id}")
    return 0
