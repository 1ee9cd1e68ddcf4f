"""ISO 9283 drift programme: the pose test repeated over a span from a cold start (``station run iso9283-drift``).

The arm starts cold; the station measures a visit of a few pose cycles (seed
000 sec. 3.1.3, the pose test's cycle) every ``interval_s`` over ``span_s``
(e.g. 8 h, every 10 minutes), the arm holding at the cycle's last pose in
between, and states the drift of AP and RP from the first visit to the last
(:mod:`station.analysis.iso9283.drift_programme`), AP(t) and RP(t) of every
visit with their U, and the plot of both against the time since the start.
With a 6-DoF target on the tool (``devices.tracker.six_dof``, as the pose
test) the orientation's too: dAPa, dAPb, dAPc and dRPa, dRPb, dRPc per pose
with their U, APa..RPc of every visit, and the plots of APa, APb, APc(t).

Steps:

1. ``check programs`` (every session), ``mount reflector``, ``clear the cell``,
   ``connect devices`` (every session), ``home`` (every session) and
   ``register base frame``: the pose test's own (:mod:`procedures.iso9283`);
2. ``cold start``: the operator confirms the arm starts cold (switched off or
   at rest long enough to be at room temperature); the programme's time
   counts from the first sample of visit 1;
3. ``visit v`` (v = 1..V): ``cycles_per_visit`` pose cycles while the tracker
   streams, the stream stopped at the end. A session that did not run the
   step before (a resume) first runs one cycle unmeasured, so the visit's
   first stop is approached as in an uninterrupted run;
4. ``wait v`` (between visits): the arm holds while the device clock runs to
   visit ``v + 1``'s time (the first visit's start + v x ``interval_s``), a
   dwell the controller runs (on the fakes the simulated clock runs it in
   lockstep, faster than real time); its last :data:`HELD_S` are streamed,
   so the device time of its end is stored with the run. The time comes from
   the tracker's device time of the last stored samples; a resumed wait knows
   only those, so a visit after a resume may start later than planned by the
   time the resume took (its own time is what is recorded and used). A visit
   found to start before its planned time (a device clock that went back)
   leaves the run undecided;
5. ``analyse``, ``report``: offline.

Everything a visit measured is committed to the run store as it arrives; a
run killed within a visit redoes that visit whole (its partial samples stay
under their attempt, outside the analysis), one killed during a wait waits
again for the same device time. Nothing measured is lost, and a resume never
measures a visit twice.

The plan is the ISO plan of the config (cube, poses, registration, tracker
rate, limits ``dap_limit_mm``, ``drp_limit_mm``, per angle of a 6-DoF target ``dapa_limit_deg`` ...
``drpc_limit_deg``) with a ``drift`` entry from the
config's ``[iso9283_drift]`` section (:class:`station.config.DriftProgrammeConfig`):
``span_s`` (8 h), ``interval_s`` (600 s), ``cycles_per_visit`` (10) and ``poses``
(all of the cube's); overrides of those names reach it (:data:`DEFAULTS`). A
config without the section does not offer the programme.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from procedures.cell import prompt_step, robot_subject
from procedures.decision import Checks
from procedures.iso9283 import (STREAM, IsoPlan, IsoSession, _plan, _run_program, _stream_in_base, _timeout,
                                orientation_problems, plan_from_config, registered_budget, registration_of, safe_state,
                                step_check_programs, step_stop_stream)
from procedures.iso9283 import build_procedure as build_iso_procedure
from procedures.preflight import report_dir_problems, tracker_rate_problems
from procedures.registry import ProcedureSpec
from station import characteristics as table
from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.drift_programme import DRIFT_ANGLE_KEYS, drift_figures
from station.analysis.iso9283.orientation import abc_of_matrices
from station.analysis.uncertainty import Budget
from station.errors import ConfigError, DataError, StationError
from station.programs.builders import TOOL_DOWN, iso_pose_program, rated_tcp_accel_mm_s2
from station.programs.program import CartesianTarget, Dwell, Move, Program, quat_from_matrix
from station.programs.rapid import render_rapid
from station.runner import Procedure, Step, StepContext

#: the plan's drift entry: name -> default (``poses`` None: every pose of the cube)
DEFAULTS: dict[str, Any] = {"span_s": 8 * 3600.0, "interval_s": 600.0, "cycles_per_visit": 10, "poses": None}
#: the most visits a programme may have (an interval too short for its span is refused)
MAX_VISITS = 500
#: the shortest interval between two visits, s
MIN_INTERVAL_S = 60.0
#: the longest dwell of one statement (the program model's bound), s
_DWELL_MAX_S = 3600.0
RESULT = "iso9283_drift"


# --------------------------------------------------------------------------- the plan
def drift_params(params: Mapping) -> dict:
    """The drift entry of a plan, checked; ConfigError names the bad key (``iso9283_drift.interval_s``)."""
    d = _checked_numbers(params["drift"])
    poses = d["poses"]
    have = list(params["poses_mm"])
    if not isinstance(poses, (list, tuple)) or not poses or len(set(poses)) != len(poses) \
            or any(p not in have for p in poses):
        raise ConfigError(f"iso9283_drift.poses must be distinct poses of the plan ({', '.join(have)}), "
                          f"got {poses!r}")
    d["poses"] = [p for p in have if p in poses]  # in the cycle's order
    return d


def _checked_numbers(entry: Mapping) -> dict:
    """The drift entry with its span, interval and cycles checked (the poses are the plan's to check)."""
    d = dict(entry)
    if sorted(d) != sorted(DEFAULTS):
        raise ConfigError(f"iso9283_drift plan: expected {', '.join(sorted(DEFAULTS))}, got {', '.join(sorted(d))}")
    for key, lo in (("span_s", 0.0), ("interval_s", MIN_INTERVAL_S)):
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < lo or v <= 0:
            raise ConfigError(f"iso9283_drift.{key} must be a finite number of seconds >= {lo:g} (and > 0), "
                              f"got {v!r}")
    if d["interval_s"] > d["span_s"]:
        raise ConfigError(f"iso9283_drift.interval_s ({d['interval_s']:g} s) must not exceed iso9283_drift.span_s "
                          f"({d['span_s']:g} s): two visits at least")
    if n_visits(d) > MAX_VISITS:
        raise ConfigError(f"iso9283_drift.interval_s: {n_visits(d)} visits over iso9283_drift.span_s, "
                          f"at most {MAX_VISITS}")
    c = d["cycles_per_visit"]
    if isinstance(c, bool) or not isinstance(c, int) or not 2 <= c <= 100:
        raise ConfigError(f"iso9283_drift.cycles_per_visit must be an integer within 2-100, got {c!r}")
    return d


def n_visits(d: Mapping) -> int:
    """Visits of a programme: at 0, interval, 2 interval, ... up to the span."""
    return int(math.floor(float(d["span_s"]) / float(d["interval_s"]) + 1e-9)) + 1


def _iso_fields() -> set[str]:
    return {f.name for f in fields(IsoPlan)}


def subject(cfg, robot: str):
    """The configured robot; the programme is offered where the config has its ``[iso9283_drift]`` section."""
    if cfg.iso9283_drift is None:
        raise ConfigError("iso9283_drift: the config has no drift programme section ([iso9283_drift] with "
                          "span_s, interval_s, cycles_per_visit, poses)")
    return robot_subject(cfg, robot)


def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    """The ISO plan of the config with the drift entry: the config's ``[iso9283_drift]``, then the overrides
    (unknown override keys refused, named)."""
    unknown = sorted(set(overrides) - set(DEFAULTS) - _iso_fields())
    if unknown:
        raise ConfigError(f"iso9283-drift plan: unknown key(s) {', '.join(unknown)} (drift keys: "
                          f"{', '.join(DEFAULTS)})")
    subject(cfg, robot)
    section = cfg.iso9283_drift.model_dump()
    d = {k: overrides.get(k, section.get(k, v)) for k, v in DEFAULTS.items()}
    _checked_numbers(d)  # before the cube is laid out (that takes a while): a bad number is refused at once
    iso_over = {k: v for k, v in overrides.items() if k not in DEFAULTS}
    params = plan_from_config(cfg, robot, **{"report_dir": report_dir, **iso_over}).params()
    if "limits" not in iso_over:  # the robot's drift limits beside the pose test's (dAP, dRP, per angle)
        params["limits"] = {**params["limits"], **cfg.robots[robot].limits.by_characteristic("drift")}
    if d["poses"] is None:
        d["poses"] = list(params["poses_mm"])
    params["drift"] = {**d, "poses": list(d["poses"]) if isinstance(d["poses"], (list, tuple)) else d["poses"]}
    params["drift"] = drift_params(params)
    return params


# --------------------------------------------------------------------------- programs
def visit_program(plan: IsoPlan, d: Mapping, v: int, *, cycles: int | None = None, name: str | None = None):
    """Visit ``v``'s pose cycles, rendered (RAPID), named for the visit (``DRIFT_3``)."""
    poses = {p: plan.poses_mm[p] for p in d["poses"]}
    prog = iso_pose_program(plan.robot, poses, cycles=int(cycles or d["cycles_per_visit"]), dwell_s=plan.dwell_s,
                            speed_frac=plan.speed_frac, name=name or f"DRIFT_{v}",
                            title=f"ISO 9283 drift programme: visit {v}")
    return render_rapid(prog)


def wait_program(plan: IsoPlan, d: Mapping, v: int, seconds: float, name: str | None = None):
    """The arm holds at the cycle's last pose (where a visit leaves it: a move of no length, the direction of
    each joint's last motion kept) for ``seconds`` (dwells of at most an hour each), rendered."""
    first = d["poses"][0]
    hold = Move(CartesianTarget(first, tuple(plan.poses_mm[first]), quat_from_matrix(TOOL_DOWN), label=first),
                "linear", 0.2)
    chunks = [_DWELL_MAX_S] * int(seconds // _DWELL_MAX_S)
    rest = seconds - _DWELL_MAX_S * len(chunks)
    if rest > 1e-6 or not chunks:
        chunks.append(max(rest, 0.0))
    prog = Program(name=name or f"DRIFT_WAIT_{v}", robot_name=plan.robot.name,
                   rated_tcp_speed_mm_s=float(plan.robot.max_tcp_speed_mm_s),
                   statements=(hold,) + tuple(Dwell(float(s)) for s in chunks), accel_frac=0.5,
                   title=f"station: hold after drift visit {v}",
                   rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(plan.robot))
    return render_rapid(prog)


# --------------------------------------------------------------------------- steps
@dataclass
class DriftSession(IsoSession):
    """The ISO session; ``figures``: the analysis of this session (visit poses, drifts, warnings)."""

    figures: tuple | None = None


def step_check_all(ctx: StepContext) -> dict:
    """The pose test's programs and a visit's through the safety gate."""
    out = step_check_programs(ctx)
    plan, d = _plan(ctx), drift_params(ctx.params)
    rep = ctx.session.gate.check_program(visit_program(plan, d, 1).program, q_start=None)
    out["programs"]["drift visit"] = {"moves": int(rep.q_rad.shape[0]),
                                      "peak_tcp_speed_mm_s": float(rep.peak_tcp_speed_mm_s)}
    return out


def _visit_seconds(plan: IsoPlan, d: Mapping) -> float:
    """A generous bound of a visit's simulated duration (for the program's timeout)."""
    return float(d["cycles_per_visit"]) * len(d["poses"]) * 2.0 * (plan.dwell_s + 2.0) + 60.0


def step_visit(v: int):
    def run(ctx: StepContext) -> dict:
        plan, d = _plan(ctx), drift_params(ctx.params)
        timeout_s = _timeout(ctx, _visit_seconds(plan, d))
        before = "register base frame" if v == 1 else f"wait {v - 1}"
        entered = None
        if ctx.session.moved_by != before:
            # a new session (a resume): one cycle unmeasured first, so the visit starts as an uninterrupted one
            _run_program(ctx, visit_program(plan, d, v, cycles=1, name=f"DRIFT_ENTRY_{v}"), timeout_s=timeout_s,
                         stream=False)
            entered = f"after {ctx.session.moved_by}"
        ctx.session.moved_by = ctx.step.name
        out = _run_program(ctx, visit_program(plan, d, v), timeout_s=timeout_s, stream=True)
        stopped = step_stop_stream(ctx)
        return {**out, "stream": stopped, "entered_again": entered}
    return run


def _visit_times(ctx: StepContext, v: int) -> tuple[float, float]:
    """(first, last) device time of visit ``v``'s samples, s."""
    t = ctx.samples(STREAM, steps=[f"visit {v}"]).get("t")
    if t is None or not t.size:
        raise DataError(f"visit {v}: no tracker samples stored")
    t = t[np.isfinite(t)]
    return float(t.min()), float(t.max())


#: the end of a wait is measured: the tracker streams the held arm this long, s (the device time of the wait's
#: end, stored; a fake cell started again to resume goes on from the last stored sample)
HELD_S = 0.5


def _last_device_time(ctx: StepContext, v: int) -> float:
    """The latest device time stored by visit ``v`` or by any attempt of this wait (its measured end), s."""
    by_name = {s.name: i for i, s in enumerate(ctx.runner.procedure.steps)}
    t = ctx.store.samples(ctx.run_id, STREAM, finished_only=False, steps=[by_name[f"visit {v}"], ctx.idx]).get("t")
    t = np.asarray([] if t is None else t, dtype=float)
    t = t[np.isfinite(t)]
    if not t.size:
        raise DataError(f"visit {v}: no tracker samples stored")
    return float(t.max())


def step_wait(v: int):
    def run(ctx: StepContext) -> dict:
        plan, d = _plan(ctx), drift_params(ctx.params)
        t_start, _ = _visit_times(ctx, 1)
        now = _last_device_time(ctx, v)
        target = t_start + v * float(d["interval_s"])
        hold = target - now
        out = {"target_since_start_s": round(target - t_start, 3), "from_since_start_s": round(now - t_start, 3)}
        if hold <= 0:  # the visit took longer than the interval (or this wait ended before a kill): go on at once
            return {**out, "held_s": 0.0, "late_s": round(max(-hold - HELD_S, 0.0), 3)}
        if hold > HELD_S:
            _run_program(ctx, wait_program(plan, d, v, hold - HELD_S), timeout_s=_timeout(ctx, hold + 60.0),
                         stream=False)
        # the wait's last moments measured: the device time of its end is stored with the run
        _run_program(ctx, wait_program(plan, d, v, min(hold, HELD_S), name=f"DRIFT_HELD_{v}"),
                     timeout_s=_timeout(ctx, 60.0), stream=True)
        held = step_stop_stream(ctx)
        if ctx.session.moved_by == f"visit {v}":  # the arm stands as the visit left it (a dwell does not move it)
            ctx.session.moved_by = ctx.step.name
        return {**out, "held_s": round(hold, 3), "late_s": 0.0, "stream": held}
    return run


def budget_of(plan: IsoPlan, outputs: Mapping) -> tuple[Budget, str]:
    """The uncertainty's inputs (the config's budget, else the default one, said so) through the run's frame."""
    reg_out = outputs["register base frame"]
    kw = dict(plan.uncertainty) if plan.uncertainty is not None else {}
    if plan.orientation:
        kw["angle_sd_deg"] = plan.angle_sd_deg
    budget = registered_budget(plan, Budget(**kw, rate_hz=plan.tracker_rate_hz), registration_of(outputs),
                               reg_out.get("uncertainty_at_poses_mm"), reg_out.get("rotation_cov_deg2"))
    return budget, "config" if plan.uncertainty is not None else "default (no [uncertainty] in the config)"


def visit_stops(plan: IsoPlan, d: Mapping, t, xyz, abc_rad=None) -> dict[str, tuple]:
    """``{pose: (attained_mm, attained_t_s)}`` of one visit's stream (base frame): the pose test's extraction;
    with the samples' angles ``abc_rad`` (N, 3) of a 6-DoF target, ``(attained_mm, attained_t_s, the attained
    stops' angles (n, 3), rad)``."""
    names = list(d["poses"])
    cmd = np.array([plan.poses_mm[p] for p in names])
    res = analyze_iso9283(t, xyz, cmd, names=names, limits={}, band_mm=plan.band_mm, distance_pairs=None,
                          mpt_repeats=min(3, int(d["cycles_per_visit"])),
                          **({} if abc_rad is None else {"orientation_rad": abc_rad}))
    out = {}
    for p, pr in res.poses.items():
        if not pr.n_cycles:
            continue
        o = pr.orientation
        if abc_rad is None:
            out[p] = (pr.attained_mm, pr.attained_t_s)
        elif o is None:  # a single stop: no orientation figures, its angles still known
            out[p] = (pr.attained_mm, pr.attained_t_s, None)
        else:
            out[p] = (pr.attained_mm, pr.attained_t_s, np.asarray(abc_rad)[o.rows])
    return out


def analyse_run(plan: IsoPlan, d: Mapping, streams: list, outputs: Mapping):
    """The drift figures of the visits' streams (``[(t, xyz, abc_rad or None)]`` per finished visit, base
    frame; the angles of a 6-DoF target give the orientation's drift against the programs' tool down)."""
    t_start = float(streams[0][0].min())
    stops = [visit_stops(plan, d, t, xyz, abc) for t, xyz, abc in streams]
    budget, source = budget_of(plan, outputs)
    cmd = {p: plan.poses_mm[p] for p in d["poses"]}
    oriented = all(abc is not None for _, _, abc in streams)
    cabc = {p: abc_of_matrices(TOOL_DOWN)[0] for p in d["poses"]} if oriented else None
    visits, drifts, warnings = drift_figures(stops, cmd, t_start, budget, cabc)
    starts = [float(t.min()) - t_start for t, _, _ in streams]  # each visit's first sample since the start
    return visits, drifts, warnings, source, t_start, starts


def _streams(ctx: StepContext, d: Mapping) -> list:
    done = set(ctx.outputs)
    out = []
    for v in range(1, n_visits(d) + 1):
        if f"visit {v}" in done:
            b = _stream_in_base(ctx, [f"visit {v}"])
            out.append((b.t, b.xyz, b.abc))
    if not out:
        raise DataError("no finished visit: nothing to analyse")
    return out


def characteristic_rows(plan: IsoPlan, drifts: Mapping) -> list[dict]:
    """One row per pose and drift figure of the table (programme ``drift``), judged against the config's limits;
    the orientation's rows where the visits measured the tool's angles (a 6-DoF target)."""
    rows = []
    oriented = any(pd.orientation is not None for pd in drifts.values())
    for pose, pd in drifts.items():
        for c in table.characteristics("drift"):
            if c.with_orientation and not oriented:
                continue
            value = c.value(pd)
            lim = plan.limits.get(c.key)
            rows.append({"pose": pose, "name": c.key, "value": value, "unit": c.unit, "limit": lim,
                         "passed": None if lim is None or value is None else bool(value <= lim)})
    return rows


def _analysis(ctx: StepContext):
    if ctx.session.figures is None:
        plan, d = _plan(ctx), drift_params(ctx.params)
        ctx.session.figures = analyse_run(plan, d, _streams(ctx, d), ctx.outputs)
    return ctx.session.figures


def step_analyse(ctx: StepContext) -> dict:
    plan, d = _plan(ctx), drift_params(ctx.params)
    visits, drifts, warnings, source, t_start, starts = _analysis(ctx)
    rows = characteristic_rows(plan, drifts)
    ctx.store.put_characteristics(ctx.run_id, rows)
    waits = {k: v for k, v in ctx.outputs.items() if k.startswith("wait ")}
    late = {k: v["late_s"] for k, v in waits.items() if v.get("late_s")}
    if late:
        warnings = warnings + [f"{k}: the visit before took longer than the interval; the next one started "
                               f"{s:.0f} s late" for k, s in late.items()]
    # a visit measured before its time rests on a clock that went back (a device restarted): said, not decided
    early = [f"visit {v}: started {since:.0f} s after the start, planned at {(v - 1) * float(d['interval_s']):.0f} s: "
             f"the device clock went back" for v, since in enumerate(starts, start=1)
             if since < (v - 1) * float(d["interval_s"]) - 1.0]
    ctx.store.put_result(ctx.run_id, RESULT, {
        "early": early, "programme": "drift", "span_s": d["span_s"], "interval_s": d["interval_s"],
        "cycles_per_visit": d["cycles_per_visit"], "visits_planned": n_visits(d),
        "visits_analysed": len({vp.visit for vp in visits}), "t_start_device_s": t_start,
        "visit_starts_since_start_s": [round(x, 3) for x in starts],
        "budget": source, "visits": [vp.to_dict() for vp in visits],
        "drift": {p: pd.to_dict() for p, pd in drifts.items()}, "warnings": warnings})
    return {"n_rows": len(rows), "warnings": warnings}


def step_report(ctx: StepContext) -> dict:
    from station.report import Report, plot_xy, write_report

    plan, d = _plan(ctx), drift_params(ctx.params)
    visits, drifts, warnings, source, _, _ = _analysis(ctx)
    run = ctx.store.run(ctx.run_id)
    res = ctx.store.result(ctx.run_id, RESULT)
    rep = Report(title=f"ISO 9283 drift of pose characteristics - {run.model} {run.serial}",
                 facts={"run": ctx.run_id,
                        "programme": f"{res['visits_analysed']} of {n_visits(d)} visits of {d['cycles_per_visit']} "
                                     f"pose cycles, every {d['interval_s']:g} s over {d['span_s'] / 3600:.3g} h "
                                     f"from a cold start",
                        "poses": ", ".join(d["poses"]),
                        "uncertainty": f"U = 2 u; budget: {source}; dAP's frame error common to both visits"},
                 rows=ctx.store.characteristics(ctx.run_id))
    for key, label in (("AP_mm", "AP"), ("RP_mm", "RP")):
        series = []
        for pose in d["poses"]:
            vs = [vp for vp in visits if vp.pose == pose and getattr(vp, key) is not None]
            if vs:
                series.append((pose, np.array([vp.t_since_start_s / 3600.0 for vp in vs]),
                               np.array([getattr(vp, key) for vp in vs]), "-"))
        rep.figures.append((f"{label} against the time since the cold start",
                            plot_xy(series, xlabel="time since the cold start [h]", ylabel=f"{label} [mm]",
                                    title=f"{label}(t) per pose")))
    for j, ax in enumerate("abc"):  # the orientation's AP per angle, with a 6-DoF target
        key = f"AP{ax}_deg"
        series = []
        for pose in d["poses"]:
            vs = [vp for vp in visits if vp.pose == pose and (vp.orientation or {}).get(key) is not None]
            if vs:
                series.append((pose, np.array([vp.t_since_start_s / 3600.0 for vp in vs]),
                               np.array([vp.orientation[key] for vp in vs]), "-"))
        if series:
            rep.figures.append((f"AP{ax} against the time since the cold start",
                                plot_xy(series, xlabel="time since the cold start [h]", ylabel=f"AP{ax} [deg]",
                                        title=f"AP{ax}(t) per pose (orientation, angle {ax})")))
    rep.notes += [f"{p}: dAP = {pd.dAP_mm * 1000:.1f} um (U {_um(pd.U_dAP_mm)}), dRP = {_um(pd.dRP_mm)} "
                  f"(U {_um(pd.U_dRP_mm)}), shift of the barycentre {pd.shift_mm * 1000:.1f} um, visits "
                  f"{pd.first_visit}-{pd.last_visit} over {pd.span_s / 3600:.2f} h" for p, pd in drifts.items()]
    rep.notes += [f"{p}: " + ", ".join(f"{k[:-4]} = {pd.orientation[k]:.4f} deg (U {_deg(pd.orientation[f'U_{k}'])})"
                                       for k in DRIFT_ANGLE_KEYS)
                  for p, pd in drifts.items() if pd.orientation is not None]
    rep.notes += warnings
    path = write_report(rep, Path(plan.report_dir) / f"{ctx.run_id}.html")
    out = {"report": str(path.resolve())}
    ctx.store.put_result(ctx.run_id, RESULT, {**res, **out})
    return out


def _um(x) -> str:
    return "-" if x is None else f"{x * 1000:.1f} um"


def _deg(x) -> str:
    return "-" if x is None else f"{x:.4f} deg"


def build_procedure(params: Mapping) -> Procedure:
    d = drift_params(params)
    V = n_visits(d)
    # the pose test's own steps up to its registration (prompts, connect, home, register), its check widened
    iso = build_iso_procedure(IsoPlan.from_params(params)).steps
    upto = [s.name for s in iso].index("register base frame")
    steps = [Step("check programs", step_check_all, every_session=True)] + [s for s in iso[: upto + 1]
                                                                          if s.name != "check programs"]
    steps += [
        Step("cold start", prompt_step("The arm starts cold (switched off or at rest until at room temperature): "
                                       "the drift programme's time counts from its first visit")),
    ]
    for v in range(1, V + 1):
        steps.append(Step(f"visit {v}", step_visit(v), label=f"{v}/{V}"))
        if v < V:
            steps.append(Step(f"wait {v}", step_wait(v), label=f"{v}/{V - 1}"))
    steps += [Step("analyse", step_analyse, offline=True), Step("report", step_report, offline=True)]
    return Procedure("iso9283-drift", steps, safe_state=safe_state)


# --------------------------------------------------------------------------- the registry's entry
def device_roles(cfg, robot: str) -> dict[str, str]:
    subject(cfg, robot)
    return {"tracker": "tracker", "controller": cfg.robots[robot].controller}


def summary(store, run_id: str) -> list[str]:
    try:
        res = store.result(run_id, RESULT)
    except Exception:  # noqa: BLE001 - nothing analysed yet
        return []
    lines = [f"{res['visits_analysed']} of {res['visits_planned']} visits, every {res['interval_s']:g} s",
             f"{'pose':<6}{'dAP mm':>10}{'U mm':>9}{'dRP mm':>10}{'U mm':>9}{'shift mm':>10}"]

    def f(x, w):
        return f"{'-':>{w}}" if x is None else f"{x:>{w}.4f}"

    for p, r in res["drift"].items():
        lines.append(f"{p:<6}{f(r['dAP_mm'], 10)}{f(r['U_dAP_mm'], 9)}{f(r['dRP_mm'], 10)}{f(r['U_dRP_mm'], 9)}"
                     f"{f(r['shift_mm'], 10)}")
    oriented = [(p, r) for p, r in res["drift"].items() if r.get("dAPa_deg") is not None]
    if oriented:
        lines.append(f"{'pose':<6}" + "".join(f"{k[:-4] + ' deg':>11}{'U':>8}" for k in DRIFT_ANGLE_KEYS))
        for p, r in oriented:
            lines.append(f"{p:<6}" + "".join(f"{f(r[k], 11)}{f(r.get(f'U_{k}'), 8)}" for k in DRIFT_ANGLE_KEYS))
    if res.get("report"):
        lines.append(f"report: {res['report']}")
    return lines


def run_checks(store, run_id: str, params: Mapping) -> Checks:
    """Visits analysed against planned, configured limits not computed; the U of each judged row."""
    undecided = []
    try:
        res = store.result(run_id, RESULT)
    except Exception:  # noqa: BLE001 - no analysis stored
        return Checks(("no drift analysis stored",))
    if res["visits_analysed"] < res["visits_planned"]:
        undecided.append(f"{res['visits_analysed']} of {res['visits_planned']} visits analysed")
    undecided += res.get("early") or []
    rows = store.characteristics(run_id)
    judged = {r["name"] for r in rows if r["limit"] is not None and r["value"] is not None}
    for c in table.characteristics("drift"):
        lim = (params.get("limits") or {}).get(c.key)
        if lim is not None and c.limit_key is not None and c.key not in judged:
            why = " (orientation needs a 6-DoF target)" if c.with_orientation else ""
            undecided.append(f"limit {c.key} <= {lim:g} configured, but {c.key} was not computed{why}")
    U = {}
    for p, r in res["drift"].items():
        for name in ("dAP_mm", "dRP_mm") + DRIFT_ANGLE_KEYS:
            if r.get(f"U_{name}") is not None:
                U[(p, name)] = r[f"U_{name}"]
    return Checks(tuple(undecided), None, (), U)


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    problems = report_dir_problems(params.get("report_dir", "reports"))
    try:
        d = drift_params(params)
    except StationError as exc:
        return problems + [str(exc)]
    plan = IsoPlan.from_params(params)
    problems += tracker_rate_problems(devices, plan.tracker_rate_hz, field="iso9283.tracker_rate_hz")
    problems += orientation_problems(plan, devices, programme="drift")
    try:
        plan.gate().check_program(visit_program(plan, d, 1).program, q_start=None)
    except StationError as exc:
        problems.append(f"drift visit program: {exc}")
    return problems


SPEC = ProcedureSpec(
    name="iso9283-drift",
    new_params=new_params,
    build=build_procedure,
    new_session=lambda devices: DriftSession(devices),
    subject=subject,
    device_roles=device_roles,
    fake_cell="fakes.cells:iso9283_cell",
    result_key=RESULT,
    summary=summary,
    preflight=preflight_problems,
    checks=run_checks,
)
