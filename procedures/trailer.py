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
   one per control tick after the newest sample (the jump to the start
   value is ramped at ``curvature_rate``),
   recording every sample (device time, speed, curvature, joint angle, the
   set point in force, segment and phase);
4. ``stop`` — speed 0, curvature 0;
5. ``estimate`` — link lengths by the chosen method (default ``dynamic``, on
   the whole continuous record) and by the comparison methods;
6. ``report`` — a JSON-able summary.

:mod:`procedures.trailer_run` runs them as journaled steps of the station's
runner (the one way every procedure runs). Samples go through
``ctx.record(stream, columns)`` as they are taken (the run store), and
``ctx.checkpoint()`` is called before every sample read, so a pause or abort
takes effect inside a command that streams for a minute.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from station.analysis.trailer.estimate import ESTIMATORS, estimate_trailer
from station.errors import ConfigError, StationError
from station.models.trailer import (
    COMMAND_KINDS, COMMAND_OMEGA_RAD_S, DEFAULT_L1_M, DEFAULT_L2_M, check_curvature_command,
    check_lengths, command_curvature,
)

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


@dataclass
class TrailerCalibrationContext:
    """What the steps share: the driver, the plan, the record, the results.

    ``record(stream, columns)`` is called with every batch of samples as it
    is taken (stream ``"odometry"``) and with the curvature set points of
    each command once it is done (stream ``"setpoints"``: the device time
    each was applied — from its acknowledgement, or the intended tick when
    the acknowledgement was lost on the line — and its value).
    """

    driver: object
    plan: TrailerCalibrationPlan = field(default_factory=TrailerCalibrationPlan)
    record: Callable[[str, dict], None] | None = None
    #: called before every sample read: blocks while the run is paused, raises when it is aborted
    checkpoint: Callable[[], None] | None = None
    samples: dict = field(default_factory=lambda: {c: [] for c in COLUMNS})
    estimates: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    log: list = field(default_factory=list)
    kappa_cmd: float = 0.0
    max_steady_psi_rad: float = 0.0
    setpoints: list = field(default_factory=list)  # [SentCommand-like, intended apply time]

    def setpoint_timeline(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t_applied, value)`` of every curvature set point, device time, in send order.

        Set points take effect in the order sent, so one whose acknowledgement
        was lost on the line took effect no later than the next acknowledged
        one: it gets that one's time (at most one tick late); after the last
        acknowledgement, its intended tick.
        """
        if not self.setpoints:
            return np.zeros(0), np.zeros(0)
        acked = np.array([np.inf if getattr(sp, "t_applied_s", None) is None else sp.t_applied_s
                          for sp, _ in self.setpoints], dtype=float)
        intended = np.array([ti for _, ti in self.setpoints], dtype=float)
        val = np.array([sp.value for sp, _ in self.setpoints], dtype=float)
        next_acked = np.minimum.accumulate(acked[::-1])[::-1]
        t = np.where(np.isfinite(acked), acked, np.where(np.isfinite(next_acked), next_acked, intended))
        t = np.maximum.accumulate(t)  # in send order, never earlier than the one before
        return t, val

    def arrays(self) -> dict[str, np.ndarray]:
        """The record so far as arrays (``segment``, ``phase`` as int), with
        ``kappa_cmd``: the set points in force averaged over each sample's
        interval (the meaning of the odometry's curvature)."""
        out = {c: np.asarray(self.samples[c], dtype=float) for c in COLUMNS}
        out["segment"] = out["segment"].astype(int)
        out["phase"] = out["phase"].astype(int)
        t_sp, v_sp = self.setpoint_timeline()
        out["kappa_cmd"] = interval_average(out["t"], t_sp, v_sp, out["kappa_set"])
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
    # time to ramp into each command and let the joint angle settle (3 L2/v)
    ends = [0.0] + [float(command_curvature(k, M, np.array([plan.duration_s]), plan.omega_rad_s)[0])
                    for k, M in plan.commands[:-1]]
    starts = [float(command_curvature(k, M, np.array([0.0]), plan.omega_rad_s)[0]) for k, M in plan.commands]
    need = [abs(b - a) / plan.curvature_rate + 3 * plan.nominal_L2_m / plan.v_m_s for a, b in zip(ends, starts)]
    return {"commands": [list(c) for c in plan.commands], "max_steady_psi_deg": math.degrees(worst),
            "settle_needed_s": need, "settle_s": plan.settle_s,
            "settled": bool(all(n <= plan.settle_s for n in need))}


def start_driving(ctx: TrailerCalibrationContext) -> dict:
    """Step 2: at rest, steer to the first command's start curvature, then drive."""
    kind, M = ctx.plan.commands[0]
    k0 = float(command_curvature(kind, M, np.array([0.0]), ctx.plan.omega_rad_s)[0])
    ctx.driver.command_speed(0.0)
    t_k = ctx.driver.command_curvature(k0)
    ctx.setpoints.append((_Applied(k0, t_k), t_k))
    ctx.kappa_cmd = k0
    t_v = ctx.driver.command_speed(ctx.plan.v_m_s)
    return {"kappa0_1_m": k0, "t_kappa_s": t_k, "t_speed_s": t_v}


def run_command(ctx: TrailerCalibrationContext, index: int) -> dict:
    """Step 3: settle, then stream command ``index`` of the plan, recording every sample.

    Each round takes every sample waiting (all recorded) and sets the point
    for the tick after the newest one, so the set points follow the device's
    time even when the station lags behind the stream.
    """
    plan = ctx.plan
    kind, M = plan.commands[index]
    drv = ctx.driver
    waiting = _read(ctx)
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
                                        ctx.kappa_cmd, index, phase)):
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
            target = ctx.kappa_cmd + min(max(k0 - ctx.kappa_cmd, -room), room)
        else:
            tau = min(t_apply - t_prof, plan.duration_s)
            target = float(command_curvature(kind, M, np.array([tau]), plan.omega_rad_s)[0])
        if abs(target - ctx.kappa_cmd) > 1e-9:
            sent = drv.send_curvature(target)  # streamed; a refusal raises from the next read
            ctx.setpoints.append((sent, t_apply))
            ctx.kappa_cmd = target
        if len(batch["t"]) >= 20:  # commit often: what is not committed is not yet acknowledged
            _flush(ctx, batch)
        waiting = _read(ctx)
    _flush(ctx, batch)
    if ctx.record is not None:
        seg = [(sp, ti) for sp, ti in ctx.setpoints if ti > t_seg]
        ctx.record("setpoints", {
            "t_intended": np.array([ti for _, ti in seg]),
            "t_applied": np.array([np.nan if getattr(sp, "t_applied_s", None) is None else sp.t_applied_s
                                   for sp, _ in seg]),
            "value": np.array([sp.value for sp, _ in seg])})
    return {"command": [kind, M], "samples": n, "t_start_s": t_seg, "t_profile_s": t_prof, "t_end_s": last_t,
            "line": drv.stats.as_dict() if hasattr(drv, "stats") else None,
            "set_points": drv.command_stats.as_dict() if hasattr(drv, "command_stats") else None}


def _read(ctx: TrailerCalibrationContext) -> list:
    """The next sample (waiting for it) and every one already queued, after the run's checkpoint."""
    if ctx.checkpoint is not None:
        ctx.checkpoint()
    return [ctx.driver.read_sample(ctx.plan.sample_timeout_s)] + ctx.driver.drain()


def stop(ctx: TrailerCalibrationContext) -> dict:
    """Step 4: speed 0 and straight ahead; samples taken meanwhile are kept (phase 2)."""
    t_v = ctx.driver.command_speed(0.0)
    t_k = ctx.driver.command_curvature(0.0)
    ctx.setpoints.append((_Applied(0.0, t_k), t_k))
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


@dataclass(frozen=True)
class _Applied:
    """A set point acknowledged by a blocking command."""

    value: float
    t_applied_s: float


def interval_average(t_s, t_change, values, fallback) -> np.ndarray:
    """Average over each sample interval ``(t_{k-1}, t_k]`` of the piecewise-constant
    set point that takes ``values[j]`` from ``t_change[j]`` on (sorted).

    Before the first change, and for the first sample, ``fallback`` (the set
    point the procedure had in force when it took the sample) is used.
    Shapes: ``t_s`` (N,), ``t_change``/``values`` (M,) -> (N,).
    """
    t = np.asarray(t_s, dtype=float)
    fb = np.asarray(fallback, dtype=float)
    if t.size == 0 or len(t_change) == 0:
        return fb.copy()
    tc = np.asarray(t_change, dtype=float)
    vc = np.asarray(values, dtype=float)
    # cumulative integral of the set point at each change time
    F_knots = np.concatenate([[0.0], np.cumsum(vc[:-1] * np.diff(tc))])
    j = np.searchsorted(tc, t, side="right") - 1
    inside = j >= 0
    jj = np.clip(j, 0, None)
    F = np.where(inside, F_knots[jj] + vc[jj] * (t - tc[jj]), np.nan)
    out = fb.copy()
    ok = inside[1:] & inside[:-1] & (np.diff(t) > 0)
    out[1:][ok] = (F[1:][ok] - F[:-1][ok]) / np.diff(t)[ok]
    return out


def _flush(ctx: TrailerCalibrationContext, batch: dict) -> None:
    if not batch["t"]:
        return
    if ctx.record is not None:
        ctx.record("odometry", {c: np.asarray(batch[c]) for c in COLUMNS})
    for c in COLUMNS:
        ctx.samples[c].extend(batch[c])
        batch[c].clear()


__all__ = [
    "ESTIMATORS", "TrailerCalibrationPlan", "TrailerCalibrationContext",
    "check_plan", "start_driving", "run_command", "stop", "estimate", "report",
    "estimate_trailer", "interval_average",
]
