"""The trailer calibration (seed 003) as a journaled, resumable runner procedure.

The step functions are those of :mod:`procedures.trailer`; this module gives
them what the runner provides: samples go to the run store as they are taken
(``ctx.record``), the odometry link is opened in every session, and a resumed
run rebuilds the record of its finished commands from the store before it
goes on (a command interrupted half-way is driven again from its start). The
trailer is stopped after a failure or an abort.

Steps: ``check plan`` (eq. (25) and the 45 deg limit for the nominal lengths,
before anything moves), ``connect odometry``, ``start driving`` (again after
a resume), ``command k/n: KIND M=..`` (settle, then the H/C/L profile of
para. [0127]), ``stop``, ``estimate``, ``report``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from procedures import trailer as tp
from procedures.preflight import report_dir_problems
from procedures.registry import ProcedureSpec, Subject
from procedures.session import Session
from station.errors import ConfigError, StationError
from station.runner import Procedure, Step, StepContext


def plan_params(plan: tp.TrailerCalibrationPlan) -> dict:
    d = dataclasses.asdict(plan)
    d["commands"] = [[k, float(m)] for k, m in plan.commands]
    d["compare"] = list(plan.compare)
    return d


def plan_from_params(p: dict) -> tp.TrailerCalibrationPlan:
    kw = {f.name: p[f.name] for f in dataclasses.fields(tp.TrailerCalibrationPlan) if f.name in p}
    kw["commands"] = tuple((k, float(m)) for k, m in kw.get("commands", ()))
    kw["compare"] = tuple(kw.get("compare", ()))
    return tp.TrailerCalibrationPlan(**kw)


@dataclass
class TrailerSession(Session):
    """What the trailer steps share within one session."""

    odometry: Any = None
    trailer_ctx: tp.TrailerCalibrationContext | None = None


def _tc(ctx: StepContext) -> tp.TrailerCalibrationContext:
    """The procedure's shared context, rebuilt from the store in a new session."""
    session: TrailerSession = ctx.session
    tc = session.trailer_ctx
    if tc is None:
        tc = tp.TrailerCalibrationContext(driver=None, plan=plan_from_params(ctx.params["plan"]))
        done = ctx.samples("odometry")
        if done:
            for c in tp.COLUMNS:
                tc.samples[c] = list(done[c])
        sp = ctx.samples("setpoints")
        if sp:
            tc.setpoints = [
                (SimpleNamespace(value=float(v), t_applied_s=None if math.isnan(ta) else float(ta)), float(ti))
                for v, ta, ti in zip(sp["value"], sp["t_applied"], sp["t_intended"])
            ]
        session.trailer_ctx = tc
    tc.driver = session.odometry
    tc.record = ctx.record
    tc.checkpoint = ctx.checkpoint
    return tc


def _connect(ctx: StepContext) -> dict:
    session: TrailerSession = ctx.session
    drv = session.odometry = session.device("odometry")
    # whatever an earlier session left running: stand still first
    t_v = drv.command_speed(0.0)
    return {"device": session.devices.describe("odometry"), "t_stopped_s": t_v}


def _wrap(fn):
    def run(ctx: StepContext):
        ctx.checkpoint()
        return fn(_tc(ctx))
    return run


def _command(i: int):
    def run(ctx: StepContext):
        ctx.checkpoint()
        tc = _tc(ctx)
        ctx.progress(f"{tc.plan.commands[i][0]} M={tc.plan.commands[i][1]:g}")
        return tp.run_command(tc, i)
    return run


def continuous_pieces(t_s: np.ndarray, gap_factor: float = 5.0) -> list[slice]:
    """Slices of ``t_s`` without a time step longer than ``gap_factor`` x the median step."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 3:
        return [slice(0, t.size)]
    dt = np.diff(t)
    cut = np.flatnonzero(dt > gap_factor * np.median(dt)) + 1
    edges = np.concatenate([[0], cut, [t.size]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def combine_estimates(method: str, parts: list) -> "tp.TrailerEstimate":
    """Inverse-covariance combination of independent estimates of (L1, L2)."""
    from station.analysis.trailer_ls import TrailerEstimate

    info = np.zeros((2, 2))
    acc = np.zeros(2)
    for e in parts:
        c = e.L1_L2_corr * e.L1_sigma_m * e.L2_sigma_m
        cov = np.array([[e.L1_sigma_m**2, c], [c, e.L2_sigma_m**2]])
        w = np.linalg.inv(cov)
        info += w
        acc += w @ np.array([e.L1_m, e.L2_m])
    cov = np.linalg.inv(info)
    L = cov @ acc
    s1, s2 = np.sqrt(np.diag(cov))
    return TrailerEstimate(
        method, float(L[0]), float(L[1]), float(s1), float(s2), float(cov[0, 1] / (s1 * s2)),
        float(max(e.condition_number for e in parts)), int(sum(e.n_samples for e in parts)),
        {"pieces": [e.to_json() for e in parts]},
        (f"the record has {len(parts)} continuous pieces (a resumed run): {method} estimated per piece "
         f"and combined by inverse covariance",),
    )


def _estimate(ctx: StepContext) -> dict:
    """Step 5, with a resumed run's record split where the trailer stood still between sessions."""
    from station.analysis.trailer_estimate import estimate_trailer

    tc = _tc(ctx)
    data = tc.arrays()
    pieces = continuous_pieces(data["t"])
    if len(pieces) == 1:
        return tp.estimate(tc)
    for name in (tc.plan.method, *tc.plan.compare):
        if name in tc.estimates:
            continue
        try:
            if name == "dynamic":
                parts = [estimate_trailer({k: v[sl] for k, v in data.items()}, name) for sl in pieces]
                tc.estimates[name] = combine_estimates(name, parts)
            else:
                tc.estimates[name] = estimate_trailer(data, name)
        except StationError as exc:
            if name == tc.plan.method:
                raise
            tc.errors[name] = str(exc)
    return {name: est.to_json() for name, est in tc.estimates.items()}


def length_rows(method: str, L1_m, L2_m, nominal_L1_m, nominal_L2_m, tol_m: float | None) -> list[dict]:
    """|L - nominal| of both links of the run's estimate, judged against ``trailer.length_tolerance_m``."""
    rows = []
    for name, est, nom in (("L1_error_m", L1_m, nominal_L1_m), ("L2_error_m", L2_m, nominal_L2_m)):
        value = None if est is None or not np.isfinite(est) else abs(float(est) - float(nom))
        passed = None if (tol_m is None or value is None) else bool(value <= tol_m)
        rows.append({"pose": method, "name": name, "value": value, "unit": "m", "limit": tol_m, "passed": passed})
    return rows


def _report(ctx: StepContext) -> dict:
    from station.report import Report, plot_xy, write_report

    tc = _tc(ctx)
    out = tp.report(tc)
    data = tc.arrays()
    rows = []
    for name, est in tc.estimates.items():
        j = est.to_json()
        for key in ("L1_m", "L2_m"):
            rows.append({"pose": name, "name": key, "value": j[key], "unit": "m", "limit": None, "passed": None})
            rows.append({"pose": name, "name": key.replace("_m", "_sigma_m"), "value": j[f"{key[:2]}_sigma_m"],
                         "unit": "m", "limit": None, "passed": None})
    main = tc.estimates[tc.plan.method]
    tol = ((ctx.store.run(ctx.run_id).config.get("trailer") or {}).get("length_tolerance_m"))
    rows += length_rows(tc.plan.method, main.L1_m, main.L2_m, tc.plan.nominal_L1_m, tc.plan.nominal_L2_m, tol)
    ctx.store.put_characteristics(ctx.run_id, rows)
    k = np.linspace(np.nanmin(data["kappa"]), np.nanmax(data["kappa"]), 200)
    # steady state of eq. (23) for the estimated lengths: sin psi = kappa (L2 + L1 cos psi)
    L1, L2 = main.L1_m, main.L2_m
    psi = _steady_psi(k, L1, L2)
    figs = [("Joint angle against curvature: measurements and the steady state of eq. (23) for the estimated lengths",
             plot_xy([("measured", data["kappa"], np.degrees(data["psi"]), "."),
                      (f"eq. (23), L1={L1:.3f} m, L2={L2:.3f} m", k, np.degrees(psi), "-")],
                     xlabel="curvature [1/m]", ylabel="joint angle [deg]", title="psi vs kappa"))]
    run = ctx.store.run(ctx.run_id)
    report = Report(
        title=f"Trailer calibration {ctx.run_id}",
        facts={"trailer": f"serial {run.serial}", "method": tc.plan.method,
               "commands": ", ".join(f"{kd} M={m:g}" for kd, m in tc.plan.commands),
               "samples": str(out["n_samples"]),
               "nominal L1, L2": f"{tc.plan.nominal_L1_m} m, {tc.plan.nominal_L2_m} m"},
        rows=rows, figures=figs, notes=list(main.to_json().get("warnings", [])))
    path = write_report(report, Path(ctx.params.get("report_dir", "reports")) / f"{ctx.run_id}.html")
    out = dict(out)
    out["report"] = str(path.resolve())
    ctx.store.put_result(ctx.run_id, "trailer", out)
    return out


def _steady_psi(kappa: np.ndarray, L1: float, L2: float) -> np.ndarray:
    """Stable root of eq. (23), sin psi = kappa (L2 + L1 cos psi), NaN beyond eq. (25)."""
    # a sin + b cos = c with a = 1, b = -kappa L1, c = kappa L2
    b = -kappa * L1
    c = kappa * L2
    r = np.sqrt(1 + b**2)
    with np.errstate(invalid="ignore"):
        return np.arcsin(c / r) - np.arctan2(b, 1.0)


def safe_state(session: TrailerSession) -> None:
    drv = session.odometry
    if drv is not None:
        try:
            drv.command_speed(0.0)
        except StationError as exc:
            raise StationError(f"could not stop the trailer: {exc}") from exc


def build_procedure(plan: tp.TrailerCalibrationPlan) -> Procedure:
    steps = [
        Step("check plan", _wrap(tp.check_plan), every_session=True),
        Step("connect odometry", _connect, every_session=True),
        Step("start driving", _wrap(tp.start_driving), every_session=True),
    ]
    for i, (kind, M) in enumerate(plan.commands):
        steps.append(Step(f"command {i + 1}/{len(plan.commands)}: {kind} M={M:g}", _command(i)))
    steps += [Step("stop", _wrap(tp.stop)), Step("estimate", _estimate), Step("report", _report)]
    return Procedure("trailer", steps, safe_state=safe_state)


# ----------------------------------------------------------------------------- the registry entry
def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    """The stored plan of a new run, from the config's [trailer] section."""
    tc = _trailer_section(cfg)
    kw = dict(commands=tuple((k, float(m)) for k, m in tc.commands), duration_s=tc.duration_s,
              settle_s=tc.settle_s, v_m_s=tc.v_m_s, nominal_L1_m=tc.nominal_L1_m, nominal_L2_m=tc.nominal_L2_m,
              method=tc.method)
    kw.update(overrides)
    return {"plan": plan_params(tp.TrailerCalibrationPlan(**kw)), "report_dir": report_dir}


def _trailer_section(cfg):
    if cfg.trailer is None:
        raise ConfigError("trailer: the config has no [trailer] section (odometry device, nominal lengths)")
    return cfg.trailer


def subject(cfg, robot: str) -> Subject:
    tc = _trailer_section(cfg)
    return Subject("trailer", tc.serial, None, f"the trailer (serial {tc.serial})")


def device_roles(cfg, robot: str) -> dict[str, str]:
    return {"odometry": _trailer_section(cfg).odometry}


def summary(store, run_id: str) -> list[str]:
    """The estimates (chosen method first, then the comparisons) and the report, as console lines."""
    res = store.result(run_id, "trailer")
    rows = [res["result"]] + list(res["comparisons"].values())

    def f(v, w, d):
        return f"{v:>{w}.{d}f}" if v is not None else f"{'-':>{w}}"

    lines = [f"{'method':<10}{'L1 m':>10}{'+-':>8}{'L2 m':>10}{'+-':>8}{'cond':>10}"]
    for r in rows:
        lines.append(f"{r['method']:<10}{f(r['L1_m'], 10, 4)}{f(r['L1_sigma_m'], 8, 4)}{f(r['L2_m'], 10, 4)}"
                     f"{f(r['L2_sigma_m'], 8, 4)}{f(r['condition_number'], 10, 1)}")
    lines.append(f"report: {res['report']}")
    return lines


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    """The plan against eq. (25), the 45 deg joint-angle limit and the report folder."""
    problems = report_dir_problems(params.get("report_dir", "reports"))
    try:
        tp.check_plan(tp.TrailerCalibrationContext(driver=None, plan=plan_from_params(params["plan"])))
    except StationError as exc:
        problems.append(f"trailer plan: {exc}")
    return problems


SPEC = ProcedureSpec(
    name="trailer",
    new_params=new_params,
    build=lambda params: build_procedure(plan_from_params(params["plan"])),
    new_session=lambda devices: TrailerSession(devices),
    subject=subject,
    device_roles=device_roles,
    fake_cell="fakes.cells:trailer_cell",
    result_key="trailer",
    summary=summary,
    preflight=preflight_problems,
)
