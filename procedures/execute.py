"""The application layer: one way to plan, check and run any procedure.

A front door (the CLI, the acceptance API, the pytest plugin, the operator's
page, a test) calls, in order:

1. :func:`prepare`: the procedure's spec from the registry, the plan of a
   new run from the config (or the stored plan of a run to resume), its id
   and what it is made on;
2. :func:`preflight`: every reason the plan cannot run on its devices, all
   at once, before anything moves (:class:`~station.errors.PreflightError`);
3. :func:`execute`: the runner drives the procedure's steps with a typed
   session around the :class:`~procedures.devices.DeviceSet` the front door
   assembled (configured devices with ``--arm``, the fake cell otherwise, or
   drivers a test injects), journals every step in the store, and closes what
   the session opened.

The choice of devices, prompts and printing stay with the front door.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from procedures.devices import DeviceSet
from procedures.registry import ProcedureSpec, Subject, get_procedure
from station.errors import ConfigError, PreflightError
from station.runner import Operator, Progress, RunControl, RunOutcome, Runner, resume_fake
from station.store import RunStore


@dataclass(frozen=True)
class PreparedRun:
    """A run ready to be assembled: what to run, its stored plan, its id."""

    spec: ProcedureSpec
    run_id: str
    params: dict
    resume: bool
    robot: str
    subject: Subject
    #: the fake cell's parameters (seed, time scale, ...) stored with the run; None for real devices
    fake: dict | None

    def start_kwargs(self, cfg) -> dict:
        return dict(params=self.params, config=cfg.model_dump(mode="json"), model=self.subject.model,
                    serial=self.subject.serial, overhaul_state=self.subject.overhaul_state)


def prepare(cfg, store: RunStore, procedure: str | None = None, *, robot: str = "r1", resume: str | None = None,
            run_id: str | None = None, report_dir: str | Path = "reports", plan_overrides: Mapping | None = None,
            fake: Mapping | None = None, acceptance: Mapping | None = None) -> PreparedRun:
    """Plan a new run, or load the stored plan of run ``resume``.

    ``fake`` (the fake cell's seed and time scale) is stored with a new run so a
    resume starts the same simulated cell; a resumed run keeps what it stored.
    ``acceptance`` (required conformance, a plant's measurements, the test
    record's who and what) is stored with a new run's plan the same way.
    """
    if resume:
        rec = store.run(resume)
        if procedure is not None and procedure != rec.procedure:
            raise ConfigError(f"run {resume} is a {rec.procedure!r} run, not {procedure!r}")
        spec = get_procedure(rec.procedure)
        params = dict(rec.params)
        subject = Subject(rec.model, rec.serial, rec.overhaul_state, f"{rec.model} serial {rec.serial}")
        fake_again = params.get("fake")
        if fake_again is not None:
            # the same cell, its clock going on after everything the run stored (time never repeats), its world
            # as the last cell left it (the arm's warmth)
            fake_again = resume_fake(store, resume, fake_again)
        return PreparedRun(spec, resume, params, True, robot, subject, fake_again)
    if procedure is None:
        raise ConfigError("name a procedure or a run to resume")
    spec = get_procedure(procedure)
    subject = spec.subject(cfg, robot)
    params = spec.new_params(cfg, robot, str(report_dir), dict(plan_overrides or {}))
    if fake is not None:
        params["fake"] = dict(fake)
        rc = cfg.robots.get(robot) if robot is not None else None
        scatter = getattr(rc, "stop_scatter_mm", None)
        if scatter is not None:  # the configured robot's simulated arm scatters so (unless the fake says)
            params["fake"].setdefault("stop_sigma_mm", float(scatter))
        model = getattr(rc, "motion_model", None)
        if model is not None:  # ... and moves with its diagnosed motion model (the file, read by the cell)
            params["fake"].setdefault("motion_model", str(model))
    if acceptance:  # what the run's verdict asks beyond the procedure (procedures.decision)
        params["acceptance"] = dict(acceptance)
    run_id = run_id or f"{subject.serial}-{time.strftime('%Y%m%d-%H%M%S')}"
    return PreparedRun(spec, run_id, params, False, robot, subject, params.get("fake"))


def preflight(prepared: PreparedRun, cfg, devices: DeviceSet) -> None:
    """Refuse, listing every problem, a plan its devices cannot run (before anything moves)."""
    problems = list(prepared.spec.preflight(prepared.params, cfg, devices))
    missing = sorted(set(prepared.spec.device_roles(cfg, prepared.robot)) - devices.roles()) \
        if not prepared.resume else []
    problems += [f"no {role} device in the device set" for role in missing]
    if problems:
        raise PreflightError(problems)


def execute(store: RunStore, prepared: PreparedRun, cfg, devices: DeviceSet, *, operator: Operator | None = None,
            control: RunControl | None = None, progress: Progress | None = None) -> RunOutcome:
    """Run (or resume) the prepared run on ``devices``; returns the runner's outcome."""
    spec = prepared.spec
    session = spec.new_session(devices)
    runner = Runner(store, spec.build(prepared.params), operator=operator, control=control, session=session,
                    progress=progress)
    try:
        if prepared.resume:
            return runner.resume(prepared.run_id)
        return runner.start(prepared.run_id, **prepared.start_kwargs(cfg))
    finally:
        session.close()
