"""Runs this server drives: one thread each, an operator that waits for the page.

A run started (or resumed) from the page goes through the same front door as
``station run`` (:func:`app.assemble.run_procedure`) in a thread of the
server. Its prompts wait in a :class:`WebOperator` until a page answers them;
pause and abort go to the run's :class:`~station.runner.RunControl`. Everything
else a page shows is read from the store, so a run started from the CLI is
seen the same way, and one started here can be resumed from the CLI.

One run at a time: a station has one cell.
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from app.page_operator import WebOperator
from station.errors import ConfigError, RunStateError, StationError
from app.terminal import ProgressLine
from station.runner import RunControl


class _PageProgress(ProgressLine):
    """The runner's progress, kept for the page instead of printed."""

    def __init__(self, live: "LiveRun") -> None:
        super().__init__(None)
        self._live = live

    def update(self, idx: int, step, detail: str = "") -> None:
        super().update(idx, step, detail)
        self._live.detail = detail


@dataclass
class LiveRun:
    """A run driven by this server's thread."""

    run_id: str
    control: RunControl
    operator: WebOperator
    started_at: float = field(default_factory=time.time)
    thread: threading.Thread | None = None
    #: exit code of the front door (station.assemble.ProcedureOutcome.exit_code; 2 when it could not
    #: start); None while running
    exit_code: int | None = None
    #: what the run came to (verdict, reasons, summary), once the front door returned
    outcome: object | None = None
    #: why the run could not start or stopped, when the store cannot say (preflight, config)
    error: str | None = None
    #: the outcome's console lines (verdict, reasons, results)
    output: str = ""
    #: what the current step is doing now (e.g. "-> P3", "pose C12"), from the runner's progress
    detail: str = ""

    @property
    def finished(self) -> bool:
        return self.thread is not None and not self.thread.is_alive()


class RunHub:
    """Starts, resumes, steers and tracks the runs of one station server.

    ``arm``: the configured devices (real hardware; the page confirms first);
    otherwise the procedure's fake cell at ``time_scale``. ``plan_overrides``
    and ``fake_options`` are handed to the front door unchanged.
    """

    def __init__(self, cfg, config_dir: Path, *, arm: bool = False, time_scale: float = 20.0,
                 plan_overrides: dict | None = None) -> None:
        if not time_scale > 0:
            raise ConfigError(f"time_scale must be > 0, got {time_scale}")
        self.cfg = cfg
        self.config_dir = Path(config_dir)
        self.arm = bool(arm)
        self.time_scale = float(time_scale)
        self.plan_overrides = dict(plan_overrides or {})
        self._lock = threading.Lock()
        self._runs: dict[str, LiveRun] = {}

    # -- queries ------------------------------------------------------------
    def live(self, run_id: str) -> LiveRun | None:
        with self._lock:
            return self._runs.get(run_id)

    def active(self) -> LiveRun | None:
        """The run this server is driving now, if any."""
        with self._lock:
            for live in self._runs.values():
                if not live.finished:
                    return live
        return None

    # -- actions ------------------------------------------------------------
    def start(self, procedure: str, robot: str = "r1", seed: int = 0, existing: set[str] | None = None) -> str:
        """Start a new run in a thread; returns its id. ``existing``: ids already in the store."""
        from procedures.registry import get_procedure, runnable_procedures

        spec = get_procedure(procedure)
        offered = runnable_procedures(self.cfg)
        if procedure not in offered:
            raise ConfigError(f"procedure {procedure!r} cannot run with this config (it can run: "
                              f"{', '.join(offered) or 'none'})")
        serial = spec.subject(self.cfg, robot).serial  # an unknown robot of a cell procedure is refused here
        base = f"{serial}-{time.strftime('%Y%m%d-%H%M%S')}"
        taken = set(existing or ()) | set(self._runs)
        run_id, k = base, 1
        while run_id in taken:
            k += 1
            run_id = f"{base}-{k}"
        kwargs = dict(robot=robot, run_id=run_id, seed=int(seed), plan_overrides=self.plan_overrides or None)
        self._launch(run_id, procedure, kwargs)
        return run_id

    def resume(self, run_id: str) -> str:
        """Resume a stored failed or aborted run in a thread (same fake cell: its stored seed)."""
        self._launch(run_id, None, dict(resume=run_id))
        return run_id

    def pause(self, run_id: str) -> None:
        self._require(run_id).control.pause()

    def proceed(self, run_id: str) -> None:
        self._require(run_id).control.resume()

    def abort(self, run_id: str) -> None:
        self._require(run_id).control.abort()

    def answer(self, run_id: str, prompt_id: int, yes: bool) -> None:
        self._require(run_id).operator.answer(prompt_id, yes)

    def close(self, timeout_s: float = 30.0) -> None:
        """Abort every run still going (resumable) and wait for its thread."""
        with self._lock:
            runs = list(self._runs.values())
        for live in runs:
            live.control.abort()
        for live in runs:
            if live.thread is not None:
                live.thread.join(timeout_s)

    # -- inside -------------------------------------------------------------
    def _require(self, run_id: str) -> LiveRun:
        live = self.live(run_id)
        if live is None or live.finished:
            raise RunStateError(f"run {run_id} is not being driven by this server")
        return live

    def _launch(self, run_id: str, procedure: str | None, kwargs: dict) -> None:
        with self._lock:
            for other in self._runs.values():
                if not other.finished:
                    raise RunStateError(f"run {other.run_id} is still going on this station; "
                                        "one run at a time (abort it or wait)")
            control = RunControl()
            live = LiveRun(run_id, control, WebOperator(control))
            live.thread = threading.Thread(target=self._drive, args=(live, procedure, kwargs),
                                           name=f"run {run_id}")
            self._runs[run_id] = live
            live.thread.start()

    def _drive(self, live: LiveRun, procedure: str | None, kwargs: dict) -> None:
        from app.assemble import RunRequest, run_procedure

        if self.arm and procedure is not None:
            # a new run on real hardware from the page is an acceptance: its standard's conformance is required
            # (a resumed run keeps what it stored)
            kwargs = {"acceptance": {"require_conformance": True}, **kwargs}
        try:
            outcome = run_procedure(RunRequest(
                self.cfg, procedure, arm=self.arm, yes=False, time_scale=self.time_scale, quiet=True,
                config_dir=self.config_dir, operator=live.operator, control=live.control,
                progress=_PageProgress(live), **kwargs))
            live.outcome, live.exit_code = outcome, outcome.exit_code
            live.output = "\n".join(outcome.lines())
        except StationError as exc:
            live.error = f"{type(exc).__name__}: {exc}"
            live.exit_code = 2
        except Exception as exc:  # a bug: keep the server up, show it on the page
            live.error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
            live.exit_code = 1
