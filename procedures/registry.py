"""The procedures the station can run, by name.

Each entry names the module that defines the procedure; that module exposes
``SPEC``, a :class:`ProcedureSpec` that says everything the application layer
(:mod:`procedures.execute`) needs to plan, assemble and run it. Adding a
procedure is adding its module and one line in :data:`REGISTRY`.

The fake cell that serves a procedure's devices is *named* in its spec
(``"module:function"``), not imported: procedures depend on drivers, never on
fakes; the front door that chooses the fake cell imports it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from station.errors import ConfigError

#: procedure name -> module whose ``SPEC`` defines it
REGISTRY: dict[str, str] = {
    "iso9283": "procedures.iso9283",
    "iso9283-path": "procedures.iso9283_path",
    "trailer": "procedures.trailer",
    "arm-calibration": "procedures.arm_calibration",
    "compliance": "procedures.compliance",
    "iso9283-drift": "procedures.iso9283_drift",
}


@dataclass(frozen=True)
class Subject:
    """What a run is made on: stored with the run, shown in the armed-run prompt."""

    model: str | None
    serial: str | None
    overhaul_state: str | None
    what: str  # e.g. "industrial-3100 serial NA8608-0042"


@dataclass(frozen=True)
class ProcedureSpec:
    """How to plan, assemble and run one procedure.

    Attributes
    ----------
    name : str
        The name runs are stored under (``station run NAME``).
    new_params : callable
        ``new_params(cfg, robot, report_dir, overrides) -> dict``: the JSON-able
        plan of a new run, stored with it (a resume rebuilds from it alone).
    build : callable
        ``build(params) -> station.runner.Procedure``: the named steps.
    new_session : callable
        ``new_session(devices) -> Session``: the typed session of one process.
    subject : callable
        ``subject(cfg, robot) -> Subject``.
    device_roles : callable
        ``device_roles(cfg, robot) -> {role: device name in the config}``:
        what ``--arm`` opens.
    fake_cell : str
        ``"module:function"`` of the fake cell serving the roles
        (``function(params, fake) -> cell`` with ``urls``, ``time_scale``, ``close()``).
    result_key : str
        The store's result entry of the run (``--json`` writes it).
    summary : callable
        ``summary(store, run_id) -> list[str]``: the results as console lines.
    preflight : callable
        ``preflight(params, cfg, devices) -> list[str]``: every reason the
        devices cannot run the plan, found before anything moves.
    checks : callable or None
        ``checks(store, run_id, params) -> procedures.decision.Checks``: what
        the procedure says of a finished run beyond its stored limits (cycles
        found against asked, limits not computed, conformance to its standard);
        :func:`procedures.decision.decide` combines it into the run's verdict.
    reanalyse : callable or None
        ``reanalyse(store, run_id) -> (result, rows)``: the procedure's analysis
        of a finished stored run from its plan, journal and raw samples (the
        result stored under ``result_key``, the characteristic rows); None:
        its runs are not re-analysed (``station store reanalyze``).
    live_view : callable or None
        ``live_view(store, run_id, params) -> dict``: what the run page shows of the procedure's instrument
        while it runs (:mod:`procedures.live_views`); None: the page draws the tracker's stream.
    standard : str or None
        The standard whose conformance an acceptance requires by default (``"ISO 9283"``: its cycles);
        None: the procedure has no conformance to check (an acceptance of it is judged by its figures).
    """

    name: str
    new_params: Callable[[Any, str, str, Mapping], dict]
    build: Callable[[Mapping], Any]
    new_session: Callable[[Any], Any]
    subject: Callable[[Any, str], Subject]
    device_roles: Callable[[Any, str], dict[str, str]]
    fake_cell: str
    result_key: str
    summary: Callable[[Any, str], list[str]]
    preflight: Callable[[Mapping, Any, Any], list[str]] = field(default=lambda params, cfg, devices: [])
    checks: Callable[[Any, str, Mapping], Any] | None = None
    reanalyse: Callable[[Any, str], tuple[dict, list[dict]]] | None = None
    live_view: Callable[[Any, str, Mapping], dict] | None = None
    standard: str | None = None


def procedure_names() -> tuple[str, ...]:
    return tuple(REGISTRY)


def runnable_procedures(cfg) -> tuple[str, ...]:
    """The procedures this config can run: those whose subject and devices it names for some robot (the
    trailer needs its [trailer] section, a cell procedure a robot with a controller device)."""
    from station.errors import StationError

    out = []
    for name in REGISTRY:
        spec = get_procedure(name)
        for robot in list(cfg.robots) or ["r1"]:
            try:
                spec.subject(cfg, robot)
                roles = spec.device_roles(cfg, robot)
            except StationError:
                continue
            if all(device in cfg.devices for device in roles.values()):
                out.append(name)
                break
    return tuple(out)


def reanalysable() -> dict[str, ProcedureSpec]:
    """The procedures whose runs can be re-analysed, by name."""
    return {name: spec for name in REGISTRY if (spec := get_procedure(name)).reanalyse is not None}


def module_of(name: str) -> str:
    """The module that defines procedure ``name`` (its source is part of the analysis version)."""
    get_procedure(name)
    return REGISTRY[name]


def get_procedure(name: str) -> ProcedureSpec:
    """The spec of procedure ``name``; ConfigError naming the known ones otherwise."""
    if name not in REGISTRY:
        raise ConfigError(f"unknown procedure {name!r}; known: {', '.join(REGISTRY)}")
    spec = importlib.import_module(REGISTRY[name]).SPEC
    if spec.name != name:
        raise ConfigError(f"registry entry {name!r} points at the spec of {spec.name!r}")
    return spec
