"""Where a run is assembled: which procedure, on which devices, with which operator.

Every front door (``station run``, ``station demo``, the acceptance API and its
pytest fixtures) comes through :func:`run_procedure`. It

* prepares the run through the application layer (:mod:`procedures.execute`):
  the plan from the config, or the stored plan of a run to resume;
* chooses its devices: those a caller passes (a test's injected drivers), the
  configured device URLs with ``arm`` (real hardware: the operator confirms
  unless ``yes``), or else the procedure's fake cell (named in its registry
  entry, started here, the same cell again on a resume);
* runs the preflight checks before anything moves, then the procedure with
  Ctrl-C = abort (resumable) and SIGUSR1 = pause/continue;
* prints the results and writes ``--json``.

This is a front door, not the core: it may import procedures and fakes.
"""

from __future__ import annotations

import importlib
import json
import signal
import sys
from contextlib import ExitStack
from pathlib import Path

from procedures.devices import DeviceSet, configured_devices
from procedures.execute import execute, prepare, preflight
from station.errors import ConfigError, SafetyError
from station.runner import InteractiveOperator, ProgressLine, RunControl, ScriptedOperator
from station.store import RunStore, StoreError


def operator_for(yes: bool, quiet: bool):
    """``--yes``: every prompt answered yes (logged; dry runs only); otherwise asked on the terminal."""
    return ScriptedOperator(True, stream=None if quiet else sys.stderr) if yes else InteractiveOperator()


def require_human(operator) -> None:
    """Refuse an operator that is not a person for a run on armed devices (real motion): scripted answers
    (``--yes``, a script's callable, a file of answers) may only drive the fakes."""
    if not getattr(operator, "human", False):
        raise SafetyError("an armed run needs a person to answer its confirmations (the terminal or the "
                          "operator's page); scripted answers (--yes, a script, an answer file) are for dry "
                          "runs on the fakes only; nothing moved")


def start_fake_cell(spec, params: dict, fake: dict):
    """Start the fake cell that the procedure's registry entry names."""
    module, _, func = spec.fake_cell.partition(":")
    return getattr(importlib.import_module(module), func)(params, fake)


def run_procedure(cfg, procedure: str | None = "iso9283", *, robot: str = "r1", resume: str | None = None,
                  run_id: str | None = None, arm: bool = False, yes: bool = False, time_scale: float = 20.0,
                  seed: int = 0, json_out: str | None = None, quiet: bool = False,
                  config_dir: Path | None = None, plan_overrides: dict | None = None,
                  fake_options: dict | None = None, devices: DeviceSet | None = None, operator=None,
                  control: RunControl | None = None, stdout=None, progress: ProgressLine | None = None) -> int:
    """Run or resume a procedure; prints the results; returns the exit code (0 done, 1 failed, 3 aborted, or
    done with a figure not decided under the guarded decision rule).

    With armed devices (``arm``: the configured URLs, real hardware) the
    ``operator`` must be a person (:func:`require_human`): ``yes`` or a
    scripted operator is refused with :class:`SafetyError` before anything
    moves, and the armed-run confirmation is always asked.

    ``devices`` overrides the choice of devices (a test injecting drivers);
    ``fake_options`` adds to the fake cell's stored parameters (e.g. a
    trailer's ``true_lengths_m``). ``progress`` replaces the console's
    progress line (the operator's page shows the step's detail, e.g. the
    target pose).
    """
    base = config_dir or Path.cwd()
    stdout = stdout or sys.stdout
    operator = operator or operator_for(yes, quiet)
    if arm:  # refused before the run is even recorded
        require_human(operator)
    with ExitStack() as stack:
        store = stack.enter_context(RunStore(cfg.station.store_file(base)))
        fake = None if (arm or devices is not None) else {"seed": int(seed), "time_scale": float(time_scale),
                                                          **(fake_options or {})}
        prepared = prepare(cfg, store, procedure, robot=robot, resume=resume, run_id=run_id,
                           report_dir=cfg.station.report_folder(base), plan_overrides=plan_overrides, fake=fake)
        spec = prepared.spec
        if devices is None and prepared.fake is None:
            devices = configured_devices(cfg, spec.device_roles(cfg, robot))
        if devices is None:
            cell = start_fake_cell(spec, prepared.params, prepared.fake)
            stack.callback(cell.close)
            devices = DeviceSet(urls=dict(cell.urls), time_scale=cell.time_scale)
        # every reason the devices cannot run the plan, before anything moves
        preflight(prepared, cfg, devices)
        if devices.armed:
            require_human(operator)
            if not operator.confirm(f"ARMED: real devices will move ({prepared.subject.what}). Continue?"):
                raise SafetyError("armed run not confirmed by the operator; nothing moved")
        forwarder = _start_forwarding(cfg, base, stack)
        outcome = _drive(store, prepared, cfg, devices, operator, control, quiet, progress)
        if forwarder is not None:
            _last_push(cfg, base, forwarder, stdout)
        print(f"run {prepared.run_id}: {outcome.status}" + (f" ({outcome.error})" if outcome.error else ""),
              file=stdout)
        if outcome.status != "done":
            print(f"resume with: station run --resume {prepared.run_id} --config <config>", file=stdout)
        lines = []
        try:
            lines = spec.summary(store, prepared.run_id)
        except Exception:  # a failed run may have no results to show
            if outcome.status == "done":
                raise
        for line in lines:
            print(line, file=stdout)
        if json_out:
            _write_json(store, prepared.run_id, outcome, json_out, spec.result_key)
        undecided = outcome.status == "done" and _not_decided(store, prepared.run_id)
    if outcome.status == "done":
        return 3 if undecided else 0
    return 3 if outcome.status == "aborted" else 1


def _not_decided(store, run_id: str) -> bool:
    """A finished run whose analysis left a figure in its guard band under the guarded rule (exit 3)."""
    return any(s.status == "done" and isinstance(s.output, dict) and s.output.get("decision_rule") == "guarded"
               and s.output.get("decision") == "not decided" for s in store.steps(run_id))


def _start_forwarding(cfg, base: Path, stack: ExitStack):
    """With a central store configured, forward in the background while the run records (local first)."""
    if not cfg.station.store_url:
        return None
    from station.store_forward import Forwarder

    fwd = Forwarder(cfg.station.store_file(base), cfg.station.store_url, station=cfg.station.name,
                    interval_s=FORWARD_INTERVAL_S).start()
    stack.callback(fwd.stop)
    return fwd


#: how often a run's new batches are forwarded to the central store
FORWARD_INTERVAL_S = 5.0


def _last_push(cfg, base: Path, forwarder, stdout) -> None:
    """After the run: stop the background pass and push what is left once; an absent centre is only said."""
    from station.store_forward import push

    forwarder.stop()
    try:
        with RunStore(cfg.station.store_file(base), station=cfg.station.name) as local, \
                RunStore(cfg.station.store_url, station=cfg.station.name) as central:
            report = push(local, central, station=cfg.station.name)
        print(f"central store: {report.batches_sent} batch(es) forwarded", file=stdout)
    except StoreError as exc:
        print(f"central store not reached ({exc}); everything is kept here: `station store push` sends it later",
              file=stdout)


def _drive(store, prepared, cfg, devices, operator, control, quiet: bool, progress=None):
    control = control or RunControl()
    old = {}
    for sig, handler in ((signal.SIGINT, lambda *_: control.abort()), (signal.SIGUSR1, lambda *_: control.toggle_pause())):
        try:
            old[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread
            pass
    try:
        return execute(store, prepared, cfg, devices, operator=operator, control=control,
                       progress=progress or ProgressLine(None if quiet else sys.stderr))
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _write_json(store, run_id, outcome, json_out, result_key: str) -> None:
    payload = {"run_id": run_id, "status": outcome.status, "error": outcome.error,
               "characteristics": store.characteristics(run_id)}
    try:
        payload["results"] = store.result(run_id, result_key)
    except Exception:
        payload["results"] = None
    Path(json_out).write_text(json.dumps(payload, indent=2, default=float))


def stored_procedure(cfg, run_id: str, base: Path) -> str:
    with RunStore(cfg.station.store_file(base)) as store:
        return store.run(run_id).procedure


__all__ = ["run_procedure", "operator_for", "require_human", "start_fake_cell", "stored_procedure", "ConfigError"]
