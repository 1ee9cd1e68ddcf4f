"""ISO 9283 path test procedure (clauses 8.2-8.5, 11): path accuracy and repeatability (also on reorientation),
cornering, path velocity, weaving.

The pose procedure's cell, connection, home and registration
(:mod:`procedures.iso9283`), then the path programmes of
:func:`station.programs.path_builders.iso_path_tests` on the test plane of
the pose test's inset cube (line, large and small circle, rectangle with and
without a corner zone, at 100, 50 and 10 % of the rated speed; on request the
line driven while the tool turns, ``reorientation``, the tool turned about
its held point, ``reorientation_held`` (a 6-DoF target: the stream's angles
say how far it has turned), and the weave, ``weaving``, at its own speed):

1. ``check programs`` — every path programme through the safety gate before
   anything connects;
2. ``mount reflector`` / ``clear the cell`` — prompts, once per run;
3. ``connect devices``, ``home``, ``register base frame`` — as the pose test;
4. ``path NAME cycle k`` — one cycle of path NAME (its programme moves to the
   path's start first, so a cycle is entered the same way in a resumed run),
   the tracker streaming;
5. ``stop stream``, ``analyse`` — each path's cycles against its commanded
   geometry (:mod:`station.analysis.path`), AT, RT, AV, RV, FV, CR, CO, WS, WF
   with their U; rows in the characteristics table (one per path and figure),
   judged against the limits of the plan (the robot's configured AT/RT and
   the plan's ``path_limits``);
6. ``report`` — the run's HTML report (:mod:`procedures.iso9283_path_report`): per path its cycles against
   the commanded path, the deviation and the speed along it, and the figures with U and verdicts.

A run killed at any moment resumes at the cycle it was in (the interrupted
cycle is redone whole; its partial samples stay under their attempt, outside
the analysis). A cycle whose programme was paused on the controller (a UR's
pendant or dashboard) and played on fails its step the same way: the
controller halted the path and went on from where it stood, so the pass is
not one motion; a resume drives the cycle again from its start.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from procedures import iso9283 as iso
from procedures.decision import Checks, decide
from procedures.preflight import report_dir_problems, tracker_rate_problems
from procedures.registry import ProcedureSpec
from station import characteristics as table
from station.analysis.path.analysis import analyze_path, check_limits
from station.analysis.path.figures import SIGNED
from station.analysis.path.path_file import parse_paths
from station.errors import ConfigError, DataError, DeviceError, StationError
from station.programs import render_rapid
from station.programs.path_builders import (
    ALL_PATH_KINDS,
    PATH_KINDS,
    REORIENT_DEG,
    SPEED_FRACS,
    WEAVE_DEFAULTS,
    PathTest,
    iso_path_tests,
)
from station.runner import Procedure, Step, StepContext

RESULT = "iso9283-path"
#: plan keys of the path test (the rest is the pose test's plan)
PATH_KEYS = ("path_cycles", "path_speed_fracs", "path_kinds", "blend_mm", "path_side_mm", "path_limits",
             "reorient_deg", *WEAVE_DEFAULTS)


@dataclass(frozen=True)
class PathPlan(iso.IsoPlan):
    """The pose test's plan (cell, cube, registration, limits) and the path test's own parameters."""

    path_cycles: int = 10
    path_speed_fracs: tuple[float, ...] = SPEED_FRACS
    path_kinds: tuple[str, ...] = PATH_KINDS
    blend_mm: float = 20.0
    #: edge of the cube the paths span (None: the pose test's inset cube)
    path_side_mm: float | None = None
    #: limits of path figures, ``{"CR_mm": 2.0, "rectangle_blend_100.CO_mm": 1.0, ...}``
    path_limits: dict[str, float] = field(default_factory=dict)
    #: the reorientation's turn either side of the middle of its line, deg (path kind "reorientation")
    reorient_deg: float = REORIENT_DEG
    #: the weave (path kind "weaving"): amplitude (half the stroke), frequency, speed along the base, its
    #: periods and the vertices a period of its programme (:mod:`station.programs.weave`)
    weave_amplitude_mm: float = WEAVE_DEFAULTS["weave_amplitude_mm"]
    weave_frequency_Hz: float = WEAVE_DEFAULTS["weave_frequency_Hz"]
    weave_speed_mm_s: float = WEAVE_DEFAULTS["weave_speed_mm_s"]
    weave_periods: int = WEAVE_DEFAULTS["weave_periods"]
    weave_points_per_period: int = WEAVE_DEFAULTS["weave_points_per_period"]
    # params() and from_params() are the pose plan's: they follow the fields of the class they are called on


def plan_from_config(cfg, robot_name: str = "r1", **overrides) -> PathPlan:
    """The pose test's plan of the config with the path parameters of its ``[iso9283_path]`` section, those of
    ``overrides`` on top."""
    section = cfg.iso9283_path.model_dump(exclude_none=True) if cfg.iso9283_path is not None else {}
    path_kw = {k: section[k] for k in PATH_KEYS if k in section}
    path_kw |= {k: overrides.pop(k) for k in PATH_KEYS if k in overrides}
    for k in ("path_speed_fracs", "path_kinds"):
        if k in path_kw:
            path_kw[k] = tuple(path_kw[k])
    unknown = [k for k in path_kw.get("path_kinds", ()) if k not in ALL_PATH_KINDS]
    if unknown:
        raise ConfigError(f"iso9283_path.path_kinds: unknown path {unknown[0]!r} (known: {', '.join(ALL_PATH_KINDS)})")
    base = iso.plan_from_config(cfg, robot_name, **overrides)
    plan = PathPlan(**{f.name: getattr(base, f.name) for f in dataclasses.fields(iso.IsoPlan)}, **path_kw)
    if plan.path_cycles < 2:
        raise ConfigError(f"path_cycles must be at least 2 (path repeatability), got {plan.path_cycles}")
    if "reorientation_held" in plan.path_kinds and not plan.orientation:
        raise ConfigError("iso9283_path.path_kinds: reorientation_held measures the angle the tool turns: it needs "
                          "a 6-DoF target on the tracker (devices.tracker.six_dof = true)")
    try:
        check_limits(limits_of(plan), parse_paths({"paths": [t.path for t in path_tests(plan)]}))
    except ConfigError as exc:
        raise ConfigError(f"path_limits: {str(exc).replace('--limit ', '')}") from None
    return plan


def cube_of(plan: PathPlan) -> tuple[np.ndarray, float]:
    """Centre (P1) and edge of the cube the paths lie in: the pose test's inset cube unless the plan says."""
    centre = np.asarray(plan.poses_mm["P1"], float)
    if plan.path_side_mm:
        return centre, float(plan.path_side_mm)
    offsets = np.array([np.asarray(p, float) - centre for p in plan.poses_mm.values()])
    return centre, 2.0 * float(np.max(np.abs(offsets)))


def path_tests(plan: PathPlan) -> list[PathTest]:
    """The plan's path programmes, one cycle each (a step runs one)."""
    centre, side = cube_of(plan)
    return iso_path_tests(plan.robot, centre, side, cycles=1, speed_fracs=plan.path_speed_fracs,
                          kinds=plan.path_kinds, blend_mm=plan.blend_mm, reorient_deg=plan.reorient_deg,
                          weave={k: getattr(plan, k) for k in WEAVE_DEFAULTS})


def cycle_program(plan: PathPlan, index: int, k: int):
    """Cycle ``k`` of path ``index``, rendered (RAPID) under a name of its own (``PATH03_C2``): the controller
    tells the cycles apart, and so do the fakes' draws (a resumed cycle meets the same arm)."""
    test = path_tests(plan)[index]
    return render_rapid(dataclasses.replace(test.program, name=f"PATH{index:02d}_C{k}"))


def limits_of(plan: PathPlan) -> dict[str, float]:
    """Limits of the path figures: the robot's configured ones of the table (AT_mm, RT_mm) and the plan's."""
    from station.analysis.path.figures import NAMES

    return {**{k: v for k, v in plan.limits.items() if k in NAMES}, **plan.path_limits}


def _plan(ctx: StepContext) -> PathPlan:
    return PathPlan.from_params(ctx.params)


def step_check_programs(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    gate = plan.gate()
    checked = {}
    for i, t in enumerate(path_tests(plan)):
        report = gate.check_program(cycle_program(plan, i, 1).program, q_start=None)
        checked[t.path["name"]] = {"moves": int(report.q_rad.shape[0]),
                                   "peak_tcp_speed_mm_s": float(report.peak_tcp_speed_mm_s)}
    ctx.session.gate = gate
    return {"programs": checked}


def _cycle_step(index: int, k: int):
    def run(ctx: StepContext) -> dict:
        plan = _plan(ctx)
        rendered = cycle_program(plan, index, k)
        ctx.session.moved_by = ctx.step.name
        out = iso._run_program(ctx, rendered, timeout_s=iso._timeout(ctx, 120.0), stream=True)
        if out.get("paused"):
            # a controller halts a paused path where it is and goes on from there on play: the pass is not one
            # motion. The step fails (its samples stay under this attempt, outside the analysis) and a resume
            # drives the cycle again from its start, as after any interruption
            raise DeviceError(f"{ctx.step.name}: the program was paused on the controller while it drove the path; "
                              "a paused path is halted, not taken up, so this cycle is no whole pass: resume the "
                              "run to drive it again from its start")
        return out
    return run


def step_names(plan: PathPlan) -> dict[str, list[str]]:
    """``{path name: its cycle steps}``."""
    return {t.path["name"]: [f"path {t.path['name']} cycle {k}" for k in range(1, plan.path_cycles + 1)]
            for t in path_tests(plan)}


def specs_of(plan: PathPlan) -> dict:
    """``{path name: PathSpec}`` of the plan's commanded paths."""
    return {s.name: s for s in parse_paths({"paths": [t.path for t in path_tests(plan)]})}


def analyse(plan: PathPlan, streams: Mapping[str, tuple], angles: Mapping[str, np.ndarray] | None = None) -> dict:
    """Each path's figures (pure): ``streams`` ``{path name: (t_s, xyz_mm base frame, valid)}``; ``angles``
    ``{path name: (N, 3) tool angles a, b, c in the base frame, deg}`` of the paths that turn the tool about its
    held point (a 6-DoF stream's)."""
    specs = specs_of(plan)
    out = {}
    for name, (t, xyz, valid) in streams.items():
        out[name] = analyze_path(specs[name], t, xyz, valid, abc_deg=(angles or {}).get(name), seed=0)
    return out


def rows_of(plan: PathPlan, results: Mapping) -> list[dict]:
    """One row per path and figure (programme "path" of the characteristics table), judged where limited."""
    limits = limits_of(plan)
    rows = []
    for name, r in results.items():
        for fig in r.figures:
            lim = limits.get(f"{name}.{fig}", limits.get(fig))
            v = r.figures[fig]
            passed = None if lim is None or v is None else bool((abs(v) if fig in SIGNED else v) <= lim)
            rows.append({"pose": name, "name": fig, "value": v, "unit": table.unit_of(fig), "limit": lim,
                         "passed": passed})
        rows.append({"pose": name, "name": "n_cycles", "value": float(r.n_cycles), "unit": "", "limit": None,
                     "passed": None})
    return rows


def _streams(ctx: StepContext, plan: PathPlan) -> tuple[dict, dict]:
    """``({path: (t, xyz, valid)}, {path: tool angles a, b, c, deg})``: the angles of the held turns only."""
    out, angles = {}, {}
    held = {s.name for s in specs_of(plan).values() if s.kind == "reorientation"}
    for name, steps in step_names(plan).items():
        b = iso._stream_in_base(ctx, steps)
        out[name] = (b.t, b.xyz, (np.asarray(b.status) == 0) & np.all(np.isfinite(b.xyz), axis=1))
        if name in held:
            if b.abc is None:
                raise DataError(f"path {name}: the tool turns about its held point and the stream has no "
                                "orientation (a 6-DoF target: devices.tracker.six_dof)")
            angles[name] = np.degrees(b.abc)
    return out, angles


def _analysed(ctx: StepContext, plan: PathPlan) -> tuple[dict, dict]:
    """``(streams, results)`` of this session, read and analysed once (a resumed run's report step again)."""
    if ctx.session.analysis is None:
        ctx.session.streams, angles = _streams(ctx, plan)
        ctx.session.analysis = analyse(plan, ctx.session.streams, angles)
    return ctx.session.streams, ctx.session.analysis


def step_analyse(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    _, results = _analysed(ctx, plan)
    rows = rows_of(plan, results)
    ctx.store.put_characteristics(ctx.run_id, rows)
    ctx.store.put_result(ctx.run_id, RESULT, {n: r.to_dict() for n, r in results.items()})
    return {"n_rows": len(rows), "cycles": {n: r.n_cycles for n, r in results.items()}}


def step_report(ctx: StepContext) -> dict:
    """The run's HTML report (:mod:`procedures.iso9283_path_report`) in the plan's report directory, with the
    run's verdict as decided from the stored rows."""
    from procedures.iso9283_path_report import build_report
    from station.report import write_report

    plan = _plan(ctx)
    streams, results = _analysed(ctx, plan)
    report = build_report(plan, ctx.store.run(ctx.run_id), ctx.store.characteristics(ctx.run_id), specs_of(plan),
                          results, streams)
    decision = decide(SPEC, ctx.store, ctx.run_id, finished=True)
    report.outcome, report.reasons = decision.outcome, list(decision.reasons)
    path = write_report(report, Path(plan.report_dir) / f"{ctx.run_id}.html")
    return {"report": str(path.resolve()), "verdict": report.verdict}


def build_procedure(plan: PathPlan) -> Procedure:
    steps = [
        Step("check programs", step_check_programs, every_session=True),
        Step("mount reflector", iso._prompt("Mount the tracker reflector on the tool flange (SMR in its nest)")),
        Step("clear the cell", iso._prompt("Clear the robot cell and close the safety fence")),
        Step("connect devices", iso.step_connect, every_session=True),
        Step("home", iso.step_home, every_session=True),
        Step("register base frame", iso.step_register),
    ]
    for i, t in enumerate(path_tests(plan)):
        steps += [Step(f"path {t.path['name']} cycle {k}", _cycle_step(i, k), label=f"{k}/{plan.path_cycles}")
                  for k in range(1, plan.path_cycles + 1)]
    steps += [Step("stop stream", iso.step_stop_stream), Step("analyse", step_analyse, offline=True),
              Step("report", step_report, offline=True)]
    return Procedure(RESULT, steps, safe_state=iso.safe_state)


def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    return plan_from_config(cfg, robot, **{"report_dir": report_dir, **overrides}).params()


def summary(store, run_id: str) -> list[str]:
    rows = store.characteristics(run_id)
    lines = []
    for r in rows:
        if r["value"] is None:
            lines.append(f"{r['pose']:<24} {r['name']:<12} -")
        else:
            mark = "" if r["passed"] is None else (" PASS" if r["passed"] else " FAIL")
            lines.append(f"{r['pose']:<24} {r['name']:<12} {r['value']:.4g}{mark}")
    return lines


def run_checks(store, run_id: str, params: Mapping) -> Checks:
    """Fewer cycles found on a path than asked, or a limited figure not computed: NOT DECIDED."""
    asked = int(params.get("path_cycles", 0))
    undecided = []
    for r in store.characteristics(run_id):
        if r["name"] == "n_cycles" and (r["value"] or 0) < asked:
            undecided.append(f"{r['pose']}: {int(r['value'] or 0)} of {asked} path cycles found")
        elif r["limit"] is not None and r["value"] is None:
            undecided.append(f"{r['pose']} {r['name']}: limit {r['limit']:g} configured, figure not computed")
    return Checks(tuple(undecided), None, ())


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    plan = PathPlan.from_params(params)
    problems = report_dir_problems(plan.report_dir)
    problems += tracker_rate_problems(devices, plan.tracker_rate_hz, field="iso9283.tracker_rate_hz")
    gate = plan.gate()
    try:
        for i, t in enumerate(path_tests(plan)):
            try:
                gate.check_program(cycle_program(plan, i, 1).program, q_start=None)
            except StationError as exc:
                problems.append(f"path {t.path['name']}: {exc}")
    except StationError as exc:
        problems.append(f"path programmes: {exc}")
    return problems


def subject(cfg, robot: str):
    """The configured robot; the path test is offered where the config has its ``[iso9283_path]`` section."""
    if cfg.iso9283_path is None:
        raise ConfigError("iso9283_path: the config has no path test section ([iso9283_path] with path_cycles, "
                          "path_speed_fracs, path_kinds, blend_mm, path_side_mm, path_limits)")
    return iso.subject(cfg, robot)


SPEC = ProcedureSpec(
    name=RESULT,
    new_params=new_params,
    build=lambda params: build_procedure(PathPlan.from_params(params)),
    new_session=lambda devices: iso.IsoSession(devices),
    subject=subject,
    device_roles=iso.device_roles,
    fake_cell="fakes.cells:iso9283_cell",
    result_key=RESULT,
    summary=summary,
    preflight=preflight_problems,
    checks=run_checks,
)
