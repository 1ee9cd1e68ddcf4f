"""Where a run is assembled: which procedure, on which devices, with which operator.

Every front door (``station run``, ``station demo``, the acceptance API and its
pytest fixtures) comes through :func:`run_procedure` with one :class:`RunRequest`
(what to run, on what, answered by whom; contradictions refused there). It

* prepares the run through the application layer (:mod:`procedures.execute`):
  the plan from the config, or the stored plan of a run to resume;
* chooses its devices: those a caller passes (a test's injected drivers), the
  configured device URLs with ``arm`` (real hardware: a person confirms),
  or else the procedure's fake cell (named in its registry
  entry, started here, the same cell again on a resume);
* runs the preflight checks before anything moves, then the procedure with
  Ctrl-C = abort (resumable) and SIGUSR1 = pause/continue;
* decides the run's verdict (:func:`procedures.decision.decide`), stores it,
  writes ``--json`` and returns a :class:`ProcedureOutcome` that each front
  door presents (the command prints its lines, the page shows it).

This is a front door, not the core: it may import procedures and fakes.
"""

from __future__ import annotations

import importlib
import json
import math
import shlex
import signal
import sys
from contextlib import ExitStack
from dataclasses import KW_ONLY, dataclass, field
from pathlib import Path

from app.page_operator import WebOperator
from procedures.devices import DeviceSet, configured_devices
from procedures.execute import execute, prepare, preflight
from station.config import StationConfig
from station.errors import ConfigError, SafetyError
from app.terminal import InteractiveOperator, ProgressLine
from station.runner import FAKE_CARRY_KEY, RunControl, ScriptedOperator
from station.store import RunStore, StoreError
from station.verdict import Outcome


def operator_for(yes: bool, quiet: bool):
    """``--yes``: every prompt answered yes (logged; dry runs only); otherwise asked on the terminal."""
    return ScriptedOperator(True, stream=None if quiet else sys.stderr) if yes else InteractiveOperator()


def require_person(operator) -> None:
    """Refuse, before anything is recorded or moves, an operator that is not a person for a run on armed
    devices (real motion).

    A person is the terminal operator with both its streams on a terminal
    (``isatty``: ``yes | station run --arm`` is a pipe, not a person) or the
    operator's page, whose answers come only from its button behind the
    token and CSRF check. The class is checked exactly, never an attribute
    an object sets about itself: a subclass, a callable, an answer file or
    ``--yes`` is a script, and scripts drive the fakes only.
    """
    if type(operator) is WebOperator:
        return
    if type(operator) is InteractiveOperator:
        operator.require_terminal()
        return
    raise SafetyError("an armed run needs a person to answer its confirmations (the terminal or the "
                      "operator's page); scripted answers (--yes, a script, an answer file, an operator "
                      f"object of its own: {type(operator).__name__}) are for dry runs on the fakes only; "
                      "nothing moved")


def start_fake_cell(spec, params: dict, fake: dict):
    """Start the fake cell that the procedure's registry entry names."""
    module, _, func = spec.fake_cell.partition(":")
    return getattr(importlib.import_module(module), func)(params, fake)


@dataclass
class ProcedureOutcome:
    """What one run through :func:`run_procedure` came to; the command and the page each present it.

    ``verdict`` and ``reasons`` are :func:`procedures.decision.decide`'s (the
    same the report, ``--json`` and the page show); ``exit_code`` is
    :func:`station.verdict.exit_code`'s (0 PASS, 1 FAIL, 3 NOT DECIDED, 4 not
    conformant with conformance required, 5 ABORTED: resumable).
    """

    run_id: str
    procedure: str
    #: the runner's status: done, aborted or failed
    status: str
    verdict: Outcome
    reasons: list[str]
    exit_code: int
    #: the standard's conformance (ISO 9283), None where the procedure has none
    conformant: bool | None = None
    error: str | None = None
    #: the procedure's results as console lines (table, conformance, report)
    summary: list[str] = field(default_factory=list)
    #: the HTML report, when the run wrote one
    report: str | None = None
    #: the fake cell's seed and time scale; None on armed devices
    fake: dict | None = None
    #: what the central store holds of the run (one sentence), None without a central store
    forwarding: str | None = None
    #: the plant's measurements as judged (station.measurements.evaluate rows)
    measurements: list[dict] = field(default_factory=list)
    #: why the run is not conformant to its standard (empty where it is or has none)
    conformance_reasons: list[str] = field(default_factory=list)
    #: the passing characteristics within the plant's guard band of their limit, one sentence each
    marginal: list[str] = field(default_factory=list)

    def lines(self, config: str | Path | None = None) -> list[str]:
        """The console's presentation: the verdict first, then why, then the results; an unfinished run
        ends its reasons with the command that resumes it (``config``: the config file it was run with)."""
        head = f"{self.verdict}: run {self.run_id} ({self.procedure}) {self.status}"
        if self.conformant is False and self.verdict is Outcome.PASS:  # a short run's PASS says what it is not
            head += f"; not {_STANDARD.get(self.procedure, 'standard')} conformant: " + "; ".join(self.conformance_reasons)
        out = [head + (f" ({self.error})" if self.error and self.status != "done" else "")]
        out += [f"  {r}" for r in self.reasons]
        out += [f"  {m}" for m in self.marginal]
        if self.status != "done":
            out.append(f"resume with: station run --resume {self.run_id}"
                       + (f" --config {shlex.quote(str(config))}" if config else ""))
        out += self.summary
        for m in self.measurements:
            val = "not computed" if m["value"] is None else f"{m['value']:.4g} {m['unit']}"
            lim = ", ".join(f"{k} {m[k]:g} {m['unit']}" for k in ("low", "high") if m[k] is not None)
            out.append(f"measurement {m['pose']} {m['name']} = {val} ({lim}): {m['outcome']}"
                       + (" marginal" if m["marginal"] else ""))
        if self.forwarding:
            out.append(self.forwarding)
        return out

    def to_dict(self) -> dict:
        return {"run_id": self.run_id, "procedure": self.procedure, "status": self.status,
                "verdict": str(self.verdict), "reasons": list(self.reasons), "exit_code": self.exit_code,
                "conformant": self.conformant, "conformance_reasons": list(self.conformance_reasons),
                "error": self.error, "report": self.report, "fake": self.fake,
                "forwarding": self.forwarding, "measurements": list(self.measurements),
                "marginal": list(self.marginal)}


@dataclass(frozen=True)
class RunRequest:
    """What :func:`run_procedure` is asked to run: the config and the procedure, then keywords.

    ``config`` is the station config and ``procedure`` the registry name of a
    new run's procedure (None: the stored one of the run to ``resume``).
    ``robot`` is the robot key of the config; ``run_id`` names a new run.

    Devices: ``arm`` uses the configured device URLs (real hardware, the
    ``operator`` must be a person: :func:`require_person`); ``devices``
    injects drivers (a test); otherwise the procedure's fake cell is started
    with ``seed``, ``time_scale`` (simulated s per real s at most) and
    ``fake_options`` added to its stored parameters (e.g. a trailer's
    ``true_lengths_m``).

    Answers: ``yes`` answers every prompt yes (dry runs only), ``operator``
    is whoever answers otherwise (default: the terminal). ``control`` pauses
    and aborts, ``progress`` replaces the console's progress line (the
    operator's page shows the step's detail), ``quiet`` silences it.

    Output: ``json_out`` receives the verdict and the results, ``stdout``
    (when given) the outcome's console lines; ``config_dir`` is the folder
    the config's relative paths are taken from (default: the working one).

    A new run's plan: ``plan_overrides`` over the config's plan;
    ``acceptance`` is stored with it and read by its verdict:
    ``require_conformance`` (bool; ``--require-iso``), ``measurements`` (a
    plant's own, :mod:`station.measurements`) and ``record`` (who and what:
    operator, work order, overhaul ticket). A resumed run keeps all of these
    as it stored them.

    Options that contradict each other are refused here, on construction,
    with :class:`ConfigError` naming them: nothing is recorded and nothing
    moves.
    """

    config: StationConfig
    procedure: str | None = "iso9283"
    _: KW_ONLY
    robot: str = "r1"
    resume: str | None = None
    run_id: str | None = None
    arm: bool = False
    yes: bool = False
    time_scale: float = 20.0
    seed: int = 0
    json_out: str | None = None
    quiet: bool = False
    config_dir: Path | None = None
    plan_overrides: dict | None = None
    fake_options: dict | None = None
    devices: DeviceSet | None = None
    operator: object = None
    control: RunControl | None = None
    stdout: object = None
    progress: ProgressLine | None = None
    acceptance: dict | None = None

    def __post_init__(self) -> None:
        problems = list(self._contradictions())
        if problems:
            raise ConfigError("run request: " + "; ".join(problems))

    def _contradictions(self):
        from procedures.registry import procedure_names

        if not self.procedure and not self.resume:
            yield f"name a procedure ({', '.join(procedure_names())}) or a run to resume (--resume RUN_ID)"
        if self.resume:
            if self.run_id is not None and self.run_id != self.resume:
                yield (f"a resumed run keeps its id: run_id {self.run_id!r} (--run-id) with resume "
                       f"{self.resume!r}")
            kept = [name for name in ("plan_overrides", "acceptance", "fake_options") if getattr(self, name)]
            if kept:
                yield (f"a resumed run keeps the plan, acceptance and fake cell it stored; "
                       f"{', '.join(kept)} cannot be given with resume {self.resume!r}"
                       + (" (--require-iso)" if "acceptance" in kept else ""))
        if self.yes and self.operator is not None:
            yield "give yes (--yes) or an operator (--answers, a script, a person), not both"
        if self.arm and self.devices is not None:
            yield "give arm (the configured devices) or devices (injected), not both"
        if self.fake_options and (self.arm or self.devices is not None):
            yield (f"fake_options {sorted(self.fake_options)} are the fake cell's; with "
                   f"{'arm' if self.arm else 'devices'} no fake cell is started")
        if isinstance(self.time_scale, bool) or not isinstance(self.time_scale, (int, float)) \
                or not math.isfinite(self.time_scale) or self.time_scale <= 0:
            yield f"time_scale (--time-scale) must be a number > 0, got {self.time_scale!r}"
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            yield f"seed (--seed) must be a whole number, got {self.seed!r}"


def run_procedure(request: RunRequest) -> ProcedureOutcome:
    """Run or resume what ``request`` asks; returns its :class:`ProcedureOutcome` (verdict, reasons, exit code).

    Nothing is printed but the progress line (stderr, unless ``quiet``) and
    the prompts; ``request.stdout``, when given, receives the outcome's
    console lines (:meth:`ProcedureOutcome.lines`). The verdict is also
    stored with the run (result ``"verdict"``) and written at the top level
    of ``json_out``.

    With armed devices (``arm``: the configured URLs, real hardware) the
    operator must be a person (:func:`require_person`): ``yes`` or a
    scripted operator is refused with :class:`SafetyError` before anything
    moves, and the armed-run confirmation is always asked.
    """
    from procedures.decision import decide, record_measurements
    from station.measurements import parse as parse_measurements

    cfg, procedure = request.config, request.procedure
    base = request.config_dir or Path.cwd()
    acceptance = request.acceptance
    if procedure is not None and not request.resume:  # the plant's measurements of the config, then the script's
        declared = cfg.measurements_for(procedure, request.robot) + list((acceptance or {}).get("measurements") or [])
        acceptance = dict(acceptance or {})
        acceptance.pop("measurements", None)
        if declared:  # refused here, naming the entry, before anything is recorded
            acceptance["measurements"] = [m.to_dict() for m in parse_measurements(declared, "measurements")]
        # the plant's guard band, stored with the run so its verdict reads the same later
        acceptance.setdefault("marginal_fraction", cfg.station.marginal_fraction)
    operator = request.operator or operator_for(request.yes, request.quiet)
    if request.arm:  # refused before the run is even recorded
        require_person(operator)
    devices = request.devices
    with ExitStack() as stack:
        store = stack.enter_context(RunStore(cfg.station.store_file(base)))
        fake = None if (request.arm or devices is not None) else {
            "seed": int(request.seed), "time_scale": float(request.time_scale), **(request.fake_options or {})}
        prepared = prepare(cfg, store, procedure, robot=request.robot, resume=request.resume, run_id=request.run_id,
                           report_dir=cfg.station.report_folder(base), plan_overrides=request.plan_overrides, fake=fake,
                           acceptance=acceptance)
        spec = prepared.spec
        if devices is None and prepared.fake is None:
            devices = configured_devices(cfg, spec.device_roles(cfg, request.robot))
        cell = None
        if devices is None:
            cell = start_fake_cell(spec, prepared.params, prepared.fake)
            stack.callback(cell.close)
            devices = DeviceSet(urls=dict(cell.urls), time_scale=cell.time_scale)
            if getattr(cell, "hand", None) is not None:  # the simulated world acts on the answers (loads)
                operator = cell.hand(operator)
        # every reason the devices cannot run the plan, before anything moves
        preflight(prepared, cfg, devices)
        if devices.armed:
            require_person(operator)
            if not operator.confirm(f"ARMED: real devices will move ({prepared.subject.what}). Continue?"):
                raise SafetyError("armed run not confirmed by the operator; nothing moved")
        forwarder = _start_forwarding(cfg, base, stack)
        ran = _drive(store, prepared, cfg, devices, operator, request.control, request.quiet, request.progress)
        if getattr(cell, "carry", None) is not None:  # what a resumed cell carries on from this one's world
            store.put_result(prepared.run_id, FAKE_CARRY_KEY, cell.carry())
        measured = record_measurements(store, prepared.run_id) if ran.status == "done" else []
        decision = decide(spec, store, prepared.run_id)
        if ran.status == "done":
            store.put_result(prepared.run_id, VERDICT_KEY, decision.to_dict())
        lines = []
        try:
            lines = spec.summary(store, prepared.run_id)
        except Exception:  # a failed run may have no results to show
            if ran.status == "done":
                raise
        outcome = ProcedureOutcome(
            prepared.run_id, spec.name, ran.status, decision.outcome, list(decision.reasons), decision.exit_code,
            decision.conformant, ran.error, lines, _report_path(store, prepared.run_id), prepared.fake,
            conformance_reasons=list(decision.conformance_reasons),
            measurements=measured, marginal=[sentence for _, _, sentence in decision.marginal])
        if forwarder is not None:  # after the verdict is stored: the centre gets it too
            outcome.forwarding = _last_push(cfg, base, forwarder, prepared.run_id)
        if request.json_out:
            _write_json(store, outcome, request.json_out, spec.result_key)
    if request.stdout is not None:
        for line in outcome.lines():
            print(line, file=request.stdout)
    return outcome


#: the standard a procedure's conformance is to, as the verdict line names it
_STANDARD = {"iso9283": "ISO 9283"}

#: the result entry a finished run's verdict is stored under
VERDICT_KEY = "verdict"


def _report_path(store, run_id: str) -> str | None:
    rep = [s.output["report"] for s in store.steps(run_id)
           if s.name == "report" and s.status == "done" and s.output and s.output.get("report")]
    return rep[-1] if rep else None


def _start_forwarding(cfg, base: Path, stack: ExitStack):
    """With a central store configured, forward in the background while the run records (local first)."""
    if not cfg.station.store_url:
        return None
    from station.store.forward import Forwarder

    fwd = Forwarder(cfg.station.store_file(base), cfg.station.store_url, station=cfg.station.name,
                    interval_s=FORWARD_INTERVAL_S).start()
    stack.callback(fwd.stop)
    return fwd


#: how often a run's new batches are forwarded to the central store
FORWARD_INTERVAL_S = 5.0


def _last_push(cfg, base: Path, forwarder, run_id: str) -> str:
    """After the run: stop the background pass and push what is left once; says what the centre holds
    of the run (an absent centre is only said)."""
    from station.store.forward import forward_status, push

    forwarder.stop()
    try:
        with RunStore(cfg.station.store_file(base), station=cfg.station.name) as local, \
                RunStore(cfg.station.store_url, station=cfg.station.name) as central:
            push(local, central, station=cfg.station.name)
            # once more by name: its verdict, stored after the background pass may have sent it as done
            push(local, central, station=cfg.station.name, run_ids=[run_id])
            st = forward_status(local).get(run_id, {})
    except StoreError as exc:
        return (f"central store not reached ({exc}); everything is kept here: `station store push` sends it "
                "later")
    n_local, n_fwd = st.get("batches_local", 0), st.get("batches_forwarded", 0)
    if st.get("in_centre") == "complete":
        return f"central store: holds run {run_id} complete ({n_fwd} of {n_local} batch(es), status {st['status']})"
    return (f"central store: holds {n_fwd} of {n_local} batch(es) of run {run_id} (status there "
            f"{st.get('status_forwarded') or 'none'}); `station store push` sends the rest")


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


def _write_json(store, outcome: ProcedureOutcome, json_out, result_key: str) -> None:
    """The verdict at the top level, then the characteristics and the procedure's results."""
    payload = {**outcome.to_dict(), "characteristics": store.characteristics(outcome.run_id)}
    try:
        payload["results"] = store.result(outcome.run_id, result_key)
    except Exception:
        payload["results"] = None
    from station.readers.out_files import write_output

    write_output(json_out, json.dumps(payload, indent=2, default=float), "--json")


def stored_procedure(cfg, run_id: str, base: Path) -> str:
    with RunStore(cfg.station.store_file(base)) as store:
        return store.run(run_id).procedure


__all__ = ["run_procedure", "RunRequest", "ProcedureOutcome", "VERDICT_KEY", "operator_for", "require_person", "start_fake_cell", "stored_procedure", "ConfigError"]
