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

PROCEDURES = ("iso9283", "trailer")


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
        raise ConfigError("name a procedure (iso9283, trailer) or --resume RUN_ID")
    cfg = load_config(args.config)
    procedure = args.procedure
    if args.resume and not procedure:
        procedure = _stored_procedure(cfg, args.resume, Path(args.config).resolve().parent)
    return execute(cfg, procedure=procedure, robot=args.robot, resume=args.resume,
                   run_id=args.run_id, arm=args.arm, yes=args.yes, time_scale=args.time_scale, seed=args.seed,
                   json_out=args.json, quiet=args.quiet, config_dir=Path(args.config).resolve().parent)


def _stored_procedure(cfg, run_id: str, base: Path) -> str:
    from station.store import RunStore

    with RunStore(cfg.station.store_file(base)) as store:
        return store.run(run_id).procedure


def execute(cfg, *, procedure: str = "iso9283", robot: str = "r1", resume: str | None = None,
            run_id: str | None = None, arm: bool = False, yes: bool = False, time_scale: float = 20.0,
            seed: int = 0, json_out: str | None = None, quiet: bool = False, config_dir: Path | None = None,
            plan_overrides: dict | None = None, stdout=sys.stdout) -> int:
    """Run or resume a procedure; prints the results table; returns the exit code."""
    if procedure == "trailer":
        return execute_trailer(cfg, resume=resume, run_id=run_id, arm=arm, yes=yes, time_scale=time_scale,
                               seed=seed, json_out=json_out, quiet=quiet, config_dir=config_dir, stdout=stdout)
    from procedures.iso9283 import build_procedure, close_devices, plan_from_config, IsoPlan
    from station.store import RunStore

    base = config_dir or Path.cwd()
    store = RunStore(cfg.station.store_file(base))
    rc = cfg.robots.get(robot)
    if rc is None:
        raise ConfigError(f"robots.{robot}: no such robot (have {', '.join(sorted(cfg.robots))})")

    if resume:
        rec = store.run(resume)
        plan = IsoPlan.from_params(rec.params)
        fake = rec.params.get("fake")
        run_id = resume
    else:
        overrides = {"report_dir": str(cfg.station.report_folder(base))}
        overrides.update(plan_overrides or {})
        plan = plan_from_config(cfg, robot, **overrides)
        fake = None if arm else {"seed": int(seed), "time_scale": float(time_scale)}
        run_id = run_id or f"{rc.serial}-{time.strftime('%Y%m%d-%H%M%S')}"

    operator = _operator(yes, quiet)
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

    session = {"devices": devices, "time_scale": scale}
    params = plan.params()
    if fake is not None:
        params["fake"] = fake
    start = dict(params=params, config=cfg.model_dump(mode="json"), model=rc.model, serial=rc.serial,
                 overhaul_state=rc.overhaul_state)
    try:
        outcome = _drive(store, build_procedure(plan), session, run_id, resume, start, operator, quiet)
    finally:
        close_devices(session)
        if station is not None:
            station.close()
    print_results(store, run_id, outcome, stdout)
    return _finish(store, run_id, outcome, json_out, "iso9283")


def _operator(yes: bool, quiet: bool):
    from station.runner import InteractiveOperator, ScriptedOperator

    return ScriptedOperator(True, stream=None if quiet else sys.stderr) if yes else InteractiveOperator()


def _drive(store, procedure, session, run_id, resume, start: dict, operator, quiet: bool):
    """Run or resume with Ctrl-C = abort (resumable) and SIGUSR1 = pause/continue."""
    from station.runner import ProgressLine, RunControl, Runner

    control = RunControl()
    old = {}
    for sig, handler in ((signal.SIGINT, lambda *_: control.abort()), (signal.SIGUSR1, lambda *_: control.toggle_pause())):
        try:
            old[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread
            pass
    runner = Runner(store, procedure, operator=operator, control=control, session=session,
                    progress=ProgressLine(None if quiet else sys.stderr))
    try:
        return runner.resume(run_id) if resume else runner.start(run_id, **start)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _finish(store, run_id, outcome, json_out, result_key: str) -> int:
    if json_out:
        payload = {"run_id": run_id, "status": outcome.status, "error": outcome.error,
                   "characteristics": store.characteristics(run_id)}
        try:
            payload["results"] = store.result(run_id, result_key)
        except Exception:
            payload["results"] = None
        Path(json_out).write_text(json.dumps(payload, indent=2, default=float))
    store.close()
    if outcome.status == "done":
        return 0
    return 3 if outcome.status == "aborted" else 1


def execute_trailer(cfg, *, resume=None, run_id=None, arm=False, yes=False, time_scale=20.0, seed=0,
                    json_out=None, quiet=False, config_dir=None, stdout=sys.stdout, true_lengths_m=None) -> int:
    """The trailer calibration (seed 003) through the odometry driver; fakes unless ``arm``."""
    from procedures import trailer as tp
    from procedures.trailer_run import build_procedure, close_devices, plan_from_params, plan_params
    from station.store import RunStore

    tc = cfg.trailer
    if tc is None:
        raise ConfigError("trailer: the config has no [trailer] section (odometry device, nominal lengths)")
    base = config_dir or Path.cwd()
    store = RunStore(cfg.station.store_file(base))
    if resume:
        rec = store.run(resume)
        params = rec.params
        fake = params.get("fake")
        run_id = resume
    else:
        plan = tp.TrailerCalibrationPlan(
            commands=tuple((k, float(m)) for k, m in tc.commands), duration_s=tc.duration_s, settle_s=tc.settle_s,
            v_m_s=tc.v_m_s, nominal_L1_m=tc.nominal_L1_m, nominal_L2_m=tc.nominal_L2_m, method=tc.method)
        params = {"plan": plan_params(plan), "report_dir": str(cfg.station.report_folder(base))}
        fake = None if arm else {"seed": int(seed), "time_scale": float(time_scale),
                                 "true_lengths_m": list(true_lengths_m) if true_lengths_m else None}
        if fake is not None:
            params["fake"] = fake
        run_id = run_id or f"{tc.serial}-{time.strftime('%Y%m%d-%H%M%S')}"
    plan = plan_from_params(params["plan"])
    operator = _operator(yes, quiet)
    world = handle = None
    if fake is None:
        if not yes and not operator.confirm(f"ARMED: the trailer (serial {tc.serial}) will drive. Continue?"):
            raise SafetyError("armed run not confirmed by the operator; nothing moved")
        devices = {"odometry": cfg.device(tc.odometry).url}
    else:
        from fakes.odometry import start_fake
        from fakes.sim.trailer import SimTrailer
        from fakes.sim.world import make_world

        world = make_world(seed=fake["seed"], time_scale=fake["time_scale"], effects=None)
        if fake.get("true_lengths_m"):
            L1, L2 = fake["true_lengths_m"]
            world.trailer = SimTrailer(world.clock, L1_m=L1, L2_m=L2, rng=world.rng)
        handle = start_fake(world)
        devices = {"odometry": handle.endpoint["device"]}
    session = {"devices": devices}
    start = dict(params=params, config=cfg.model_dump(mode="json"), model="trailer", serial=tc.serial,
                 overhaul_state=None)
    try:
        outcome = _drive(store, build_procedure(plan), session, run_id, resume, start, operator, quiet)
    finally:
        close_devices(session)
        if handle is not None:
            handle.close()
        if world is not None:
            world.close()
    print_trailer_results(store, run_id, outcome, stdout)
    return _finish(store, run_id, outcome, json_out, "trailer")


def print_trailer_results(store, run_id, outcome, out=sys.stdout) -> None:
    print(f"run {run_id}: {outcome.status}" + (f" ({outcome.error})" if outcome.error else ""), file=out)
    if outcome.status != "done":
        print(f"resume with: station run --resume {run_id} --config <config>", file=out)
        return
    res = store.result(run_id, "trailer")
    rows = [res["result"]] + list(res["comparisons"].values())
    print(f"{'method':<10}{'L1 m':>10}{'+-':>8}{'L2 m':>10}{'+-':>8}{'cond':>10}", file=out)
    for r in rows:
        f = lambda v, w, d: f"{v:>{w}.{d}f}" if v is not None else f"{'-':>{w}}"
        print(f"{r['method']:<10}{f(r['L1_m'], 10, 4)}{f(r['L1_sigma_m'], 8, 4)}{f(r['L2_m'], 10, 4)}"
              f"{f(r['L2_sigma_m'], 8, 4)}{f(r['condition_number'], 10, 1)}", file=out)
    print(f"report: {res['report']}", file=out)


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
