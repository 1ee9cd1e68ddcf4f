"""`station store ...`: the run store from the command line.

    station store runs --config C
    station store history --config C --serial SN --name RP_mm [--pose P1]
    station store exceeding --config C --name RP_mm [--all-runs]
    station store export RUN_ID --config C --out DIR [--format csv|parquet]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("store", help="query and export the run store")
    s = p.add_subparsers(dest="store_cmd", metavar="ACTION")
    a = s.add_parser("runs", help="list the runs")
    a.add_argument("--config", required=True)
    a.set_defaults(func=_runs)
    h = s.add_parser("history", help="one robot's values of a characteristic across its runs")
    h.add_argument("--config", required=True)
    h.add_argument("--serial", required=True)
    h.add_argument("--name", required=True, help="characteristic, e.g. RP_mm, AP_mm, MPT_s")
    h.add_argument("--pose", default=None)
    h.add_argument("--json", action="store_true")
    h.set_defaults(func=_history)
    e = s.add_parser("exceeding", help="robots with a characteristic over its limit")
    e.add_argument("--config", required=True)
    e.add_argument("--name", required=True)
    e.add_argument("--all-runs", action="store_true", help="every finished run, not only each robot's latest")
    e.add_argument("--json", action="store_true")
    e.set_defaults(func=_exceeding)
    x = s.add_parser("export", help="write a run's samples, journal and results as CSV or Parquet")
    x.add_argument("run_id")
    x.add_argument("--config", required=True)
    x.add_argument("--out", required=True)
    x.add_argument("--format", choices=("csv", "parquet"), default="csv")
    x.set_defaults(func=_export)


def _open(config: str):
    from station.config import load_config
    from station.store import RunStore

    cfg = load_config(config)
    from station.assemble import open_store

    return open_store(cfg.station.store_file(Path(config).resolve().parent))


def _ts(t: float | None) -> str:
    return "-" if t is None else time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _runs(args) -> int:
    with _open(args.config) as store:
        for r in store.runs():
            print(f"{r.run_id:<34} {r.procedure:<10} {r.serial or '-':<14} {r.overhaul_state or '-':<10} "
                  f"{r.status:<8} {_ts(r.created_at)}")
    return 0


def _history(args) -> int:
    with _open(args.config) as store:
        rows = store.history(args.serial, args.name, args.pose)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        verdict = "" if r["passed"] is None else ("pass" if r["passed"] else "FAIL")
        print(f"{_ts(r['created_at'])}  {r['run_id']:<34} {r['overhaul_state'] or '-':<10} {r['pose']:<8} "
              f"{args.name} = {r['value']:.4g}  {verdict}")
    return 0


def _exceeding(args) -> int:
    with _open(args.config) as store:
        rows = store.robots_exceeding(args.name, latest_only=not args.all_runs)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for r in rows:
        print(f"{r['model']:<18} {r['serial']:<14} {r['run_id']:<34} {r['pose']:<8} "
              f"{args.name} = {r['value']:.4g} > {r['limit']:g}")
    return 1 if rows else 0


def _export(args) -> int:
    with _open(args.config) as store:
        paths = store.export(args.run_id, args.out, args.format)
    for p in paths:
        print(p)
    return 0
