"""Trailer link-length calibration (seed 003): the plan, the steps, and the procedure's registry entry.

Steps, journaled and resumable like every procedure's (``step(ctx) -> dict``,
JSON-able output; ``ctx`` the runner's :class:`~station.runner.StepContext`,
``ctx.session`` a :class:`TrailerSession`):

1. ``check plan`` — every command of the plan (H, C, L of para. [0127] with
   amplitude M) is checked against the jackknife bound of eq. (25) and the
   45 deg joint-angle limit for the nominal lengths, and the speed against
   its limit, before anything moves;
2. ``connect odometry`` — the link opened in every session, the trailer
   stood still first (whatever an earlier session left running);
3. ``start driving`` — curvature set to the first command's start value,
   then the speed (again after a resume);
4. ``command k/n`` — hold the command's start curvature for ``settle_s``
   (the joint angle settles), then stream the profile as curvature set
   points, one per control tick after the newest sample (the jump to the
   start value is ramped at ``curvature_rate``), recording every sample
   (device time, speed, curvature, joint angle, the set point in force,
   segment and phase);
5. ``stop`` — speed 0, curvature 0;
6. ``estimate`` — link lengths by the chosen method (default ``dynamic``) and
   by the comparison methods; a resumed run's record is estimated per
   continuous piece and combined;
7. ``report`` — the HTML report and the stored result.

Samples go to the run store as they are taken (``ctx.record``), and
``ctx.checkpoint()`` is called before every sample read, so a pause or abort
takes effect inside a command that streams for a minute. A new session (a
resume) rebuilds the record of its finished commands from the store before
it goes on; a command interrupted half-way is driven again from its start.
The trailer is stopped after a failure or an abort.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from procedures.preflight import report_dir_problems
from procedures.registry import ProcedureSpec, Subject
from procedures.session import Session
from procedures.live_views import odometry_view
from procedures.plan_params import plan_from_params, plan_params
from station.analysis.trailer.estimate import estimate_trailer
from station.analysis.trailer.setpoints import interval_average, place_unacknowledged
from station.errors import ConfigError, StationError
from station.models.trailer import (
    ESTIMATORS, COMMAND_KINDS, COMMAND_OMEGA_RAD_S, DEFAULT_L1_M, DEFAULT_L2_M, check_curvature_command,
    check_lengths, command_curvature,
)
from station.runner import Procedure, Step, StepContext

#: speed limit of the plan, m/s
MAX_PLAN_SPEED_M_S = 3.0
COLUMNS = ("t", "v", "kappa", "psi", "kappa_set", "segment", "phase")


@dataclass(frozen=True)
class TrailerCalibrationPlan:
    """What the procedure drives and how it estimates.

    Parameters
    ----------
    commands : tuple of (kind, M)
        Command kinds ``"H"``, ``"C"``, ``"L"`` and amplitudes, 1/m.
    duration_s, settle_s : float
        Profile length (seed: 63 s) and the hold before it.
    v_m_s : float
        Driving speed.
    nominal_L1_m, nominal_L2_m : float
        Design lengths, for the checks of step 1.
    method : str
        ``"M1"``..``"M24"``, ``"odr"`` or ``"dynamic"``.
    compare : tuple of str
        Further methods reported alongside.
    sample_timeout_s : float
        Longest wait for one odometry sample.
    omega_rad_s : float
        Rate of the command signals (seed: 0.1 rad/s).
    curvature_rate : float
        Largest change of the curvature set point while settling, 1/(m s):
        the jumps between commands are ramped (steps of curvature between
        two samples would bias the dynamic estimate).
    """

    commands: tuple = (("H", 0.2), ("C", 0.2), ("L", 0.2))
    duration_s: float = 63.0
    settle_s: float = 20.0
    v_m_s: float = 1.0
    nominal_L1_m: float = DEFAULT_L1_M
    nominal_L2_m: float = DEFAULT_L2_M
    method: str = "dynamic"
    compare: tuple = ("M17", "M21")
    sample_timeout_s: float = 2.0
    omega_rad_s: float = COMMAND_OMEGA_RAD_S
    curvature_rate: float = 0.1

    def __post_init__(self) -> None:
        if not self.commands:
            raise ConfigError("plan.commands must list at least one (kind, M)")
        for i, item in enumerate(self.commands):
            if not (isinstance(item, (tuple, list)) and len(item) == 2):
                raise ConfigError(f"plan.commands[{i}] must be (kind, M), got {item!r}")
            kind, M = item
            if kind not in COMMAND_KINDS:
                raise ConfigError(f"plan.commands[{i}] kind must be one of {COMMAND_KINDS}, got {kind!r}")
            if not (isinstance(M, (int, float)) and math.isfinite(M) and M != 0):
                raise ConfigError(f"plan.commands[{i}] amplitude M must be a non-zero number, got {M!r}")
        for name in ("duration_s", "sample_timeout_s", "omega_rad_s", "curvature_rate"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"plan.{name} must be a number > 0, got {value!r}")
        if not (isinstance(self.settle_s, (int, float)) and 0 <= self.settle_s < 1e5):
            raise ConfigError(f"plan.settle_s must be >= 0, got {self.settle_s!r}")
        if not (isinstance(self.v_m_s, (int, float)) and 0 < self.v_m_s <= MAX_PLAN_SPEED_M_S):
            raise ConfigError(f"plan.v_m_s must be in (0, {MAX_PLAN_SPEED_M_S}] m/s, got {self.v_m_s!r}")
        try:
            check_lengths(self.nominal_L1_m, self.nominal_L2_m)
        except ConfigError as exc:
            raise ConfigError(f"plan nominal lengths: {exc}") from exc
        for name in (self.method, *self.compare):
            if name not in ESTIMATORS:
                raise ConfigError(f"plan method {name!r} unknown; use one of M1..M24, odr, dynamic")


@dataclass(frozen=True)
class SetPoint:
    """A curvature set point: its value and the device time it was applied (None: its acknowledgement
    was lost on the line). The driver's own sent commands have the same two attributes."""

    value: float
    t_applied_s: float | None


@dataclass
class TrailerSession(Session):
    """What the trailer steps share within one session: the odometry link and the run's record.

    ``samples`` (``COLUMNS`` -> list) and ``setpoints`` (``[(set point,
    intended apply time)]``, send order) are rebuilt from the store when a
    new session starts (:func:`_record`); ``estimates`` and ``errors`` are
    the estimate step's.
    """

    odometry: Any = None
    plan: TrailerCalibrationPlan | None = None
    samples: dict | None = None
    setpoints: list = field(default_factory=list)
    estimates: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    kappa_cmd: float = 0.0
    max_steady_psi_rad: float = 0.0

    def setpoint_timeline(self, t_end: float = -np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t_latest, t_earliest, value, acknowledged)`` of every curvature set point, device time, in send
        order: the bracket in which each took effect.

        An acknowledged set point's bracket is its acknowledged tick. Set points
        take effect in the order sent, so one whose acknowledgement was lost took
        effect no later than the next acknowledged one; after the last
        acknowledgement, no later than the end of the record ``t_end`` (or its
        intended tick, if later). Its intended tick (the tick after the newest
        sample the procedure had read) is the earliest: the unit runs ahead of
        what the procedure has read. :meth:`arrays` places it inside the bracket
        by the measured curvature.
        """
        if not self.setpoints:
            return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool)
        acked = np.array([np.inf if getattr(sp, "t_applied_s", None) is None else sp.t_applied_s
                          for sp, _ in self.setpoints], dtype=float)
        intended = np.array([ti for _, ti in self.setpoints], dtype=float)
        val = np.array([sp.value for sp, _ in self.setpoints], dtype=float)
        next_acked = np.minimum.accumulate(acked[::-1])[::-1]
        t = np.where(np.isfinite(acked), acked,
                     np.where(np.isfinite(next_acked), next_acked, np.maximum(intended, t_end)))
        t = np.maximum.accumulate(t)  # in send order, never earlier than the one before
        return t, intended, val, np.isfinite(acked)

    def arrays(self) -> dict[str, np.ndarray]:
        """The record so far as arrays (``segment``, ``phase`` as int), with
        ``kappa_cmd``: the set points in force averaged over each sample's
        interval (the meaning of the odometry's curvature); a set point whose
        acknowledgement was lost is placed by the measured curvature
        (:func:`~station.analysis.trailer.setpoints.place_unacknowledged`)."""
        out = {c: np.asarray(self.samples[c], dtype=float) for c in COLUMNS}
        out["segment"] = out["segment"].astype(int)
        out["phase"] = out["phase"].astype(int)
        t_end = float(out["t"][-1]) if out["t"].size else -np.inf
        t_sp, t_early, v_sp, acked = self.setpoint_timeline(t_end)
        t_sp = place_unacknowledged(out["t"], out["kappa"], out["kappa_set"], t_sp, v_sp, acked, t_early)
        out["kappa_cmd"] = interval_average(out["t"], t_sp, v_sp, out["kappa_set"])
        return out


def _record(ctx: StepContext) -> TrailerSession:
    """The session, its plan and record rebuilt from the store once in a new session."""
    s: TrailerSession = ctx.session
    if s.samples is None:
        s.plan = plan_from_params(TrailerCalibrationPlan, ctx.params["plan"])
        s.samples = {c: [] for c in COLUMNS}
        done = ctx.samples("odometry")
        if done:
            for c in COLUMNS:
                s.samples[c] = list(done[c])
        sp = ctx.samples("setpoints")
        if sp:
            s.setpoints = [(SetPoint(float(v), None if math.isnan(ta) else float(ta)), float(ti))
                           for v, ta, ti in zip(sp["value"], sp["t_applied"], sp["t_intended"])]
    return s


# ----------------------------------------------------------------------------- steps
def plan_check(plan: TrailerCalibrationPlan) -> dict:
    """Every command of ``plan`` against eq. (25) and the 45 deg limit for the nominal lengths
    (StationError naming the command); the settling each jump needs against ``settle_s``."""
    tau = np.linspace(0.0, plan.duration_s, 2001)
    worst = 0.0
    for i, (kind, M) in enumerate(plan.commands):
        kappa = command_curvature(kind, M, tau, plan.omega_rad_s)
        try:
            worst = max(worst, check_curvature_command(kappa, plan.nominal_L1_m, plan.nominal_L2_m))
        except StationError as exc:
            raise type(exc)(f"plan.commands[{i}] ({kind}, M={M}): {exc}") from exc
    # time to ramp into each command and let the joint angle settle (3 L2/v)
    ends = [0.0] + [float(command_curvature(k, M, np.array([plan.duration_s]), plan.omega_rad_s)[0])
                    for k, M in plan.commands[:-1]]
    starts = [float(command_curvature(k, M, np.array([0.0]), plan.omega_rad_s)[0]) for k, M in plan.commands]
    need = [abs(b - a) / plan.curvature_rate + 3 * plan.nominal_L2_m / plan.v_m_s for a, b in zip(ends, starts)]
    return {"commands": [list(c) for c in plan.commands], "max_steady_psi_deg": math.degrees(worst),
            "settle_needed_s": need, "settle_s": plan.settle_s,
            "settled": bool(all(n <= plan.settle_s for n in need))}


def check_plan(ctx: StepContext) -> dict:
    """Step 1: refuse a plan that passes eq. (25) or 45 deg for the nominal lengths."""
    s = _record(ctx)
    out = plan_check(s.plan)
    s.max_steady_psi_rad = math.radians(out["max_steady_psi_deg"])
    return out


def connect(ctx: StepContext) -> dict:
    """Step 2: open the odometry link; whatever an earlier session left running stands still first."""
    s = _record(ctx)
    drv = s.odometry = s.device("odometry")
    t_v = drv.command_speed(0.0)
    return {"device": s.devices.describe("odometry"), "t_stopped_s": t_v}


def start_driving(ctx: StepContext) -> dict:
    """Step 3: at rest, steer to the first command's start curvature, then drive."""
    ctx.checkpoint()
    s = _record(ctx)
    kind, M = s.plan.commands[0]
    k0 = float(command_curvature(kind, M, np.array([0.0]), s.plan.omega_rad_s)[0])
    s.odometry.command_speed(0.0)
    t_k = s.odometry.command_curvature(k0)
    s.setpoints.append((SetPoint(k0, t_k), t_k))
    s.kappa_cmd = k0
    t_v = s.odometry.command_speed(s.plan.v_m_s)
    return {"kappa0_1_m": k0, "t_kappa_s": t_k, "t_speed_s": t_v}


def run_command(index: int):
    """Step 4, command ``index``: settle, then stream the command, recording every sample.

    Each round takes every sample waiting (all recorded) and sets the point
    for the tick after the newest one, so the set points follow the device's
    time even when the station lags behind the stream.
    """
    def run(ctx: StepContext) -> dict:
        ctx.checkpoint()
        s = _record(ctx)
        ctx.progress(f"{s.plan.commands[index][0]} M={s.plan.commands[index][1]:g}")
        return _command(ctx, s, index)
    return run


def _command(ctx: StepContext, s: TrailerSession, index: int) -> dict:
    plan = s.plan
    kind, M = plan.commands[index]
    drv = s.odometry
    waiting = _read(ctx, s)
    t_seg = waiting[-1].t_s
    t_prof = t_seg + plan.settle_s
    t_end = t_prof + plan.duration_s
    dt = None
    last_t = None
    k0 = float(command_curvature(kind, M, np.array([0.0]), plan.omega_rad_s)[0])
    batch = {c: [] for c in COLUMNS}
    n = 0
    while True:
        for sample in waiting:
            phase = 0 if sample.t_s < t_prof else 1
            for c, val in zip(COLUMNS, (sample.t_s, sample.v_m_s, sample.kappa_1_m, sample.psi_rad,
                                        s.kappa_cmd, index, phase)):
                batch[c].append(val)
            n += 1
            if last_t is not None and sample.t_s > last_t:
                gap = sample.t_s - last_t
                dt = gap if dt is None else min(dt, gap) if gap < 1.5 * dt else dt
            last_t = sample.t_s
        if last_t >= t_end:
            break
        # set point for the tick after the newest sample: ramp to the start value, then the profile
        step = dt or 0.1
        t_apply = last_t + step
        if t_apply < t_prof:
            room = plan.curvature_rate * step
            target = s.kappa_cmd + min(max(k0 - s.kappa_cmd, -room), room)
        else:
            tau = min(t_apply - t_prof, plan.duration_s)
            target = float(command_curvature(kind, M, np.array([tau]), plan.omega_rad_s)[0])
        if abs(target - s.kappa_cmd) > 1e-9:
            sent = drv.send_curvature(target)  # streamed; a refusal raises from the next read
            s.setpoints.append((sent, t_apply))
            s.kappa_cmd = target
        if len(batch["t"]) >= 20:  # commit often: what is not committed is not yet acknowledged
            _flush(ctx, s, batch)
        waiting = _read(ctx, s)
    _flush(ctx, s, batch)
    seg = [(sp, ti) for sp, ti in s.setpoints if ti > t_seg]
    if seg:
        ctx.record("setpoints", {
            "t_intended": np.array([ti for _, ti in seg]),
            "t_applied": np.array([np.nan if getattr(sp, "t_applied_s", None) is None else sp.t_applied_s
                                   for sp, _ in seg]),
            "value": np.array([sp.value for sp, _ in seg])})
    return {"command": [kind, M], "samples": n, "t_start_s": t_seg, "t_profile_s": t_prof, "t_end_s": last_t,
            "line": drv.stats.as_dict() if hasattr(drv, "stats") else None,
            "set_points": drv.command_stats.as_dict() if hasattr(drv, "command_stats") else None}


def _read(ctx: StepContext, s: TrailerSession) -> list:
    """The next sample (waiting for it) and every one already queued, after the run's checkpoint."""
    ctx.checkpoint()
    return [s.odometry.read_sample(s.plan.sample_timeout_s)] + s.odometry.drain()


def stop(ctx: StepContext) -> dict:
    """Step 5: speed 0 and straight ahead; samples taken meanwhile are kept (phase 2)."""
    ctx.checkpoint()
    s = _record(ctx)
    t_v = s.odometry.command_speed(0.0)
    t_k = s.odometry.command_curvature(0.0)
    s.setpoints.append((SetPoint(0.0, t_k), t_k))
    s.kappa_cmd = 0.0
    batch = {c: [] for c in COLUMNS}
    for sample in s.odometry.drain():
        for c, val in zip(COLUMNS, (sample.t_s, sample.v_m_s, sample.kappa_1_m, sample.psi_rad, 0.0,
                                    len(s.plan.commands) - 1, 2)):
            batch[c].append(val)
    n = len(batch["t"])
    _flush(ctx, s, batch)
    return {"t_speed_s": t_v, "t_kappa_s": t_k, "samples_while_stopping": n}


def estimate(ctx: StepContext) -> dict:
    """Step 6: the chosen estimate (errors raise) and the comparisons (errors reported); a resumed run's
    record, split where the trailer stood still between sessions, is estimated per continuous piece by
    the dynamic method and the pieces combined."""
    s = _record(ctx)
    data = s.arrays()
    pieces = continuous_pieces(data["t"])
    for name in (s.plan.method, *s.plan.compare):
        if name in s.estimates:
            continue
        try:
            if name == "dynamic" and len(pieces) > 1:
                parts = [estimate_trailer({k: v[sl] for k, v in data.items()}, name) for sl in pieces]
                s.estimates[name] = combine_estimates(name, parts)
            else:
                s.estimates[name] = estimate_trailer(data, name)
        except StationError as exc:
            if name == s.plan.method:
                raise
            s.errors[name] = str(exc)
    return {name: est.to_json() for name, est in s.estimates.items()}


#: coverage factor of a length's expanded uncertainty U = k sigma (about 95 %, as the ISO 9283 figures')
LENGTH_K = 2.0


def length_rows(method: str, L1_m, L2_m, nominal_L1_m, nominal_L2_m, tol_m: float | None,
                sigmas_m=(None, None), rule: str = "guarded") -> list[dict]:
    """|L - nominal| of both links of the run's estimate, judged against ``trailer.length_tolerance_m`` by
    ``rule`` (:func:`station.analysis.decision.decide`) with U = :data:`LENGTH_K` x the estimate's sigma
    (``sigmas_m``; None: not known, which decides nothing under ``guarded``). Each row carries its ``U``."""
    from station.analysis.decision import decide

    rows = []
    for name, est, nom, sd in (("L1_error_m", L1_m, nominal_L1_m, sigmas_m[0]),
                               ("L2_error_m", L2_m, nominal_L2_m, sigmas_m[1])):
        value = None if est is None or not np.isfinite(est) else abs(float(est) - float(nom))
        U = None if sd is None or not np.isfinite(sd) else LENGTH_K * float(sd)
        passed = None if (tol_m is None or value is None) else decide(value, tol_m, U, rule).passed
        rows.append({"pose": method, "name": name, "value": value, "unit": "m", "limit": tol_m, "passed": passed,
                     "U": U})
    return rows


def run_checks(store, run_id: str, params: Mapping):
    """The length errors' U (stored with the result), for the verdict's reasons and the marginal figures."""
    from procedures.decision import Checks

    try:
        res = store.result(run_id, "trailer")
    except Exception:  # noqa: BLE001 - no result stored: nothing to add
        return Checks()
    return Checks(uncertainties={(d["pose"], d["name"]): d["U"] for d in res.get("length_errors") or ()
                                 if d.get("U") is not None})


def report(ctx: StepContext) -> dict:
    """Step 7: the characteristics (the link lengths, and their errors from nominal judged against
    ``trailer.length_tolerance_m``), the HTML report and the stored result."""
    from station.report import Report, plot_xy, write_report

    s = _record(ctx)
    main = s.estimates[s.plan.method]
    data = s.arrays()
    drv = s.odometry
    out = {
        "method": s.plan.method,
        "result": main.to_json(),
        "comparisons": {k: v.to_json() for k, v in s.estimates.items() if k != s.plan.method},
        "comparison_errors": dict(s.errors),
        "n_samples": int(data["t"].size),
        "nominal_L_m": [s.plan.nominal_L1_m, s.plan.nominal_L2_m],
        "line": drv.stats.as_dict() if hasattr(drv, "stats") else None,
        "set_points": drv.command_stats.as_dict() if hasattr(drv, "command_stats") else None,
    }
    rows = []
    for name, est in s.estimates.items():
        j = est.to_json()
        for key in ("L1_m", "L2_m"):
            rows.append({"pose": name, "name": key, "value": j[key], "unit": "m", "limit": None, "passed": None})
            rows.append({"pose": name, "name": key.replace("_m", "_sigma_m"), "value": j[f"{key[:2]}_sigma_m"],
                         "unit": "m", "limit": None, "passed": None})
    section = ctx.store.run(ctx.run_id).config.get("trailer") or {}
    tol, rule = section.get("length_tolerance_m"), section.get("decision_rule", "guarded")
    errors = length_rows(s.plan.method, main.L1_m, main.L2_m, s.plan.nominal_L1_m, s.plan.nominal_L2_m, tol,
                         (main.L1_sigma_m, main.L2_sigma_m), rule)
    out["length_errors"] = [{**r, "rule": rule} for r in errors]
    rows += errors
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
    rep = Report(
        title=f"Trailer calibration {ctx.run_id}",
        facts={"trailer": f"serial {run.serial}", "method": s.plan.method,
               "commands": ", ".join(f"{kd} M={m:g}" for kd, m in s.plan.commands),
               "samples": str(out["n_samples"]),
               "nominal L1, L2": f"{s.plan.nominal_L1_m} m, {s.plan.nominal_L2_m} m"},
        rows=rows, figures=figs, notes=list(main.to_json().get("warnings", [])))
    path = write_report(rep, Path(ctx.params.get("report_dir", "reports")) / f"{ctx.run_id}.html")
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


def _flush(ctx: StepContext, s: TrailerSession, batch: dict) -> None:
    """Commit a batch of samples (acknowledged once in the store), then keep it in the session's record."""
    if not batch["t"]:
        return
    ctx.record("odometry", {c: np.asarray(batch[c]) for c in COLUMNS})
    for c in COLUMNS:
        s.samples[c].extend(batch[c])
        batch[c].clear()


def continuous_pieces(t_s: np.ndarray, gap_factor: float = 5.0) -> list[slice]:
    """Slices of ``t_s`` without a time step longer than ``gap_factor`` x the median step."""
    t = np.asarray(t_s, dtype=float)
    if t.size < 3:
        return [slice(0, t.size)]
    dt = np.diff(t)
    cut = np.flatnonzero(dt > gap_factor * np.median(dt)) + 1
    edges = np.concatenate([[0], cut, [t.size]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def combine_estimates(method: str, parts: list) -> Any:
    """Inverse-covariance combination of independent estimates of (L1, L2)."""
    from station.analysis.trailer.least_squares import TrailerEstimate

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


def safe_state(session: TrailerSession) -> None:
    drv = session.odometry
    if drv is not None:
        try:
            drv.command_speed(0.0)
        except StationError as exc:
            raise StationError(f"could not stop the trailer: {exc}") from exc


def build_procedure(plan: TrailerCalibrationPlan) -> Procedure:
    steps = [
        Step("check plan", check_plan, every_session=True),
        Step("connect odometry", connect, every_session=True),
        Step("start driving", start_driving, every_session=True),
    ]
    for i, (kind, M) in enumerate(plan.commands):
        steps.append(Step(f"command {i + 1}/{len(plan.commands)}: {kind} M={M:g}", run_command(i)))
    steps += [Step("stop", stop), Step("estimate", estimate), Step("report", report)]
    return Procedure("trailer", steps, safe_state=safe_state)


# ----------------------------------------------------------------------------- the registry entry
def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    """The stored plan of a new run, from the config's [trailer] section."""
    tc = _trailer_section(cfg)
    kw = dict(commands=tuple((k, float(m)) for k, m in tc.commands), duration_s=tc.duration_s,
              settle_s=tc.settle_s, v_m_s=tc.v_m_s, nominal_L1_m=tc.nominal_L1_m, nominal_L2_m=tc.nominal_L2_m,
              method=tc.method)
    kw.update(overrides)
    return {"plan": plan_params(TrailerCalibrationPlan(**kw)), "report_dir": report_dir}


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
    for e in res.get("length_errors") or ():  # each length error against the tolerance, with its U and rule
        if e.get("limit") is None or e.get("value") is None:
            continue
        from station.verdict import outcome_of

        U = "" if e.get("U") is None else f" +/- U {e['U']:.2g} m (k = 2)"
        lines.append(f"{e['name']} {e['value']:.4f} m{U} against tolerance {e['limit']:g} m ({e['rule']} rule): "
                     f"{outcome_of(e['passed'])}")
    lines.append(f"report: {res['report']}")
    return lines


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    """The plan against eq. (25), the 45 deg joint-angle limit and the report folder."""
    problems = report_dir_problems(params.get("report_dir", "reports"))
    try:
        plan_check(plan_from_params(TrailerCalibrationPlan, params["plan"]))
    except StationError as exc:
        problems.append(f"trailer plan: {exc}")
    return problems


SPEC = ProcedureSpec(
    name="trailer",
    new_params=new_params,
    build=lambda params: build_procedure(plan_from_params(TrailerCalibrationPlan, params["plan"])),
    new_session=lambda devices: TrailerSession(devices),
    subject=subject,
    device_roles=device_roles,
    fake_cell="fakes.cells:trailer_cell",
    result_key="trailer",
    summary=summary,
    preflight=preflight_problems,
    live_view=odometry_view,
    checks=run_checks,
)
