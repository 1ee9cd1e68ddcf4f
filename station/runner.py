"""Executes a procedure step by step and journals every step.

A :class:`Procedure` is a readable list of named :class:`Step` objects. The
:class:`Runner` runs them in order, and for each attempt journals start, end,
outcome and output in the run store; samples a step takes go to the store in
committed batches through :meth:`StepContext.record` before the step is
marked done. A run stopped at any moment (abort, fault, ``kill -9``) resumes
with :meth:`Runner.resume`: steps marked ``every_session`` (connect devices,
bring the robot back to a known pose) run again first, then the run goes on
from the first step that is not done. Nothing acknowledged is lost: samples of
an interrupted attempt stay in the store, marked by their attempt number.

Run states (data, not code: :data:`station.store.RUN_TRANSITIONS`, enforced
by the store)::

    running --(all steps done)--> done
    running --(step raised)-----> failed   (resumable)
    running --(abort request)---> aborted  (resumable)
    failed/aborted --(resume)---> running
    running --(resume after kill -9)--> running

The runner does not know what a session holds: each procedure keeps its live
objects (devices, plan, intermediate results) in a typed session object of its
own, which the runner hands to every step as ``ctx.session`` and to the
procedure's ``safe_state`` after a failure or abort.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TextIO

import numpy as np

from station.errors import RunStateError, StationError
from station.store import RunStore, StoreError
from station.numeric import json_default



class RunAborted(StationError):
    """The operator (or a signal) asked the run to stop; it can be resumed."""


class Operator(Protocol):
    """Who answers a run's prompts. A run on armed devices takes only a person
    (:func:`app.assemble.require_person`): the terminal operator on a real
    terminal, or the operator's page. No attribute an object sets makes it one."""

    def confirm(self, message: str) -> bool: ...


class ScriptedOperator:
    """Answers every prompt with ``answer`` (``--yes``) and logs it: dry runs on the fakes only."""

    def __init__(self, answer: bool = True, stream: TextIO | None = None) -> None:
        self.answer = answer
        self.stream = stream
        self.asked: list[str] = []

    def confirm(self, message: str) -> bool:
        self.asked.append(message)
        if self.stream is not None:
            print(f"? {message} -> {'yes' if self.answer else 'no'} (scripted)", file=self.stream)
        return self.answer


class CallableOperator:
    """A script's own answers: ``answer(message) -> bool`` for each prompt, logged in ``asked``. Dry runs on
    the fakes only."""

    def __init__(self, answer: Callable[[str], bool]) -> None:
        self._answer = answer
        self.asked: list[tuple[str, bool]] = []

    def confirm(self, message: str) -> bool:
        answer = bool(self._answer(message))
        self.asked.append((message, answer))
        return answer


class AnswerFileOperator:
    """Scripted answers from a file, for dry runs only: one answer per prompt in order,
    each line ``yes`` or ``no``, optionally ``TEXT = yes|no`` where ``TEXT`` must occur in the prompt;
    blank lines and ``#`` comments are skipped. A prompt with no answer left, or not matching its line,
    is refused (:class:`~station.errors.ConfigError`) rather than guessed."""

    def __init__(self, path: str | Path) -> None:
        from station.errors import ConfigError

        from station.errors import DataError
        from station.readers.once import read_bytes

        self.path = Path(path)
        try:  # one bounded read (a pipe or /dev/zero is not read for ever)
            text = read_bytes(path, 1 << 20, "an answer file holds a line per prompt").decode("utf-8")
        except (DataError, UnicodeDecodeError) as exc:
            raise ConfigError(f"answer file {self.path}: cannot read it ({exc})") from None
        self._answers: list[tuple[int, str, bool]] = []
        for lineno, raw in enumerate(text.splitlines(), 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            expect, _, word = line.rpartition("=")
            word = word.strip().lower()
            if word not in ("yes", "no", "y", "n"):
                raise ConfigError(f"answer file {self.path} line {lineno}: {raw.strip()!r} is not 'yes', 'no' "
                                  "or 'TEXT = yes|no'")
            self._answers.append((lineno, expect.strip(), word.startswith("y")))
        self.asked: list[tuple[str, bool]] = []

    def confirm(self, message: str) -> bool:
        from station.errors import ConfigError

        if len(self.asked) >= len(self._answers):
            raise ConfigError(f"answer file {self.path}: no answer left for prompt {len(self.asked) + 1} "
                              f"({message!r})")
        lineno, expect, answer = self._answers[len(self.asked)]
        if expect and expect.lower() not in message.lower():
            raise ConfigError(f"answer file {self.path} line {lineno}: expected a prompt with {expect!r}, "
                              f"the run asks {message!r}")
        self.asked.append((message, answer))
        return answer


class RunControl:
    """Pause and abort requests, safe to call from signal handlers and threads."""

    def __init__(self) -> None:
        self._abort = threading.Event()
        self._running = threading.Event()
        self._running.set()
        self._held = threading.Event()

    def abort(self) -> None:
        self._abort.set()
        self._running.set()

    def pause(self) -> None:
        self._running.clear()

    def resume(self) -> None:
        self._running.set()

    def toggle_pause(self) -> None:
        if self._running.is_set():
            self.pause()
        else:
            self.resume()

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    @property
    def held(self) -> bool:
        """True while the procedure waits at a checkpoint because of a pause: the station sends nothing new.

        Between :meth:`pause` and the procedure's next checkpoint it goes on:
        ``paused`` and not yet ``held``. A checkpoint may sit in the wait for a
        program's end, so a program already started on the controller still
        runs to its end while the station holds.
        """
        return self._held.is_set()

    @property
    def abort_requested(self) -> bool:
        return self._abort.is_set()

    def checkpoint(self) -> None:
        """Block while paused (:attr:`held` meanwhile); raise RunAborted if an abort was requested."""
        if not self._running.is_set():
            self._held.set()
            try:
                while not self._running.wait(0.1):
                    pass
            finally:
                self._held.clear()
        if self._abort.is_set():
            raise RunAborted("run aborted on request (resumable)")


@dataclass(frozen=True)
class Step:
    """One named step.

    ``run(ctx)`` does the work and returns a JSON-able dict (its output, kept
    in the journal) or None. ``every_session`` steps (connect, home) run at
    the start of every session, fresh or resumed, unless every step left is
    ``offline`` (works on the store alone: analysis, report): a resume then
    opens no device and asks nothing again. ``label`` is what the progress
    line shows (e.g. ``"cycle 3/30"``).
    """

    name: str
    run: Callable[["StepContext"], Mapping | None]
    label: str = ""
    every_session: bool = False
    offline: bool = False


@dataclass
class Procedure:
    name: str
    steps: list[Step]
    #: called with the session after a failure or abort, to leave devices safe
    safe_state: Callable[[Any], None] | None = None

    def __post_init__(self) -> None:
        names = [s.name for s in self.steps]
        dupes = {n for n in names if names.count(n) > 1}
        if dupes:
            raise StationError(f"procedure {self.name!r}: step names must be unique, repeated: {sorted(dupes)}")


@dataclass
class StepContext:
    """What a step sees: the store, the live session, earlier outputs, the operator."""

    runner: "Runner"
    run_id: str
    idx: int
    attempt: int
    step: Step
    session: Any
    params: dict
    outputs: dict[str, Any]
    n_recorded: int = 0

    @property
    def store(self) -> RunStore:
        return self.runner.store

    def record(self, stream: str, columns: Mapping[str, np.ndarray]) -> int:
        """Commit a batch of samples to the store (acknowledged on return)."""
        n = self.store.append_samples(self.run_id, stream, self.idx, self.attempt, columns)
        self.n_recorded += n
        return n

    def samples(self, stream: str, steps: list[str] | None = None) -> dict[str, np.ndarray]:
        """Samples of finished steps (optionally only the named ones)."""
        idx = None
        if steps is not None:
            by_name = {s.name: i for i, s in enumerate(self.runner.procedure.steps)}
            idx = [by_name[n] for n in steps]
        return self.store.samples(self.run_id, stream, steps=idx)

    def confirm(self, message: str) -> bool:
        return self.runner.operator.confirm(message)

    def checkpoint(self) -> None:
        self.runner.control.checkpoint()

    def progress(self, detail: str) -> None:
        self.runner.progress.update(self.idx, self.step, detail)

    def log(self, message: str) -> None:
        self.runner.progress.log(message)


class Progress(Protocol):
    """Where the runner shows a run's progress: the terminal's bar (:class:`app.terminal.ProgressLine`),
    the operator's page, or nothing (:class:`SilentProgress`)."""

    total: int
    done: int

    def update(self, idx: int, step: "Step", detail: str = "") -> None: ...

    def log(self, message: str) -> None: ...

    def finish(self) -> None: ...


class SilentProgress:
    """Shows nothing (a run driven from code with no display)."""

    def __init__(self) -> None:
        self.total = 0
        self.done = 0

    def update(self, idx: int, step: "Step", detail: str = "") -> None:
        pass

    def log(self, message: str) -> None:
        pass

    def finish(self) -> None:
        pass


@dataclass
class RunOutcome:
    run_id: str
    status: str
    outputs: dict[str, Any] = field(default_factory=dict)
    error: str | None = None


class Runner:
    """Runs a :class:`Procedure` against a :class:`RunStore`."""

    def __init__(
        self,
        store: RunStore,
        procedure: Procedure,
        *,
        operator: Operator | None = None,
        control: RunControl | None = None,
        progress: Progress | None = None,
        session: Any = None,
    ) -> None:
        self.store = store
        self.procedure = procedure
        self.operator = operator or ScriptedOperator(True)
        self.control = control or RunControl()
        self.progress = progress or SilentProgress()
        self.progress.total = len(procedure.steps)
        self.session: Any = session if session is not None else {}

    def start(
        self,
        run_id: str,
        *,
        params: Mapping,
        config: Mapping | None = None,
        model: str | None = None,
        serial: str | None = None,
        overhaul_state: str | None = None,
    ) -> RunOutcome:
        self.store.create_run(
            run_id, self.procedure.name, model=model, serial=serial, overhaul_state=overhaul_state,
            config=config or {}, params=params,
        )
        return self._execute(run_id, first_session=True)

    def resume(self, run_id: str) -> RunOutcome:
        rec = self.store.run(run_id)
        if rec.procedure != self.procedure.name:
            raise RunStateError(f"run {run_id} is a {rec.procedure!r} run, not {self.procedure.name!r}")
        if rec.status == "done":
            raise RunStateError(f"run {run_id} is already done; nothing to resume")
        # a "running" run is one whose process died without journaling its end: resume is for that too
        self.store.set_run_status(run_id, "running")
        return self._execute(run_id, first_session=False)

    def _execute(self, run_id: str, *, first_session: bool) -> RunOutcome:
        rec = self.store.run(run_id)
        params = rec.params
        done = self.store.done_steps(run_id)
        outputs = {self.procedure.steps[i].name: s.output for i, s in done.items() if i < len(self.procedure.steps)}
        self.progress.done = len(done)
        pending = [i for i in range(len(self.procedure.steps)) if i not in done]
        if not first_session and pending:
            self.progress.log(f"resuming run {run_id} at step {pending[0] + 1}: {self.procedure.steps[pending[0]].name}")
        try:
            # every-session steps before the resume point run again first (reconnect, home)
            first_pending = pending[0] if pending else len(self.procedure.steps)
            needs_session = any(not self.procedure.steps[i].offline for i in pending)
            replay = [i for i in range(first_pending)
                      if self.procedure.steps[i].every_session and i in done and needs_session]
            for i in replay:
                self._run_step(run_id, i, params, outputs, replay=True)
            for i in pending:
                self._run_step(run_id, i, params, outputs, replay=False)
        except RunAborted as exc:
            self._safe_state()
            self.store.set_run_status(run_id, "aborted")
            self.progress.finish()
            return RunOutcome(run_id, "aborted", outputs, str(exc))
        except Exception as exc:
            self._safe_state()
            self.store.set_run_status(run_id, "failed")
            self.progress.finish()
            if isinstance(exc, StationError):
                return RunOutcome(run_id, "failed", outputs, f"{type(exc).__name__}: {exc}")
            raise
        self.store.set_run_status(run_id, "done")
        self.progress.finish()
        return RunOutcome(run_id, "done", outputs)

    def _run_step(self, run_id: str, idx: int, params: dict, outputs: dict, *, replay: bool) -> None:
        step = self.procedure.steps[idx]
        self.control.checkpoint()
        self.progress.update(idx, step, "(again: new session)" if replay else "")
        attempt = self.store.step_started(run_id, idx, step.name)
        ctx = StepContext(self, run_id, idx, attempt, step, self.session, params, outputs)
        try:
            out = step.run(ctx)
            out = dict(out) if out is not None else {}
            json.dumps(out, default=json_default)  # refuse non-JSON output before marking done
        except RunAborted as exc:
            self.store.step_ended(run_id, idx, attempt, "aborted", message=str(exc))
            raise
        except Exception as exc:
            self.store.step_ended(run_id, idx, attempt, "failed", output={"error": error_origin(exc)},
                                  message=f"{type(exc).__name__}: {exc}")
            self.progress.log(f"step {idx + 1} {step.name} failed: {exc}")
            raise
        out.setdefault("n_samples", ctx.n_recorded)
        self.store.step_ended(run_id, idx, attempt, "done", output=out)
        outputs[step.name] = out
        if not replay:
            self.progress.done += 1

    def _safe_state(self) -> None:
        if self.procedure.safe_state is None:
            return
        try:
            self.procedure.safe_state(self.session)
        except Exception as exc:  # the original error matters more; say what else went wrong
            self.progress.log(f"warning: bringing devices to a safe state failed: {exc}")


def error_origin(exc: BaseException) -> dict:
    """What failed a step: the exception's type and the device driver modules its traceback passed through
    (``drivers``, outermost first: a driver and the transport under it), for the page's device states. The
    core names the modules only; it imports no driver."""
    drivers: list[str] = []
    tb = exc.__traceback__
    while tb is not None:
        module = tb.tb_frame.f_globals.get("__name__", "")
        if (module == "drivers" or module.startswith("drivers.")) and module not in drivers:
            drivers.append(module)
        tb = tb.tb_next
    return {"type": type(exc).__name__, "drivers": drivers}


#: a resumed fake cell starts its clock this long after the last stored sample, s (a gap, never a repeat)
RESUME_GAP_S = 1.0


#: the result under which a run keeps what its fake cell's world carries on to a resumed cell (fake options)
FAKE_CARRY_KEY = "fake cell carries"


def resume_fake(store: RunStore, run_id: str, fake: dict) -> dict:
    """The fake cell's parameters of a resumed run: the stored ones, its clock going on after everything the
    run stored (:func:`resume_start_s`), and what the last cell's world left (:data:`FAKE_CARRY_KEY`: the
    arm's warmth), when it stored it."""
    try:
        carried = store.result(run_id, FAKE_CARRY_KEY)
    except StoreError:
        carried = {}
    return {**fake, **(carried if isinstance(carried, dict) else {}), "start_s": resume_start_s(store, run_id)}


def resume_start_s(store: RunStore, run_id: str) -> float:
    """Simulated time at which a fake cell that resumes ``run_id`` starts its clock, s.

    After the last time stamp (``t``) of every sample the run stored, in any
    attempt, plus :data:`RESUME_GAP_S`: the cell goes on from where the one
    that was interrupted left off, as a real instrument's clock does, so a
    resumed stream's time base never repeats or goes back. 0 for a run with
    no samples.
    """
    last = 0.0
    for stream in store.streams(run_id):
        t = store.samples(run_id, stream, finished_only=False).get("t")
        if t is not None and t.size:
            t = t[np.isfinite(t)]
            if t.size:
                last = max(last, float(t.max()) + RESUME_GAP_S)
    return float(np.ceil(last))
