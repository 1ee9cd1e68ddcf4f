"""What an ideal ISO 9283 run would report for an arm whose errors are known.

Given the error effects of an arm (:class:`station.models.effects.EffectSet`,
e.g. the truth of a simulated cell, or a fitted model), this predicts the
static part of the procedure's results without noise: the base frame the
axis registration would find (the same :func:`register_by_axes` on the true
tool points of the joint-1 and joint-2 sweeps, each approached from below),
the attained positions of P1..P5 reached in cycle order (backlash from the
direction of the last motion), and from them AP (seed 000 eq. (1), the
distance of the attained from the commanded position) and AD (eq. (8), the
attained minus the commanded distance of P2-P4).

What it leaves out is random or dynamic, and :func:`prediction_scatter`
estimates the random part by Monte Carlo: the stop scatter of the sweep
points, which the circle fits of two short arcs amplify about sevenfold into
the frame's error at the poses, the mean of the n stops at each pose and the
tracker's noise. The servo's settling and the thermal growth during the run
(evaluated at one warm-up time) are left out. Over 50 fake cells (5 cycles
each, 250 poses) the measured AP differed from the prediction by 0.00 +/-
0.22 mm, at most 0.68 mm; measured in the scatter's rms length at each pose
(0.27-0.55 mm), at most 1.7 of it; AD by 0.02 +/- 0.02 mm
(``bench/bench_fake_truth.py``).

Used to draw simulated cells whose robot is inside or outside its
manufacturer's limits on purpose (:mod:`app.testing`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from procedures.iso9283 import IsoPlan, axis_sweep_q_deg, axis_sweeps
from station.analysis.registration import register_by_axes
from station.errors import ConfigError
from station.models import kinematics as kin
from station.models.effects import EffectContext, EffectSet
from station.programs.builders import TOOL_DOWN
from station.programs.program import CartesianTarget, quat_from_matrix


@dataclass(frozen=True)
class StaticPrediction:
    """Noise-free static results of an ISO 9283 run (mm)."""

    AP_mm: dict[str, float]
    AD_mm: dict[str, float]
    attained_base_mm: dict[str, tuple[float, float, float]]


def _true_positions(plan: IsoPlan, effects: EffectSet | None, q_rad: np.ndarray, last_dir: np.ndarray,
                    warmup_s: float, temperature_rise_K: float | None = None) -> np.ndarray:
    """The arm's true tool positions at joint angles ``q_rad``, warmed ``warmup_s`` by its effects' warm-up
    model, or by ``temperature_rise_K`` when given (the simulated arm's rise from its motion, fakes.sim.heat)."""
    robot = plan.robot
    if effects is None:
        return kin.fk(robot.dh_nominal, q_rad)[:, :3, 3]
    rise = None if temperature_rise_K is None else np.full(len(q_rad), float(temperature_rise_K))
    ctx = EffectContext(robot=robot, last_dir=last_dir, warmup_s=np.full(len(q_rad), float(warmup_s)),
                        temperature_rise_K=rise, payload_kg=plan.payload_kg)
    dh, q = effects.apply(robot.dh_nominal, q_rad, ctx)
    return kin.fk(dh, q)[:, :3, 3]


def _tool_down(xyz) -> np.ndarray:
    """The pose the procedure's programs command at ``xyz`` (tool pointing down), (4, 4)."""
    return CartesianTarget("T", tuple(float(v) for v in xyz), quat_from_matrix(TOOL_DOWN)).pose


def pose_joints_rad(plan: IsoPlan) -> np.ndarray:
    """Joints of P1..P5 (nominal IK from the safety gate, each from the previous pose's branch)."""
    gate = plan.gate()
    out, prev = [], None
    for name, xyz in plan.poses_mm.items():
        prev = gate.check_cartesian_target(_tool_down(xyz), name, q_seed=prev)
        out.append(prev)
    return np.array(out)


def arrival_directions(plan: IsoPlan, q_rad: np.ndarray, *, back_mm: float = 1.0) -> np.ndarray:
    """Sign of each joint's motion as the linear move of the cycle arrives at each pose (N, 6).

    The cycle runs P1..P5 and back to P1 in straight lines, and a joint can
    turn back part-way along a line, so the direction is taken over the last
    ``back_mm`` of the move (IK of a point that far before the pose). A joint
    that does not move on the way in keeps the direction of the move before.
    """
    gate = plan.gate()
    names = list(plan.poses_mm)
    xyz = np.array(list(plan.poses_mm.values()), dtype=float)
    n = len(xyz)
    step = np.zeros((n, 6))
    for k in range(n):
        back = xyz[k - 1] - xyz[k]
        before = _tool_down(xyz[k] + back / np.linalg.norm(back) * back_mm)
        step[k] = q_rad[k] - gate.check_cartesian_target(before, f"before {names[k]}", q_seed=q_rad[k])
    moving = np.abs(step) > 1e-9
    out = np.sign(step)
    for _ in range(2):  # twice round the cycle carries a direction into every pose
        for k in range(n):
            out[k] = np.where(moving[k], out[k], out[k - 1])
    return out


@dataclass(frozen=True)
class RunGeometry:
    """The joints a run of ``plan`` visits (the same for every arm of the model; compute once).

    ``q_sweep_rad`` (M, 6): registration points, the first ``n_sweep1`` of
    them the joint-1 sweep; ``q_pose_rad`` (P, 6): P1..P5; ``arrival_dir``
    (P, 6): sign of each joint's motion arriving at each pose.
    """

    q_sweep_rad: np.ndarray
    n_sweep1: int
    q_pose_rad: np.ndarray
    arrival_dir: np.ndarray

    @classmethod
    def of(cls, plan: IsoPlan) -> "RunGeometry":
        if plan.registration != "axes":
            raise ConfigError("the prediction needs the axis registration (iso9283.registration = 'axes')")
        q_sweep = np.radians(np.array(list(axis_sweep_q_deg(plan).values())))
        q_pose = pose_joints_rad(plan)
        return cls(q_sweep, len(axis_sweeps(plan)[0][1]), q_pose, arrival_directions(plan, q_pose))


def _registration(plan: IsoPlan, geo: RunGeometry, p_sweep: np.ndarray):
    n1, q = geo.n_sweep1, geo.q_sweep_rad
    return register_by_axes(plan.robot.dh_nominal, q[:n1], p_sweep[:n1], q[n1:], p_sweep[n1:])


def _noise_free(plan: IsoPlan, effects: EffectSet | None, geo: RunGeometry, warmup_s: float,
                temperature_rise_K: float | None = None):
    """True attained positions of P1..P5 (base frame) and the frame the registration finds, without noise."""
    q_sweep = geo.q_sweep_rad
    reg = _registration(plan, geo, _true_positions(plan, effects, q_sweep, np.ones_like(q_sweep), warmup_s,
                                                   temperature_rise_K))
    return _true_positions(plan, effects, geo.q_pose_rad, geo.arrival_dir, warmup_s, temperature_rise_K), reg


def _distance_pair(names: list[str]) -> tuple[int, int] | None:
    """Indices of P2 and P4, the pair of the procedure's AD and RD."""
    return (names.index("P2"), names.index("P4")) if {"P2", "P4"} <= set(names) else None


def predict_static(plan: IsoPlan, effects: EffectSet | None, *, warmup_s: float = 0.0,
                   geometry: RunGeometry | None = None, temperature_rise_K: float | None = None) -> StaticPrediction:
    """Noise-free AP per pose and AD of P2-P4 of an arm with ``effects`` (``None``: nominal arm).

    Parameters
    ----------
    plan : IsoPlan
        The procedure's plan (poses, sweeps, payload); only ``registration == "axes"``.
    effects : EffectSet or None
        The arm's error effects.
    warmup_s : float
        Time since the arm started working, s (thermal drift by the effects' warm-up model).
    temperature_rise_K : float, optional
        The links' temperature rise instead (a simulated arm's, from its motion: ``arm.temperature_rise_K(t)``).
    geometry : RunGeometry, optional
        ``RunGeometry.of(plan)``, when many arms are predicted for one plan.

    Raises
    ------
    ConfigError
        The plan registers by a best fit (that frame depends on the noise of all points).
    """
    p_true, reg = _noise_free(plan, effects, geometry or RunGeometry.of(plan), warmup_s, temperature_rise_K)
    names = list(plan.poses_mm)
    # the registration maps the (estimated) base frame into the true one: invert it
    p_base = (p_true - reg.t_mm) @ reg.R
    cmd = np.array([plan.poses_mm[n] for n in names])
    ap = np.linalg.norm(p_base - cmd, axis=1)
    ad = {}
    if (pair := _distance_pair(names)) is not None:
        i, j = pair
        ad["P2-P4"] = float(np.linalg.norm(p_true[i] - p_true[j]) - np.linalg.norm(cmd[i] - cmd[j]))
    return StaticPrediction(
        AP_mm={n: float(v) for n, v in zip(names, ap)},
        AD_mm=ad,
        attained_base_mm={n: tuple(float(v) for v in p) for n, p in zip(names, p_base)},
    )


@dataclass(frozen=True)
class PredictionScatter:
    """How far a real run's results scatter about :func:`predict_static` (mm, per pose / pair).

    ``AP_rms_mm[pose]`` is the rms length of the error of the attained
    position in the registered frame (registration noise and the mean of the
    stop offsets together): ``|AP_measured - AP_predicted|`` is at most that
    length. ``AD_sd_mm`` is the standard deviation of AD.
    """

    AP_rms_mm: dict[str, float]
    AD_sd_mm: dict[str, float]
    draws: int


def prediction_scatter(plan: IsoPlan, effects: EffectSet | None, stop_sigma_rad, *, cycles: int,
                       tracker_sigma_mm: float = 0.0, draws: int = 200, rng: np.random.Generator | None = None,
                       warmup_s: float = 0.0, geometry: RunGeometry | None = None,
                       tracker_accuracy: tuple | None = None) -> PredictionScatter:
    """Monte Carlo of the random part that :func:`predict_static` leaves out.

    Each draw gives every registration point its own stop offset (joints,
    ``N(0, stop_sigma_rad)``, as the simulated arm and a real one stop) and
    tracker noise (``tracker_sigma_mm`` per coordinate), fits the axis
    registration to them, and stops ``cycles`` times at each pose with fresh
    offsets; the mean attained position, mapped by that registration, is
    compared with the noise-free one. With ``tracker_accuracy`` each draw is
    also a measurement session of the tracker of :mod:`fakes.sim.tracker`: its
    MPE a systematic error drawn once for every point of the draw (an offset
    of sd ``a / 2``, a scale and three angles of sd ``b / 2`` ppm and urad
    about the tracker), so what the registration absorbs of it (the offset
    and the angles) is absorbed here too; ``tracker_sigma_mm`` is then the
    reading noise alone. The circle fits of a +-25 deg and a
    +-30 deg arc turn a few hundredths of a millimetre of stop scatter into
    tenths of a millimetre of frame error at the poses, so this is most of the
    difference between a run and its prediction.

    Parameters
    ----------
    stop_sigma_rad : array_like, shape (6,)
        1-sigma joint offset of each stop.
    cycles : int
        Stops per pose whose mean is the attained pose (>= 1).
    tracker_sigma_mm : float
        Tracker noise per coordinate of one measured point (registration points and stops).
    tracker_accuracy : (origin_mm (3,), a_um, b_um_per_m), optional
        The tracker's position in the base frame and its MPE ``a + b R``, read
        as a systematic error of each draw (see above); None: no such error.
    draws : int
        Monte Carlo draws (>= 10).

    Raises
    ------
    ConfigError
        Bad ``cycles``, ``draws``, ``stop_sigma_rad`` or ``tracker_sigma_mm``, or a
        best-fit registration.
    """
    sigma = np.asarray(stop_sigma_rad, dtype=float)
    if sigma.shape != (6,) or not np.all(np.isfinite(sigma)) or np.any(sigma < 0):
        raise ConfigError(f"stop_sigma_rad must be 6 finite values >= 0, got {stop_sigma_rad!r}")
    if int(cycles) < 1 or int(draws) < 10:
        raise ConfigError(f"prediction_scatter needs cycles >= 1 and draws >= 10, got {cycles}, {draws}")
    if not (np.isfinite(tracker_sigma_mm) and tracker_sigma_mm >= 0):
        raise ConfigError(f"tracker_sigma_mm must be finite and >= 0, got {tracker_sigma_mm!r}")
    geo = geometry or RunGeometry.of(plan)
    rng = rng if rng is not None else np.random.default_rng()
    cycles, draws = int(cycles), int(draws)
    q_sweep, q_pose, dirs = geo.q_sweep_rad, geo.q_pose_rad, geo.arrival_dir
    m, P = len(q_sweep), len(q_pose)
    names = list(plan.poses_mm)
    # the noise-free frame is the reference: the prediction maps through it
    exact, reg0 = _noise_free(plan, effects, geo, warmup_s)
    base0 = (exact - reg0.t_mm) @ reg0.R

    qs = q_sweep[None] + rng.normal(size=(draws, m, 6)) * sigma
    ps = _true_positions(plan, effects, qs.reshape(-1, 6), np.ones((draws * m, 6)), warmup_s).reshape(draws, m, 3)
    ps = ps + rng.normal(size=ps.shape) * tracker_sigma_mm
    qp = q_pose[None, None] + rng.normal(size=(draws, cycles, P, 6)) * sigma
    pp = _true_positions(plan, effects, qp.reshape(-1, 6), np.tile(dirs, (draws * cycles, 1)), warmup_s)
    mean_true = pp.reshape(draws, cycles, P, 3).mean(axis=1)  # (draws, P, 3), true base frame
    if tracker_accuracy is not None:  # the session's error: the registration points and the stops read through it
        origin, a_um, b_um = np.asarray(tracker_accuracy[0], dtype=float), *map(float, tracker_accuracy[1:])
        e = rng.standard_normal((draws, 7))
        off, scale, w = e[:, :3] * a_um * 1e-3 / 2, e[:, 3] * b_um * 1e-6 / 2, e[:, 4:] * b_um * 1e-6 / 2

        def read(p):  # (draws, k, 3) in the base frame
            d = p - origin
            return p + scale[:, None, None] * d + np.cross(w[:, None, :], d) + off[:, None, :]

        ps = read(ps)
        mean_true = read(mean_true)  # the mean of readings of one session: the reading of the mean
        mean_true = mean_true + rng.normal(size=mean_true.shape) * tracker_sigma_mm / math.sqrt(cycles)
    err = np.empty((draws, P, 3))
    for k in range(draws):
        reg = _registration(plan, geo, ps[k])
        err[k] = (mean_true[k] - reg.t_mm) @ reg.R - base0
    ap_rms = np.sqrt(np.mean(np.sum(err**2, axis=2), axis=0))
    ad = {}
    if (pair := _distance_pair(names)) is not None:
        i, j = pair
        d = np.linalg.norm(mean_true[:, i] - mean_true[:, j], axis=1) - np.linalg.norm(exact[i] - exact[j])
        ad["P2-P4"] = float(np.sqrt(np.mean(d**2)))
    return PredictionScatter(AP_rms_mm={n: float(v) for n, v in zip(names, ap_rms)}, AD_sd_mm=ad, draws=draws)
