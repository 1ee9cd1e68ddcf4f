"""`station store ...`: the run store from the command line.

    station store runs --config C [--central]
    station store history --config C --serial SN [--model M] --name RP_mm [--pose P1] [--central]
    station store overhaul --config C --serial SN [--model M] --date 2026-11-02 --what "J2 gearbox replaced" [--ticket T]
    station store overhauls --config C [--serial SN] [--central]
    station store exceeding --config C --name RP_mm [--all-runs] [--central]
    station store export RUN_ID --config C --out DIR [--format csv|parquet] [--central]
    station store push --config C [--run RUN_ID ...] [--watch S]     forward local runs to the central store
    station store status --config C                                  what of each run has reached the centre
    station store reanalyze --config C [--central] [--run ID ...] [--jobs N] [--force]
    station store exchangeability --config C (--model M | --serials A,B,...) [--central] [--json]
    station store fleet history|since-overhaul|over-limits|drifting|page --config C [--central] ...

One rule for which store a command asks: the station's own file, unless
``--central`` asks the store named by ``[station] store_url`` (``store fleet``
too). A question without an answer says so. Exit codes: 0 fine, 1 a finding (values over limits,
drifting robots) or the central store unreachable (the runs stay local, push
again later), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from app.commands.store_open import CENTRAL_HELP, CONFIG_HELP, JSON_HELP, open_store
from station.shown import shown
from station.verdict import Outcome, outcome_of


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("store", help="query, export and forward the run store")
    s = p.add_subparsers(dest="store_cmd", metavar="ACTION")
    a = s.add_parser("runs", help="list the runs (with what reached the central store)")
    _common(a)
    a.set_defaults(func=_runs)
    h = s.add_parser("history", help="one robot's values of a characteristic across its runs")
    _common(h)
    h.add_argument("--serial", required=True, help="the robot's serial")
    h.add_argument("--model", default=None, help="the robot's model (needed when robots of two models share the serial)")
    h.add_argument("--name", required=True, help="characteristic, e.g. RP_mm, AP_mm, MPT_s")
    h.add_argument("--pose", default=None, help="one pose (default: every pose)")
    h.add_argument("--json", action="store_true", help=JSON_HELP)
    h.set_defaults(func=_history)
    e = s.add_parser("exceeding", help="robots with a characteristic over its limit (and, in their latest run, "
                                       "those not decided under the guarded rule, listed apart)")
    _common(e)
    e.add_argument("--name", required=True, help="characteristic, e.g. RP_mm")
    e.add_argument("--all-runs", action="store_true", help="every finished run, not only each robot's latest")
    e.add_argument("--json", action="store_true", help=JSON_HELP)
    e.set_defaults(func=_exceeding)
    o = s.add_parser("overhaul", help="record an overhaul of a robot (since-overhaul figures and drift count from it)")
    _common(o)
    o.add_argument("--serial", required=True, help="the robot's serial")
    o.add_argument("--model", default=None,
                   help="the robot's model (default: the one model the store knows this serial of)")
    o.add_argument("--date", required=True, metavar="WHEN",
                   help="when the overhaul was finished: YYYY-MM-DD or YYYY-MM-DDTHH:MM (local time)")
    o.add_argument("--what", required=True, help="what was done, e.g. 'J2 gearbox and J3 motor replaced'")
    o.add_argument("--ticket", default=None, help="the work order or overhaul ticket")
    o.set_defaults(func=_overhaul)
    ol = s.add_parser("overhauls", help="list the recorded overhauls")
    _common(ol)
    ol.add_argument("--serial", default=None, help="one robot's (default: every robot's)")
    ol.add_argument("--json", action="store_true", help=JSON_HELP)
    ol.set_defaults(func=_overhauls)
    x = s.add_parser("export", help="write a run's samples, journal and results as CSV or Parquet")
    x.add_argument("run_id", help="the run to export (station store runs lists them)")
    _common(x)
    x.add_argument("--out", required=True, metavar="DIR", help="directory the files are written to")
    x.add_argument("--format", choices=("csv", "parquet"), default="csv", help="file format (default csv)")
    x.set_defaults(func=_export)
    u = s.add_parser("push", help="forward the local runs to the central store (store_url)")
    u.add_argument("--config", required=True, help=CONFIG_HELP)
    u.add_argument("--run", action="append", dest="runs", metavar="RUN_ID", help="only these runs (repeatable)")
    u.add_argument("--watch", type=float, default=None, metavar="S",
                   help="keep forwarding every S seconds until interrupted (retries when the centre is away)")
    u.add_argument("--chunk-batches", type=int, default=200, help="sample batches per central transaction")
    u.set_defaults(func=_push)
    t = s.add_parser("status", help="what of each local run has reached the central store")
    t.add_argument("--config", required=True, help=CONFIG_HELP)
    t.add_argument("--json", action="store_true", help=JSON_HELP)
    t.set_defaults(func=_status)
    r = s.add_parser("reanalyze", help="re-run the analysis of archived runs from their raw samples (results kept beside)")
    _common(r)
    r.add_argument("--run", action="append", dest="runs", metavar="RUN_ID", help="only these runs (repeatable)")
    r.add_argument("--procedure", default=None, help="only runs of this procedure")
    r.add_argument("--jobs", type=int, default=1, help="parallel processes")
    r.add_argument("--force", action="store_true", help="again even when this analysis version has a result")
    r.add_argument("--json", action="store_true", help=JSON_HELP)
    r.set_defaults(func=_reanalyze)
    from app.commands import store_exchangeability, store_fleet

    store_fleet.register(s)
    store_exchangeability.register(s)


def _common(p) -> None:
    p.add_argument("--config", required=True, help=CONFIG_HELP)
    p.add_argument("--central", action="store_true", help=CENTRAL_HELP)


def _ts(t: float | None) -> str:
    return "-" if t is None else time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _runs(args) -> int:
    from station.config import load_config
    from station.store.forward import forward_status

    forwarding = not args.central and bool(load_config(args.config).station.store_url)
    with open_store(args.config, args.central) as store:
        fwd = forward_status(store) if forwarding else {}
        runs = store.runs()
        if not runs:
            print(f"no runs in {'the central store' if args.central else 'the store'}")
            return 0
        rows = [(r.run_id, r.procedure, r.serial or "-", r.overhaul_state or "-", r.status,
                 _run_verdict(store, r), _ts(r.created_at), r.station or "-") for r in runs]
        head = ("run", "procedure", "serial", "overhaul", "status", "verdict", "created", "station")
        widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
        for r, row in zip([None] + runs, [head] + rows):
            line = "  ".join(f"{str(v):<{w}}" for v, w in zip(row, widths))
            f = fwd.get(r.run_id) if r is not None else None
            if forwarding:  # only with a central store configured: what of the run reached it
                line += "  " + ("centre" if r is None else "-" if f is None else
                                f"{f['in_centre']} ({f['batches_forwarded']}/{f['batches_local']} batches)")
            print(line.rstrip())
    return 0


def _run_verdict(store, run) -> str:
    """A run's stored verdict (its words as ``station run`` prints them); ``-`` before the run decided one."""
    from station.verdict import Outcome

    try:
        stored = store.result(run.run_id, "verdict")
    except Exception:  # noqa: BLE001 - no verdict stored (not finished, or an old run)
        return "-"
    try:
        return str(Outcome.parse(stored.get("verdict") if isinstance(stored, dict) else stored))
    except Exception:  # noqa: BLE001 - an unreadable stored verdict is shown as unknown, not guessed
        return "?"


def _history(args) -> int:
    with open_store(args.config, args.central) as store:
        rows = store.history(args.serial, args.name, args.pose, model=args.model)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print(f"no values of {args.name} for serial {args.serial}" + (f" at {args.pose}" if args.pose else "")
              + " (is the serial right? station store runs lists the runs)")
    for r in rows:
        verdict = "" if r["passed"] is None else outcome_of(r["passed"]).cell
        print(f"{_ts(r['created_at'])}  {r['run_id']:<34} {r['overhaul_state'] or '-':<10} {r['pose']:<8} "
              f"{args.name} = {r['value']:.4g}  {verdict}")
    return 0


def _exceeding(args) -> int:
    undecided = []
    with open_store(args.config, args.central) as store:
        rows = store.robots_exceeding(args.name, latest_only=not args.all_runs)
        if not args.all_runs:
            # the runs' decision rule (ISO 14253-1): over the limit but within U of it is not proven
            from station.fleet.questions import limit_decisions_now

            d = limit_decisions_now(store, args.name)
            proven = {(r["run_id"], r["pose"]) for r in d["proven"]}
            rows = [r for r in rows if (r["run_id"], r["pose"]) in proven]
            undecided = [{k: r[k] for k in ("model", "serial", "run_id", "created_at", "pose", "value", "limit", "U",
                                            "rule", "decision")} for r in d["not_decided"]]
    if args.json:
        from station.fleet.questions import decisions_as_json

        print(json.dumps(rows + decisions_as_json(undecided), indent=2))
        return 0
    if not rows and not undecided:
        print(f"no robot over its {args.name} limit ("
              + ("any finished run" if args.all_runs else "each robot's latest run") + ")")
    for r in rows:
        print(f"{r['model']:<18} {r['serial']:<14} {r['run_id']:<34} {r['pose']:<8} "
              f"{args.name} = {r['value']:.4g} > {r['limit']:g}")
    for r in undecided:
        u = "" if r["U"] is None else f" +/- {r['U']:.2g}"
        print(f"{r['model']:<18} {r['serial']:<14} {r['run_id']:<34} {r['pose']:<8} "
              f"{args.name} = {r['value']:.4g}{u} against {r['limit']:g}: {Outcome.NOT_DECIDED} (guard band)")
    return 1 if rows or undecided else 0


def _overhaul(args) -> int:
    from station.config import load_config

    from station.fleet.questions import parse_when

    at = parse_when(args.date, "--date")
    station = load_config(args.config).station.name
    with open_store(args.config, args.central) as store:
        if args.model is None:
            model, serial = store.resolve_robot(args.serial)
        else:
            model, serial = args.model, args.serial
        new = store.record_overhaul(model, serial, at, args.what, ticket=args.ticket, station=station)
    print(f"{shown(model)} serial {shown(serial)}: overhaul of {_ts(at)} "
          + ("recorded" if new else "was already recorded")
          + f" ({shown(args.what.strip(), 200)}" + (f", ticket {shown(args.ticket)}" if args.ticket else "") + ")")
    return 0


def _overhauls(args) -> int:
    with open_store(args.config, args.central) as store:
        rows = store.overhauls(serial=args.serial)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print("no overhaul recorded" + (f" for serial {args.serial}" if args.serial else ""))
    for r in rows:
        print(f"{_ts(r['at'])}  {shown(r['model']):<18} {shown(r['serial']):<14} {shown(r['what'])}"
              + (f"  (ticket {shown(r['ticket'])})" if r["ticket"] else "") + f"  [{shown(r['station'] or '-')}]")
    return 0


def _export(args) -> int:
    from station.readers.out_files import output_dir

    output_dir(args.out, "--out")
    with open_store(args.config, args.central) as store:
        paths = store.export(args.run_id, args.out, args.format)
    for p in paths:
        print(p)
    return 0


def _push(args) -> int:
    from station.config import load_config
    from station.errors import ConfigError
    from station.store import RunStore, StoreUnavailable, redacted
    from station.store.forward import Forwarder, push

    cfg = load_config(args.config)
    if not cfg.station.store_url:
        raise ConfigError(f"{args.config}: [station] store_url is not set: nowhere to push to")
    if args.chunk_batches < 1:
        raise ConfigError(f"--chunk-batches must be at least 1, got {args.chunk_batches}")
    local_path = cfg.station.store_file(Path(args.config).resolve().parent)
    if args.watch is not None:
        if args.watch <= 0:
            raise ConfigError(f"--watch must be a positive number of seconds, got {args.watch}")

        def said(report, error):
            if error is not None:
                print(f"station: {error}; retrying", file=sys.stderr, flush=True)
            elif report.batches_sent or report.errors:
                _print_report(report)

        fwd = Forwarder(local_path, cfg.station.store_url, station=cfg.station.name, interval_s=args.watch,
                        chunk_batches=args.chunk_batches, on_pass=said).start()
        try:
            while fwd.is_alive():
                time.sleep(0.5)
        finally:
            fwd.stop()
        return 0
    with RunStore(local_path, station=cfg.station.name) as local:
        try:
            central = RunStore(cfg.station.store_url, station=cfg.station.name)
        except StoreUnavailable as exc:
            print(f"station: {exc}. Nothing was lost: the runs stay in {local_path}; push again later.",
                  file=sys.stderr)
            return 1
        with central:
            try:
                report = push(local, central, station=cfg.station.name, run_ids=args.runs,
                              chunk_batches=args.chunk_batches)
            except StoreUnavailable as exc:
                print(f"station: {exc}. What reached {redacted(cfg.station.store_url)} is recorded; "
                      "push again to send the rest.", file=sys.stderr)
                return 1
    _print_report(report)
    return 1 if report.errors else 0


def _print_report(report) -> None:
    if not report.runs:
        print("nothing to send: no local run has anything the central store lacks", flush=True)
    for r in report.runs:
        extra = f"  ERROR: {r.error}" if r.error else ""
        print(f"{r.run_id:<34} {r.status:<8} sent {r.batches_sent} batches ({r.samples_sent} samples), "
              f"{r.batches_already_there} already there{extra}", flush=True)
    if report.overhauls_sent or report.reanalyses_sent:
        print(f"sent {report.overhauls_sent} recorded overhaul(s) and {report.reanalyses_sent} re-analysis "
              "result(s)", flush=True)


def _status(args) -> int:
    from station.store.forward import forward_status

    with open_store(args.config) as store:
        rows = forward_status(store)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print("no runs in the store")
    for run_id, f in rows.items():
        print(f"{run_id:<34} {f['status']:<8} centre: {f['in_centre']:<8} {f['batches_forwarded']}/{f['batches_local']}"
              f" batches, status there: {f['status_forwarded'] or '-'}" + (f"  ({f['last_error']})" if f['last_error'] else ""))
    return 0


def _reanalyze(args) -> int:
    from dataclasses import asdict

    from app.reanalysis import reanalyze, runs_to_reanalyze

    with open_store(args.config, args.central) as store:
        target = store.name if not args.central else None
        ids = runs_to_reanalyze(store, args.runs, args.procedure)
    if args.central:
        from station.config import load_config

        target = load_config(args.config).station.store_url
    t0 = time.perf_counter()
    done = reanalyze(target, ids, jobs=args.jobs, force=args.force)
    wall = time.perf_counter() - t0
    if args.json:
        print(json.dumps([asdict(d) for d in done], indent=2))
    else:
        for d in done:
            what = ("already done at this version" if d.skipped else f"ERROR {d.error}" if d.error else
                    f"{d.n_values} values, largest change {d.max_change:.3g}, "
                    f"{len(d.verdict_changes)} verdict changes" + "".join(f"\n    {v}" for v in d.verdict_changes))
            print(f"{d.run_id:<34} {d.version}  {what}")
        n = sum(1 for d in done if not d.skipped and not d.error)
        if n:
            print(f"{n} runs in {wall:.1f} s with {args.jobs} processes: {60 * n / wall / args.jobs:.1f} runs/min/process")
    return 1 if any(d.error or d.verdict_changes for d in done) else 0
