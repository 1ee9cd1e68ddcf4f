"""Steps a robot-and-tracker cell shares across procedures (ISO 9283, arm calibration).

:func:`connect_cell` opens the tracker and the controller of a session and
takes over from an earlier session that died (a program left running, the
comm-watchdog fault it caused); :func:`stop_cell` is the procedures' safe
state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from procedures.registry import Subject
from procedures.session import Session
from station.errors import ConfigError, StationError


@dataclass
class CellSession(Session):
    """What the steps of a robot-and-instrument cell share within one session: the plan (rebuilt from the
    stored parameters once), the safety gate, the open tracker and controller."""

    plan: Any = None
    gate: Any = None
    tracker: Any = None
    controller: Any = None


def connect_controller(session, gate) -> dict:
    """Open ``session.controller`` (a :class:`drivers.robot.Robot`: the program-upload controller or the UR)
    behind ``gate``; stop or clear what an earlier session that died left (:meth:`~drivers.robot.Robot.take_over`)."""
    controller = session.controller = session.device("controller", gate=gate)
    controller.connect()
    state, took_over = controller.take_over()
    return {"controller_state": state, "took_over": took_over}


#: the stream of the arm's own readings (controller time; joints deg, TCP mm in the base frame)
ROBOT_STREAM = "robot"


def record_robot_readings(ctx, robot, counts: dict | None = None) -> int:
    """Commit the arm's own joint and TCP readings since the last call to the run's ``robot`` stream
    (a robot that gives only point reads records nothing); how many. ``counts`` (a dict) accumulates
    ``received``, ``dropped`` and ``missed`` for the step's output."""
    readings = robot.readings()
    if readings is None:
        return 0
    if counts is not None:
        for key, n in (("received", len(readings)), ("dropped", readings.dropped), ("missed", readings.missed)):
            counts[key] = counts.get(key, 0) + int(n)
    if not len(readings):
        return 0
    return ctx.record(ROBOT_STREAM, readings.columns())


def connect_cell(session, gate) -> dict:
    """Open ``session.tracker`` (mm) and ``session.controller`` (behind ``gate``); say what was taken over."""
    tracker = session.tracker = session.device("tracker")
    info = tracker.connect()
    tracker.set_units("mm")
    return {"tracker": str(getattr(info, "name", info)), **connect_controller(session, gate)}


def prompt_step(message: str):
    """A step that asks the operator ``message`` and fails the run on a no."""
    def run(ctx) -> dict:
        if not ctx.confirm(message):
            raise StationError(f"operator declined: {message}")
        return {"confirmed": message}
    return run


def stop_cell(session) -> None:
    """Stop the program and the stream; keep the connections for a resume to reopen."""
    errors = []
    controller = getattr(session, "controller", None)
    if controller is not None:
        try:
            controller.stop()
        except Exception as exc:  # report, keep going: the stream must stop too
            errors.append(f"controller stop: {exc}")
    tracker = getattr(session, "tracker", None)
    if tracker is not None and getattr(tracker, "streaming", False):
        try:
            tracker.stop_stream()
        except Exception as exc:
            errors.append(f"tracker stop: {exc}")
    if errors:
        raise StationError("; ".join(errors))


def robot_subject(cfg, robot: str) -> Subject:
    """The configured robot a cell procedure runs on (``robots.NAME`` of the config)."""
    rc = cfg.robots.get(robot)
    if rc is None:
        raise ConfigError(f"robots.{robot}: no such robot (have {', '.join(sorted(cfg.robots))})")
    return Subject(rc.model, rc.serial, rc.overhaul_state, f"{rc.model} serial {rc.serial}")

