"""`station store fleet ...`: fleet questions; across stations with ``--central`` (the central store).

    station store fleet history --config C --serial SN --name RP_mm [--pose P1] [--central]
    station store fleet since-overhaul --config C --name RP_mm [--model M] [--central]
    station store fleet over-limits --config C [--name RP_mm] [--central]
    station store fleet drifting --config C --name RP_mm [--model M] [--q 0.05] [--min-runs 5] [--central]
    station store fleet page --config C --name RP_mm --out fleet.html [--central]

The same rule as every store command: the station's own store unless
``--central``. An empty answer says so.
"""

from __future__ import annotations

import argparse
import json
import time

from app.commands.store_open import CENTRAL_HELP, CONFIG_HELP, JSON_HELP
from station.verdict import Outcome


def register(s) -> None:
    f = s.add_parser("fleet", help="fleet questions (across stations with --central)")
    fs = f.add_subparsers(dest="fleet_cmd", metavar="QUESTION")
    h = fs.add_parser("history", help="one robot's values across stations and overhauls")
    _common(h)
    h.add_argument("--serial", required=True, help="the robot's serial")
    h.add_argument("--model", default=None, help="the robot's model (needed when two models share the serial)")
    h.add_argument("--name", required=True, help="characteristic, e.g. RP_mm")
    h.add_argument("--pose", default=None, help="one pose (default: every pose)")
    h.set_defaults(func=_history)
    o = fs.add_parser("since-overhaul", help="per robot: change and trend since its last overhaul")
    _common(o)
    o.add_argument("--name", required=True, help="characteristic, e.g. RP_mm")
    o.add_argument("--model", default=None, help="one robot model (default: every model)")
    o.set_defaults(func=_since)
    x = fs.add_parser("over-limits", help="robots whose latest run is over a limit (proven), then those not decided "
                                          "under the guarded rule (in the guard band)")
    _common(x)
    x.add_argument("--name", default=None, help="one characteristic (default: any)")
    x.set_defaults(func=_over)
    d = fs.add_parser("drifting", help="robots whose characteristic grows since their last overhaul (trend test)")
    _common(d)
    d.add_argument("--name", required=True, help="characteristic, e.g. RP_mm")
    d.add_argument("--model", default=None, help="one robot model (default: every model)")
    d.add_argument("--q", type=float, default=0.05, help="false-discovery rate across a model's robots")
    d.add_argument("--min-runs", type=int, default=5, help="runs since the overhaul a trend needs (default 5)")
    d.set_defaults(func=_drifting)
    p = fs.add_parser("page", help="write the static HTML fleet page")
    _common(p)
    p.add_argument("--name", default="RP_mm", help="characteristic (default RP_mm)")
    p.add_argument("--out", required=True, metavar="FILE.html", help="the page to write")
    p.add_argument("--q", type=float, default=0.05, help="false-discovery rate of the drifting list")
    p.set_defaults(func=_page)


def _common(p) -> None:
    p.add_argument("--config", required=True, help=CONFIG_HELP)
    p.add_argument("--central", action="store_true", help=CENTRAL_HELP)
    p.add_argument("--local", action="store_true", help=argparse.SUPPRESS)  # the default; kept for old scripts
    p.add_argument("--json", action="store_true", help=JSON_HELP)


def _open(args):
    from app.commands.store_open import open_store

    return open_store(args.config, central=args.central)


def _ts(t) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _where(args) -> str:
    return "the central store" if args.central else "this station's store (--central asks across stations)"


def _emit(args, rows, line, empty: str) -> None:
    if args.json:
        print(json.dumps(rows, indent=2))
    elif not rows:
        print(f"{empty} in {_where(args)}")
    else:
        for r in rows:
            print(line(r))


def _history(args) -> int:
    from station.fleet.questions import robot_history

    with _open(args) as store:
        rows = robot_history(store, args.serial, args.name, args.pose, model=args.model)
    _emit(args, rows, lambda r: f"{_ts(r['created_at'])}  {r['station'] or '-':<10} {r['run_id']:<34} "
                                f"{r['overhaul_state'] or '-':<10} {r['pose']:<6} {r['value']:.4g}",
          f"no values of {args.name} for serial {args.serial}")
    return 0


def _since(args) -> int:
    from station.fleet.questions import since_overhaul

    with _open(args) as store:
        rows = since_overhaul(store, args.name, model=args.model)
    _emit(args, rows, lambda r: (
        f"{r['serial']:<14} {r['model']:<18} "
        + (f"since overhaul of {_ts(r['overhaul_at'])}: " if r["overhaul_at"] is not None else "no overhaul recorded: ")
        + f"{r['baseline_value']:.4g} -> {r['latest_value']:.4g} (change {r['change']:+.3g}, {r['runs_since']} runs, "
        + ("slope -" if r["slope_per_year"] is None else f"{r['slope_per_year']:+.3g}/year") + ")"),
          f"no robot with {args.name} since an overhaul")
    return 0


def _over(args) -> int:
    from station.fleet.questions import decisions_as_json, limit_decisions_now

    with _open(args) as store:
        d = limit_decisions_now(store, args.name)
    # non-conformance proven first (the line of old), then the figures left in their guard band
    rows = d["proven"] + d["not_decided"]
    if args.json:
        rows = decisions_as_json(rows)

    def line(r):
        head = f"{r['model']:<18} {r['serial']:<14} {r['station'] or '-':<10} {r['run_id']:<34} {r['pose']:<6} "
        if r["decision"] is Outcome.NOT_DECIDED:
            u = "" if r["U"] is None else f" +/- {r['U']:.2g}"
            return head + f"{r['name']} = {r['value']:.4g}{u} against {r['limit']:g}: {Outcome.NOT_DECIDED} (guard band)"
        return head + f"{r['name']} = {r['value']:.4g} > {r['limit']:g}" + (
            f" (proven: - U {r['U']:.2g}, {r['rule']} rule)" if r["rule"] == "guarded" and r["U"] is not None else "")

    _emit(args, rows, line, "no robot whose latest run is over " + (f"its {args.name} limit" if args.name else "a limit")
          + " or not decided against it")
    return 1 if rows else 0


def _drifting(args) -> int:
    from station.fleet.questions import drifting

    with _open(args) as store:
        rows = drifting(store, args.name, model=args.model, q_max=args.q, min_runs=args.min_runs)
    _emit(args, rows, lambda r: f"{r['serial']:<14} {r['model']:<18} {r['slope_per_year']:+.3g}/year over "
                                f"{r['runs_since']} runs since {r['baseline_run']} (q = {r['q']:.2g})",
          f"no robot whose {args.name} drifts (q <= {args.q:g}, at least {args.min_runs} runs since its overhaul)")
    return 1 if rows else 0


def _page(args) -> int:
    from station.fleet.page import write_fleet_page

    from station.readers.out_files import check_outputs

    check_outputs(args, out="--out")
    with _open(args) as store:
        path = write_fleet_page(store, args.out, args.name, q_max=args.q)
    print(path)
    return 0
