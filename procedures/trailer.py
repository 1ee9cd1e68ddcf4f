"""Trailer link-length calibration (seed 003), as a sequence of small steps.

The steps (each ``step(ctx) -> dict | None``, JSON-able output):

1. ``check plan`` — every command of the plan (H, C, L of para. [0127] with
   amplitude M) is checked against the jackknife bound of eq. (25) and the
   45 deg joint-angle limit for the nominal lengths, and the speed against
   its limit, before anything moves;
2. ``start driving`` — curvature set to the first command's start value,
   then the speed;
3. ``command k`` — hold the command's start curvature for ``settle_s`` (the
   joint angle settles), then stream the profile as curvature set points,
   one per odometry sample (each set point for the next control tick),
   recording every sample (device time, speed, curvature, joint angle, the
   set point in force, segment and phase);
4. ``stop`` — speed 0, curvature 0;
5. ``estimate`` — link lengths by the chosen method (default ``dynamic``, on
   the whole continuous record) and by the comparison methods;
6. ``report`` — a JSON-able summary.

:func:`calibration_steps` lists them as ``(name, function)`` pairs so a runner
can journal them; :func:`run_trailer_calibration` runs them in order and
leaves the trailer stopped if a step fails. Samples go through
``ctx.record(stream, columns)`` as they are taken (hook for the run store).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from station.analysis.trailer_better import ESTIMATORS, estimate_trailer
from station.analysis.trailer_ls import TrailerEstimate
from station.errors import ConfigError, StationError
from station.models.trailer import (
    COMMAND_KINDS, COMMAND_OMEGA_RAD_S, DEFAULT_L1_M, DEFAULT_L2_M, check_curvature_command,
    check_lengths, command_curvature,
)

#: speed limit of the plan, m/s
MAX_PLAN_SPEED_M_S = 3.0
COLUMNS = ("t", "v", "kappa", "psi", "kappa_cmd", "segment", "phase")


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
        for name in ("duration_s", "sample_timeout_s", "omega_rad_s"):
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


@dataclass
class TrailerCalibrationContext:
    """What the steps share: the driver, the plan, the record, the results.

    ``record(stream, columns)`` is called with every batch of samples as it
    is taken (default: nothing beyond the in-memory record).
    """

    driver: object
    plan: TrailerCalibrationPlan = field(default_factory=TrailerCalibrationPlan)
    record: Callable[[str, dict], None] | None = None
    samples: dict = field(default_factory=lambda: {c: [] for c in COLUMNS})
    estimates: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    log: list = field(default_factory=list)
    kappa_cmd: float = 0.0
    max_steady_psi_rad: float = 0.0

    def arrays(self) -> dict[str, np.ndarray]:
        """The record so far as arrays (``segment``, ``phase`` as int)."""
        out = {c: np.asarray(self.samples[c], dtype=float) for c in COLUMNS}
        out["segment"] = out["segment"].astype(int)
        out["phase"] = out["phase"].astype(int)
        return out


# ----------------------------------------------------------------------------- steps
def check_plan(ctx: TrailerCalibrationContext) -> dict:
    """Step 1: refuse a plan that passes eq. (25) or 45 deg for the nominal lengths."""
    plan = ctx.plan
    tau = np.linspace(0.0, plan.duration_s, 2001)
    worst = 0.0
    for i, (kind, M) in enumerate(plan.commands):
        kappa = command_curvature(kind, M, tau, plan.omega_rad_s)
        try:
            worst = max(worst, check_curvature_command(kappa, plan.nominal_L1_m, plan.nominal_L2_m))
        except StationError as exc:
            raise type(exc)(f"plan.commands[{i}] ({kind}, M={M}): {exc}") from exc
    ctx.max_steady_psi_rad = worst
    return {"commands": [list(c) for c in plan.commands], "max_steady_psi_deg": math.degrees(worst)}


def start_driving(ctx: TrailerCalibrationContext) -> dict:
    """Step 2: start curvature of the first command, then the speed."""
    kind, M = ctx.plan.commands[0]
    k0 = float(command_curvature(kind, M, np.array([0.0]), ctx.plan.omega_rad_s)[0])
    t_k = ctx.driver.command_curvature(k0)
    ctx.kappa_cmd = k0
    t_v = ctx.driver.command_speed(ctx.plan.v_m_s)
    return {"kappa0_1_m": k0, "t_kappa_s": t_k, "t_speed_s": t_v}


def run_command(ctx: TrailerCalibrationContext, index: int) -> dict:
    """Step 3: settle, then stream command ``index`` of the plan, recording every sample."""
    plan = ctx.plan
    kind, M = plan.commands[index]
    drv = ctx.driver
    first = drv.read_sample(plan.sample_timeout_s)
    t_seg = first.t_s
    t_prof = t_seg + plan.settle_s
    t_end = t_prof + plan.duration_s
    dt = None
    last_t = None
    k0 = float(command_curvature(kind, M, np.array([0.0]), plan.omega_rad_s)[0])
    batch = {c: [] for c in COLUMNS}
    n = 0
    sample = first
    while True:
        phase = 0 if sample.t_s < t_prof else 1
        for c, val in zip(COLUMNS, (sample.t_s, sample.v_m_s, sample.kappa_1_m, sample.psi_rad,
                                    ctx.kappa_cmd, index, phase)):
            batch[c].append(val)
        n += 1
        if last_t is not None and sample.t_s > last_t:
            dt = sample.t_s - last_t if dt is None else 0.8 * dt + 0.2 * (sample.t_s - last_t)
        last_t = sample.t_s
        if sample.t_s >= t_end:
            break
        # set point for the next control tick
        t_apply = sample.t_s + (dt or 0.0)
        tau = min(max(t_apply - t_prof, 0.0), plan.duration_s)
        target = k0 if t_apply < t_prof else float(command_curvature(kind, M, np.array([tau]),
                                                                    plan.omega_rad_s)[0])
        if abs(target - ctx.kappa_cmd) > 1e-9:
            drv.send_curvature(target)  # streamed; a refusal raises from the next read
            ctx.kappa_cmd = target
        if len(batch["t"]) >= 100:
            _flush(ctx, batch)
        sample = drv.read_sample(plan.sample_timeout_s)
    _flush(ctx, batch)
    return {"command": [kind, M], "samples": n, "t_start_s": t_seg, "t_profile_s": t_prof, "t_end_s": last_t,
            "line": drv.stats.as_dict() if hasattr(drv, "stats") else None,
            "set_points": drv.command_stats.as_dict() if hasattr(drv, "command_stats") else None}


def stop(ctx: TrailerCalibrationContext) -> dict:
    """Step 4: speed 0 and straight ahead; samples taken meanwhile are kept (phase 2)."""
    t_v = ctx.driver.command_speed(0.0)
    t_k = ctx.driver.command_curvature(0.0)
    ctx.kappa_cmd = 0.0
    batch = {c: [] for c in COLUMNS}
    for s in ctx.driver.drain():
        for c, val in zip(COLUMNS, (s.t_s, s.v_m_s, s.kappa_1_m, s.psi_rad, 0.0,
                                    len(ctx.plan.commands) - 1, 2)):
            batch[c].append(val)
    n = len(batch["t"])
    _flush(ctx, batch)
    return {"t_speed_s": t_v, "t_kappa_s": t_k, "samples_while_stopping": n}


def estimate(ctx: TrailerCalibrationContext) -> dict:
    """Step 5: the chosen estimate (errors raise) and the comparisons (errors reported)."""
    data = ctx.arrays()
    ctx.estimates[ctx.plan.method] = estimate_trailer(data, ctx.plan.method)
    for name in ctx.plan.compare:
        if name == ctx.plan.method:
            continue
        try:
            ctx.estimates[name] = estimate_trailer(data, name)
        except StationError as exc:
            ctx.errors[name] = str(exc)
    return {name: est.to_json() for name, est in ctx.estimates.items()}


def report(ctx: TrailerCalibrationContext) -> dict:
    """Step 6: summary of the run."""
    main = ctx.estimates.get(ctx.plan.method)
    data = ctx.arrays()
    return {
        "method": ctx.plan.method,
        "result": main.to_json() if main is not None else None,
        "comparisons": {k: v.to_json() for k, v in ctx.estimates.items() if k != ctx.plan.method},
        "comparison_errors": dict(ctx.errors),
        "n_samples": int(data["t"].size),
        "nominal_L_m": [ctx.plan.nominal_L1_m, ctx.plan.nominal_L2_m],
        "line": ctx.driver.stats.as_dict() if hasattr(ctx.driver, "stats") else None,
        "set_points": ctx.driver.command_stats.as_dict() if hasattr(ctx.driver, "command_stats") else None,
    }


def safe_state(ctx: TrailerCalibrationContext) -> None:
    """Leave the trailer stopped (best effort, after a failure)."""
    try:
        ctx.driver.command_speed(0.0)
    except StationError:
        pass


def calibration_steps(plan: TrailerCalibrationPlan) -> list[tuple[str, Callable]]:
    """The procedure as ``(name, step(ctx))`` pairs, in order."""
    steps: list[tuple[str, Callable]] = [("check plan", check_plan), ("start driving", start_driving)]
    for i, (kind, M) in enumerate(plan.commands):
        steps.append((f"command {i + 1}/{len(plan.commands)}: {kind} M={M:g}",
                      lambda ctx, i=i: run_command(ctx, i)))
    steps += [("stop", stop), ("estimate", estimate), ("report", report)]
    return steps


# ----------------------------------------------------------------------------- entry point
@dataclass(frozen=True)
class TrailerCalibrationResult:
    """Outcome of :func:`run_trailer_calibration`."""

    estimate: TrailerEstimate
    comparisons: dict
    samples: dict
    steps: dict
    report: dict


def run_trailer_calibration(driver, plan: TrailerCalibrationPlan | None = None, *,
                            record: Callable[[str, dict], None] | None = None,
                            on_step: Callable[[str, dict | None], None] | None = None
                            ) -> TrailerCalibrationResult:
    """Run the whole procedure on an odometry driver.

    Parameters
    ----------
    driver : drivers.odometry.OdometryDriver
        Or anything with ``read_sample``, ``drain``, ``send_curvature``,
        ``command_curvature``, ``command_speed`` (and optionally ``stats``,
        ``command_stats``).
    plan : TrailerCalibrationPlan, optional
    record : callable, optional
        ``record("odometry", columns)`` for each batch of samples.
    on_step : callable, optional
        ``on_step(name, output)`` after each step (progress, journal).
    """
    ctx = TrailerCalibrationContext(driver, plan or TrailerCalibrationPlan(), record)
    outputs = {}
    moving = False
    try:
        for name, step in calibration_steps(ctx.plan):
            if name == "start driving":
                moving = True
            out = step(ctx)
            if name == "stop":
                moving = False
            outputs[name] = out
            ctx.log.append(name)
            if on_step is not None:
                on_step(name, out)
    except BaseException:
        if moving:
            safe_state(ctx)
        raise
    main = ctx.estimates[ctx.plan.method]
    return TrailerCalibrationResult(main, {k: v for k, v in ctx.estimates.items() if k != ctx.plan.method},
                                    ctx.arrays(), outputs, outputs["report"])


def _flush(ctx: TrailerCalibrationContext, batch: dict) -> None:
    if not batch["t"]:
        return
    if ctx.record is not None:
        ctx.record("odometry", {c: np.asarray(batch[c]) for c in COLUMNS})
    for c in COLUMNS:
        ctx.samples[c].extend(batch[c])
        batch[c].clear()


__all__ = [
    "ESTIMATORS", "TrailerCalibrationPlan", "TrailerCalibrationContext", "TrailerCalibrationResult",
    "check_plan", "start_driving", "run_command", "stop", "estimate", "report", "safe_state",
    "calibration_steps", "estimate_trailer", "run_trailer_calibration",
]
