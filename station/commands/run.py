"""`station run PROCEDURE --config C` and `station run --resume RUN_ID --config C`.

Without ``--arm`` nothing real moves: the station starts its own fake cell
(simulated arm, emScon tracker fake, controller fake) on loopback and points
the procedure's devices at it. With ``--arm`` the configured device URLs are
used as they are (real hardware, or fakes started with ``station fakes serve
station``); the operator confirms that the cell is clear unless ``--yes``.

The config is validated before anything starts. A run killed at any moment
(Ctrl-C, ``kill -9``, a fault) is resumed with ``--resume RUN_ID``: the robot
is brought back to a known pose, then the run goes on from its last finished
step; with fakes, the same simulated cell (same seed) is started again.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path

from station.errors import ConfigError, SafetyError

PROCEDURES = ("iso9283",)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a procedure (fakes by default; --arm for real hardware)")
    p.add_argument("procedure", nargs="?", choices=PROCEDURES)
    p.add_argument("--config", required=True, help="station config (TOML or JSON)")
    p.add_argument("--robot", default="r1", help="robot key in the config (default r1)")
    p.add_argument("--resume", metavar="RUN_ID", help="resume this run from its last finished step")
    p.add_argument("--run-id", help="id of a new run (default SERIAL-YYYYmmdd-HHMMSS)")
    p.add_argument("--arm", action="store_true", help="use the configured devices: real hardware moves")
    p.add_argument("--yes", action="store_true", help="answer every operator prompt with yes (scripted run)")
    p.add_argument("--time-scale", type=float, default=20.0, help="fake cell: simulated s per real s (default 20)")
    p.add_argument("--seed", type=int, default=0, help="fake cell: seed of the simulated world")
    p.add_argument("--json", metavar="OUT", help="write the results as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(func=_cmd_run)


def _cmd_run(args: argparse.Namespace) -> int:
    from station.config import load_config

    if not args.resume and not args.procedure:
        raise ConfigError("name a procedure (iso9283) or --resume RUN_ID")
    cfg = load_config(args.config)
    return execute(cfg, procedure=args.procedure or "iso9283", robot=args.robot, resume=args.resume,
                   run_id=args.run_id, arm=args.arm, yes=args.yes, time_scale=args.time_scale, seed=args.seed,
                   json_out=args.json, quiet=args.quiet, config_dir=Path(args.config).resolve().parent)


def execute(cfg, *, procedure: str = "iso9283", robot: str = "r1", resume: str | None = None,
            run_id: str | None = None, arm: bool = False, yes: bool = False, time_scale: float = 20.0,
            seed: int = 0, json_out: str | None = None, quiet: bool = False, config_dir: Path | None = None,
            plan_overrides: dict | None = None, stdout=sys.stdout) -> int:
    """Run or resume a procedure; prints the results table; returns the exit code."""
    from procedures.iso9283 import build_procedure, close_devices, plan_from_config, IsoPlan
    from station.runner import InteractiveOperator, ProgressLine, RunControl, Runner, ScriptedOperator
    from station.store import RunStore

    base = config_dir or Path.cwd()
    store_path = Path(cfg.station.store_path)
    store_path = store_path if store_path.is_absolute() else base / store_path
    store = RunStore(store_path)
    rc = cfg.robots.get(robot)
    if rc is None:
        raise ConfigError(f"robots.{robot}: no such robot (have {', '.join(sorted(cfg.robots))})")

    if resume:
        rec = store.run(resume)
        plan = IsoPlan.from_params(rec.params)
        fake = rec.params.get("fake")
        run_id = resume
    else:
        report_dir = Path(cfg.station.report_dir)
        overrides = {"report_dir": str(report_dir if report_dir.is_absolute() else base / report_dir)}
        overrides.update(plan_overrides or {})
        plan = plan_from_config(cfg, robot, **overrides)
        fake = None if arm else {"seed": int(seed), "time_scale": float(time_scale)}
        run_id = run_id or f"{rc.serial}-{time.strftime('%Y%m%d-%H%M%S')}"

    operator = ScriptedOperator(True, stream=None if quiet else sys.stderr) if yes else InteractiveOperator()
    if fake is None:
        if not yes and not operator.confirm(
            f"ARMED: real devices will move ({cfg.robots[robot].model} serial {rc.serial}). Continue?"
        ):
            raise SafetyError("armed run not confirmed by the operator; nothing moved")
        ctrl = cfg.device(rc.controller)
        devices = {"tracker": cfg.device("tracker").url, "controller": ctrl.url, "register_map": ctrl.register_map}
        station = None
        scale = 1.0
    else:
        from fakes.station import FakeStation

        station = FakeStation.start(seed=fake["seed"], time_scale=fake["time_scale"], robot=plan.robot.name,
                                    payload_kg=plan.payload_kg)
        devices = {"tracker": station.tracker_url, "controller": station.controller_url}
        scale = fake["time_scale"]

    control = RunControl()
    old = {}
    for sig, handler in ((signal.SIGINT, lambda *_: control.abort()), (signal.SIGUSR1, lambda *_: control.toggle_pause())):
        try:
            old[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread
            pass
    session = {"devices": devices, "time_scale": scale}
    runner = Runner(store, build_procedure(plan), operator=operator, control=control, session=session,
                    progress=ProgressLine(None if quiet else sys.stderr))
    try:
        if resume:
            outcome = runner.resume(run_id)
        else:
            params = plan.params()
            if fake is not None:
                params["fake"] = fake
            outcome = runner.start(run_id, params=params, config=cfg.model_dump(mode="json"), model=rc.model,
                                   serial=rc.serial, overhaul_state=rc.overhaul_state)
    finally:
        close_devices(session)
        if station is not None:
            station.close()
        for sig, h in old.items():
            signal.signal(sig, h)

    print_results(store, run_id, outcome, stdout)
    if json_out:
        payload = {"run_id": run_id, "status": outcome.status, "error": outcome.error,
                   "characteristics": store.characteristics(run_id)}
        try:
            payload["results"] = store.result(run_id, "iso9283")
        except Exception:
            payload["results"] = None
        Path(json_out).write_text(json.dumps(payload, indent=2, default=float))
    store.close()
    if outcome.status == "done":
        return 0
    return 3 if outcome.status == "aborted" else 1


def print_results(store, run_id: str, outcome, out=sys.stdout) -> None:
    rows = store.characteristics(run_id)
    print(f"run {run_id}: {outcome.status}" + (f" ({outcome.error})" if outcome.error else ""), file=out)
    if outcome.status != "done":
        print(f"resume with: station run --resume {run_id} --config <config>", file=out)
    if not rows:
        return
    by_pose: dict[str, dict] = {}
    for r in rows:
        by_pose.setdefault(r["pose"], {})[r["name"]] = r
    cols = [("AP_mm", "AP mm"), ("RP_mm", "RP mm"), ("POS_mm", "POS mm"), ("PST_s", "PST s"), ("vAP_mm", "vAP mm"),
            ("n_cycles", "n")]
    print(f"{'pose':<8}" + "".join(f"{h:>10}" for _, h in cols), file=out)
    for pose in sorted(p for p in by_pose if p.startswith("P") and "-" not in p):
        line = f"{pose:<8}"
        for key, _ in cols:
            r = by_pose[pose].get(key)
            line += f"{_fmt(r):>10}"
        print(line, file=out)
    for pose, d in sorted(by_pose.items()):
        for key in ("AD_mm", "RD_mm", "MPT_s"):
            if key in d:
                print(f"{key:<7} {pose:<8} {_fmt(d[key]):>10}", file=out)
    judged = [r["passed"] for r in rows if r["passed"] is not None]
    verdict = "no limits configured" if not judged else ("PASS" if all(judged) else "FAIL")
    failed = [f"{r['pose']} {r['name']} {r['value']:.4g} > {r['limit']:g}" for r in rows if r["passed"] is False]
    print(f"verdict: {verdict}" + (f" ({'; '.join(failed)})" if failed else ""), file=out)
    try:
        rep = next(s.output["report"] for s in store.steps(run_id) if s.name == "report" and s.status == "done")
        print(f"report: {rep}", file=out)
    except StopIteration:
        pass


def _fmt(r) -> str:
    if r is None or r["value"] is None:
        return "-"
    v = r["value"]
    mark = "" if r["passed"] is None else ("" if r["passed"] else "!")
    return f"{v:.0f}" if r["name"] == "n_cycles" else f"{v:.3f}{mark}"
