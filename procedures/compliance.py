"""ISO 9283 clause 10, static compliance: loads on the tool, a force gauge in the load path, a tracker.

Steps (the cell's, as in :mod:`procedures.iso9283`, then the loads):

1. ``check programs`` (every session) — the safety gate over the cell's programs;
2. ``mount reflector`` / ``mount gauge`` / ``clear the cell`` — operator prompts;
3. ``connect devices`` (every session) — tracker, controller and the force gauge (its model and serial);
4. ``home``, ``register base frame`` — as the ISO procedure (the tracker tied to the base frame);
5. ``go to P1`` (every session) — the arm to the test pose (the cube's centre, ISO 9283 clause 10), where
   it holds under servo; ``hold`` — stationary points of the unloaded tool at the loading's pace (the
   tracker's scatter on that time scale, for the slope's uncertainty);
6. ``load +x`` ... ``load -z`` — one step per direction of the base frame: the operator takes every load off
   the tool, the gauge is zeroed, then for each level of :func:`load_levels_N` (up to the rated load in
   ``steps`` steps and back down) the operator pulls the tool along the direction until the gauge reads it
   (a prompt on the console or the page), and the station reads the gauge (``gauge_readings`` readings,
   before and after) and a stationary tracker point;
7. ``analyse`` — per direction, the slope of the displacement along the load against the gauge's load
   (:mod:`station.analysis.iso9283.compliance`), its standard error and U (k = 2), and the hysteresis;
8. ``report`` — the figures and the plot of displacement against load, loading and unloading apart.

The plan is the ISO plan of the config (cube, registration) with a ``compliance`` entry:
``rated_load_N`` (default the arm's rated payload times g), ``steps`` (10), ``directions`` (all six),
``gauge_readings`` (3), ``measure_s`` (0.5: the tracker's averaging), ``u_F_rel`` (0.005: the gauge's
relative standard uncertainty), ``hold_readings`` (null: as many as the load levels; 0: no hold);
``--set``-style overrides of those names reach it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from procedures.cell import prompt_step, robot_subject
from procedures.iso9283 import (IsoPlan, IsoSession, _plan, _point_program, _run_program, _timeout, plan_from_config,
                                registration_of, safe_state, step_check_programs, step_connect, step_home,
                                step_register)
from procedures.preflight import report_dir_problems
from procedures.registry import ProcedureSpec
from station.analysis.iso9283.compliance import (COMPLIANCE, DIRECTIONS, characteristic_rows, direction_compliance,
                                                 load_levels_N, load_prompt)
from station.errors import ConfigError, StationError
from station.programs.rapid import render_rapid
from station.runner import Procedure, Step, StepContext

#: the plan's compliance entry: name -> default (None: from the arm)
DEFAULTS: dict[str, Any] = {"rated_load_N": None, "steps": 10, "directions": list(DIRECTIONS), "gauge_readings": 3,
                            "measure_s": 0.5, "u_F_rel": 0.005, "pose": "P1", "hold_readings": None}
G_M_S2 = 9.80665


@dataclass
class ComplianceSession(IsoSession):
    """The cell's session with the force gauge."""

    gauge: Any = None


def compliance_params(params: Mapping) -> dict:
    """The compliance entry of a plan, checked; ConfigError names a bad value."""
    c = dict(params["compliance"])
    if sorted(c) != sorted(DEFAULTS):
        raise ConfigError(f"compliance plan: expected {', '.join(sorted(DEFAULTS))}, got {', '.join(sorted(c))}")
    bad = [d for d in c["directions"] if d not in DIRECTIONS]
    if bad or not c["directions"] or len(set(c["directions"])) != len(c["directions"]):
        raise ConfigError(f"compliance.directions must be distinct ones of {', '.join(DIRECTIONS)}, "
                          f"got {c['directions']!r}")
    load_levels_N(c["rated_load_N"], c["steps"])  # checks both
    if not (isinstance(c["gauge_readings"], int) and 1 <= c["gauge_readings"] <= 100):
        raise ConfigError(f"compliance.gauge_readings must be an integer within 1-100, got {c['gauge_readings']!r}")
    if not (isinstance(c["measure_s"], (int, float)) and 0.05 <= c["measure_s"] <= 60):
        raise ConfigError(f"compliance.measure_s must be within 0.05-60 s, got {c['measure_s']!r}")
    if not (isinstance(c["u_F_rel"], (int, float)) and 0 <= c["u_F_rel"] < 0.5):
        raise ConfigError(f"compliance.u_F_rel must be within [0, 0.5), got {c['u_F_rel']!r}")
    if c["hold_readings"] is not None and not (isinstance(c["hold_readings"], int)
                                               and not isinstance(c["hold_readings"], bool)
                                               and (c["hold_readings"] == 0 or 3 <= c["hold_readings"] <= 1000)):
        raise ConfigError(f"compliance.hold_readings must be 0 (no hold), an integer within 3-1000 or null (as many "
                          f"as the load levels), got {c['hold_readings']!r}")
    if c["pose"] not in params["poses_mm"]:
        raise ConfigError(f"compliance.pose {c['pose']!r} is not a pose of the plan ({', '.join(params['poses_mm'])})")
    return c


# --------------------------------------------------------------------------- steps
def step_connect_all(ctx: StepContext) -> dict:
    out = step_connect(ctx)
    gauge = ctx.session.gauge = ctx.session.device("gauge")
    out["gauge"] = gauge.connect()
    return out


def step_go_to_pose(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    name = compliance_params(ctx.params)["pose"]
    prog = render_rapid(_point_program(plan, name, plan.poses_mm[name], dwell_s=1.0))
    ctx.session.moved_by = ctx.step.name
    return {"pose": name, **_run_program(ctx, prog, timeout_s=_timeout(ctx, 60), stream=False)}


def hold_readings(c: Mapping) -> int:
    """How many stationary points the hold takes (the load levels' count unless the plan says)."""
    n = c["hold_readings"]
    return len(load_levels_N(float(c["rated_load_N"]), int(c["steps"]))) if n is None else int(n)


def step_hold(ctx: StepContext) -> dict:
    """The unloaded tool held at the test pose: as many stationary points as a direction has load levels, at
    its pace (the gauge read before and after each, as there): the tracker's scatter on the loading's time
    scale, which the slope's residuals do not show of a slow wander (:mod:`station.analysis.iso9283.compliance`)."""
    c = compliance_params(ctx.params)
    gauge, tracker = ctx.session.gauge, ctx.session.tracker
    points = []
    for _ in range(hold_readings(c)):
        ctx.checkpoint()
        gauge.read_force_avg_N(int(c["gauge_readings"]))
        m = tracker.measure_stationary(duration_s=float(c["measure_s"]))
        gauge.read_force_avg_N(int(c["gauge_readings"]))
        points.append([float(v) for v in m.xyz_mm])
    return {"tracker_mm": points}


def step_load(direction: str):
    """The load programme of one direction: zero, then every level with the gauge and a tracker point."""
    def run(ctx: StepContext) -> dict:
        c = compliance_params(ctx.params)
        gauge, tracker = ctx.session.gauge, ctx.session.tracker
        levels = load_levels_N(float(c["rated_load_N"]), int(c["steps"]))
        peak = int(np.argmax(levels))
        out = {"direction": direction, "asked_N": [], "load_N": [], "load_sd_N": [], "tracker_mm": [], "loading": []}
        for k, level in enumerate(levels):
            ctx.checkpoint()
            message = load_prompt(direction, float(level))
            if not ctx.confirm(message):
                raise StationError(f"operator declined: {message}")
            if k == 0:  # nothing on the tool: the gauge's zero
                gauge.zero()
            before, sd_b = gauge.read_force_avg_N(int(c["gauge_readings"]))
            m = tracker.measure_stationary(duration_s=float(c["measure_s"]))
            after, sd_a = gauge.read_force_avg_N(int(c["gauge_readings"]))
            out["asked_N"].append(float(level))
            out["load_N"].append(0.5 * (before + after))
            # the load's steadiness while the tracker measured: the change across it, and the gauge's scatter
            out["load_sd_N"].append(float(max(abs(after - before) / 2.0, sd_b, sd_a)))
            out["tracker_mm"].append([float(v) for v in m.xyz_mm])
            out["loading"].append(k <= peak)
            ctx.progress(f"{direction} {level:.0f} N")
        return out
    return run


def analyse_outputs(params: Mapping, outputs: Mapping) -> list:
    """Every measured direction's :class:`DirectionCompliance` from the steps' outputs (base frame)."""
    c = compliance_params(params)
    reg = registration_of(outputs)
    held = (outputs.get("hold") or {}).get("tracker_mm")
    hold = reg.to_base(np.asarray(held, dtype=float)) if held and len(held) >= 3 else None
    results = []
    for d in c["directions"]:
        out = outputs.get(f"load {d}")
        if out is None:
            continue
        P = reg.to_base(np.asarray(out["tracker_mm"], dtype=float))
        results.append(direction_compliance(d, out["load_N"], P, out["loading"], u_F_rel=float(c["u_F_rel"]),
                                            hold_mm=hold))
    return results


def step_analyse(ctx: StepContext) -> dict:
    results = analyse_outputs(ctx.params, ctx.outputs)
    ctx.store.put_characteristics(ctx.run_id, characteristic_rows(results))
    ctx.store.put_result(ctx.run_id, "compliance", {"figure": COMPLIANCE.key, "unit": COMPLIANCE.unit,
                                                    "directions": [r.to_dict() for r in results]})
    return {"directions": [r.direction for r in results]}


def step_report(ctx: StepContext) -> dict:
    from station.report import Report, plot_load_displacement, write_report

    plan = _plan(ctx)
    results = analyse_outputs(ctx.params, ctx.outputs)
    c = compliance_params(ctx.params)
    run = ctx.store.run(ctx.run_id)
    rep = Report(title=f"Static compliance (ISO 9283 clause 10) - {run.model} {run.serial}",
                 facts={"run": ctx.run_id, "test pose": f"{c['pose']} {list(plan.poses_mm[c['pose']])} mm",
                        "rated load": f"{c['rated_load_N']:.0f} N in {c['steps']} steps, up and down",
                        "gauge": str(ctx.outputs.get("connect devices", {}).get("gauge", "")),
                        "uncertainty": "U = k u (k: Student's t at 95 %), u^2 = max(se(slope), se_noise)^2 + "
                                       f"(slope u_F_rel)^2, u_F_rel = {c['u_F_rel']:g}; se_noise from a hold of "
                                       f"{hold_readings(c)} points (0: none)"},
                 rows=[{"pose": r.direction, "name": COMPLIANCE.key, "value": r.compliance_mm_per_N,
                        "unit": COMPLIANCE.unit, "limit": None, "passed": None} for r in results])
    rep.figures.append(("Displacement along the load against the load",
                        plot_load_displacement({r.direction: (np.array(r.load_N), np.array(r.displacement_mm),
                                                              np.array(r.loading)) for r in results})))
    rep.notes += [f"{r.direction}: {r.compliance_mm_per_N:.4g} mm/N, U = {r.U_mm_per_N:.2g} mm/N (k = {r.k:.2f}), "
                  f"hysteresis {r.hysteresis_mm * 1000:.1f} um, residual sd {r.residual_sd_mm * 1000:.1f} um"
                  for r in results]
    path = write_report(rep, Path(plan.report_dir) / f"{ctx.run_id}.html")
    out = {"report": str(path.resolve())}
    ctx.store.put_result(ctx.run_id, "compliance", {**ctx.store.result(ctx.run_id, "compliance"), **out})
    return out


def build_procedure(params: Mapping) -> Procedure:
    c = compliance_params(params)
    steps = [
        Step("check programs", step_check_programs, every_session=True),
        Step("mount reflector", prompt_step("Mount the tracker reflector on the tool flange (SMR in its nest)")),
        Step("mount gauge", prompt_step("Hook the force gauge's pull line to the tool flange at the TCP")),
        Step("clear the cell", prompt_step("Clear the robot cell and close the safety fence; stand at the tool "
                                           "with the force gauge")),
        Step("connect devices", step_connect_all, every_session=True),
        Step("home", step_home, every_session=True),
        Step("register base frame", step_register),
        Step(f"go to {c['pose']}", step_go_to_pose, every_session=True),
    ]
    if hold_readings(c):
        steps.append(Step("hold", step_hold))
    steps += [Step(f"load {d}", step_load(d), label=d) for d in c["directions"]]
    steps += [Step("analyse", step_analyse, offline=True), Step("report", step_report, offline=True)]
    return Procedure("compliance", steps, safe_state=safe_state)


# --------------------------------------------------------------------------- the registry's entry
def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    """The ISO plan of the config (cube, P1, registration) with the compliance entry."""
    iso_over = {k: v for k, v in overrides.items() if k not in DEFAULTS}
    params = plan_from_config(cfg, robot, **{"report_dir": report_dir, **iso_over}).params()
    c = {k: overrides.get(k, v) for k, v in DEFAULTS.items()}
    if c["rated_load_N"] is None:
        c["rated_load_N"] = round(IsoPlan.from_params(params).robot.rated_payload_kg * G_M_S2, 1)
    c["directions"] = list(c["directions"])
    params["compliance"] = c
    compliance_params(params)
    return params


def device_roles(cfg, robot: str) -> dict[str, str]:
    robot_subject(cfg, robot)
    return {"tracker": "tracker", "controller": cfg.robots[robot].controller, "gauge": "gauge"}


def summary(store, run_id: str) -> list[str]:
    try:
        res = store.result(run_id, "compliance")
    except Exception:  # noqa: BLE001 - nothing analysed yet
        return []
    lines = [f"{'direction':<10}{'mm/N':>12}{'U mm/N':>12}{'hyst. um':>10}{'max N':>9}"]
    for r in res["directions"]:
        lines.append(f"{r['direction']:<10}{r['compliance_mm_per_N']:>12.4g}{r['U_mm_per_N']:>12.2g}"
                     f"{r['hysteresis_mm'] * 1000:>10.1f}{r['max_load_N']:>9.0f}")
    if res.get("report"):
        lines.append(f"report: {res['report']}")
    return lines


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    problems = report_dir_problems(params.get("report_dir", "reports"))
    try:
        compliance_params(params)
    except StationError as exc:
        problems.append(str(exc))
    if "gauge" not in devices.roles():
        problems.append(f"the run needs a force gauge (role 'gauge'); the device set has "
                        f"{', '.join(sorted(devices.roles())) or 'none'}")
    return problems


SPEC = ProcedureSpec(
    name="compliance",
    new_params=new_params,
    build=build_procedure,
    new_session=lambda devices: ComplianceSession(devices),
    subject=robot_subject,
    device_roles=device_roles,
    fake_cell="fakes.cells:compliance_cell",
    result_key="compliance",
    summary=summary,
    preflight=preflight_problems,
)
