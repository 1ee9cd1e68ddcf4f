"""The simulated world: one clock, one arm, the instruments, one truth.

:func:`make_world` builds everything from a robot name and a seed; every
random choice (error effects, servo, tracker pose, stopping errors, scanner)
comes from its own stream spawned from that seed, so a world is reproducible
and changing one option does not reshuffle the others.

Fakes share a world: the tracker fake measures ``world.tracker_source()``,
the controller fake moves ``world.arm``, the odometry fake drives
``world.get_trailer()``; all read ``world.clock``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fakes.sim.arm import SimArm
from fakes.sim.clock import ManualClock, SimClock
from fakes.sim.joint_defect import JointDefect
from fakes.sim.scanner import ScanResult, SimScanner, look_at
from fakes.sim.tracker import TrackerModel
from station.errors import ConfigError, StationError
from station.models import kinematics as kin
from station.models.effects import EffectSet, realistic_effects, realistic_stop_sigma_rad
from station.models.jig import CornerJig
from station.models.motion import PROFILE_KINDS, ServoParams
from station.models.motion_effects import MotionModel, servo_of
from station.models.robots import RobotSpec, get_robot
from station.models.tracker_noise import TrackerNoise
from station.numeric import finite_number
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

__all__ = ["World", "TrackerSource", "make_world", "realistic_servo", "ISO_CUBE_CENTRE_MM", "work_centre_mm",
           "draw_tracker_pose"]

#: centre of the seed 000 Table 1 test cube (P1 of Table 2), robot base frame, mm
ISO_CUBE_CENTRE_MM = (0.0, 1700.0, 1400.0)


@dataclass(frozen=True)
class TrackerSource:
    """What a tracker fake streams: the arm's reflector through the tracker model.

    Attributes
    ----------
    clock : SimClock or ManualClock
    rate_hz : float
    tracker : TrackerModel
    """

    clock: Any
    rate_hz: float
    tracker: TrackerModel
    _arm: SimArm = field(repr=False)
    #: a diagnosed motion model whose creep, mode and drift the readings show (None: the arm alone)
    _motion: Any = field(default=None, repr=False)
    _seed: int = field(default=0, repr=False)

    def measure(self, t_sim) -> tuple[np.ndarray, np.ndarray]:
        """``(xyz_mm (N, 3) in the tracker frame, valid (N,))`` at world times ``t_sim``.

        The noise of a sample is drawn per move of the arm and sample index since
        that move started (:meth:`SimArm.noise_epochs`,
        :meth:`TrackerModel.epoch_noise`): a move that names itself is measured
        with the same noise in any world of the seed, so a resumed run meets
        the samples of the run it resumes, not only its stops.
        """
        def noise(t):
            return self.tracker.epoch_noise(t, *self._arm.noise_epochs(t))

        position = self._arm.tool_position_mm
        if self._motion is not None:
            from fakes.sim.motion_offsets import arm_motion_offsets_mm

            def position(t, _arm=self._arm, _model=self._motion, _seed=self._seed):
                tt = np.asarray(t, dtype=float)
                p = _arm.tool_position_mm(tt)
                return p + arm_motion_offsets_mm(_arm, tt, _model, _seed).reshape(p.shape)

        return self.tracker.measure(t_sim, position, noise_fn=noise)

    def orientation(self, t_sim) -> np.ndarray:
        """Rotation matrices (N, 3, 3) a 6-DoF target on the tool reports at world times ``t_sim``: the arm's
        true TCP rotation in the tracker frame, with the tracker's angle noise (:mod:`fakes.sim.six_dof`)."""
        from fakes.sim.six_dof import target_rotation

        return target_rotation(self.tracker, self._arm.tool_pose, t_sim)

    def sample_times(self, t_start: float, t_end: float) -> np.ndarray:
        """World times of the device's grid samples in ``[t_start, t_end)``."""
        return self.tracker.sample_times(t_start, t_end)

    def device_time(self, t_sim) -> np.ndarray:
        """Device timestamps of world times."""
        return self.tracker.device_time(t_sim)


@dataclass
class World:
    """The simulated cell (build it with :func:`make_world`).

    Attributes
    ----------
    clock : SimClock or ManualClock
    robot : RobotSpec
    arm : SimArm
    tracker : TrackerModel
    scanner : SimScanner
    rng : numpy.random.Generator
        A free stream for users of the world (fault injection, ...).
    seed : int
    work_centre_mm : ndarray, shape (3,)
        Centre of the working volume (the ISO cube centre for
        ``industrial-3100``, else the nominal TCP at home), base frame.
    trailer : SimTrailer or None
        Created by :meth:`get_trailer`.
    """

    clock: Any
    robot: RobotSpec
    arm: SimArm
    tracker: TrackerModel
    scanner: SimScanner
    rng: np.random.Generator
    seed: int
    work_centre_mm: np.ndarray
    trailer: Any = None
    #: the diagnosed motion model the cell runs with (station.models.motion_effects.MotionModel), or None
    motion_model: Any = None
    _scan_rng: np.random.Generator = field(default=None, repr=False)
    _trailer_rng: np.random.Generator = field(default=None, repr=False)
    _closed: bool = field(default=False, repr=False)

    @property
    def base_T_tracker(self) -> np.ndarray:
        """Tracker pose in the robot base frame (the truth a registration estimates)."""
        return self.tracker.base_T_tracker.copy()

    def tracker_source(self) -> TrackerSource:
        """The object a tracker fake measures (``clock``, ``rate_hz``, ``measure``)."""
        return TrackerSource(self.clock, self.tracker.rate_hz, self.tracker, self.arm, self.motion_model, self.seed)

    def scan(self, t_sim: float | None = None) -> ScanResult:
        """Scan the jig at the arm's true pose at ``t_sim`` (default now)."""
        t = float(self.clock.now()) if t_sim is None else float(t_sim)
        return self.scanner.render(self.arm.tool_pose(t), self._scan_rng)

    def get_trailer(self):
        """The simulated trailer (created on first use, on this world's clock)."""
        if self.trailer is None:
            try:
                from fakes.sim.trailer import SimTrailer
            except ImportError as exc:
                raise ConfigError(f"the trailer simulation is not available: {exc}") from exc
            self.trailer = SimTrailer(self.clock, rng=self._trailer_rng)
        return self.trailer

    def close(self) -> None:
        """Release the world (stops the arm; idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            if self.arm.state == "moving":
                self.arm.protective_stop()
        except StationError:
            pass
        closer = getattr(self.trailer, "close", None)
        if callable(closer):
            closer()

    def __enter__(self) -> "World":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def carried(self) -> dict:
        """What a cell started again to resume a run carries on from this one (``make_world`` keywords): the
        arm's temperature rise now (``arm_rise``), when it has a thermal drift."""
        if self.arm.heat is None:
            return {}
        t = float(self.clock.now())
        return {"arm_rise": [t, float(self.arm.temperature_rise_K(t)[0])]}

    def describe(self) -> dict:
        """JSON-able truth of the world (for people, tests and truth files)."""
        return {
            "seed": self.seed,
            "robot": self.robot.name,
            "work_centre_mm": self.work_centre_mm.tolist(),
            "effects": None if self.arm.effects is None else self.arm.effects.to_dict(),
            "servo": None if self.arm.servo is None else self.arm.servo.to_dict(),
            "stop_sigma_rad": self.arm.stop_sigma_rad.tolist(),
            "profile": self.arm.profile,
            "motion_model": None if self.motion_model is None else _model_dict(self.motion_model),
            "payload_kg": self.arm.payload_kg,
            "tracker": self.tracker.describe(),
            "scanner": self.scanner.describe(),
        }


#: a motion model whose command's jerk time is shorter than this moves on a trapezoid, s
MODEL_TRAPEZOID_JERK_S = 0.01


def _model_dict(m: MotionModel) -> dict:
    return {"servo_hz": m.servo_hz, "servo_damping": m.servo_zeta, "jerk_time_s": m.jerk_time_s,
            "deceleration_mm_s2": m.deceleration_mm_s2, "effects": m.effects}


def realistic_servo(rng: np.random.Generator, spec: RobotSpec | None = None) -> ServoParams:
    """Axis loops of the arm ``spec``: an industrial arm's 6-12 Hz natural frequency, damping 0.6-0.9; a
    UR-style cobot's (``spec.controller == "ur"``) 12-20 Hz, damping 0.75-1.0.

    Position loops of large arms close at roughly 5-15 Hz (limited by the
    structure's first resonances); the damping is tuned for little overshoot.
    A UR arm measured by a tracker (issue 42) overshoots its target by about
    4 um along travel and settles within 0.03 s after UR's trapezoidal
    ramps: the loop of the motion look-alike of that arm
    (``tests/motion/real_arm.py``); an industrial arm's loop under UR's
    abrupt end of deceleration would ring by a millimetre for 0.2 s.
    """
    if spec is not None and spec.controller == "ur":
        return ServoParams(2.0 * np.pi * rng.uniform(12.0, 20.0, 6), rng.uniform(0.75, 1.0, 6))
    return ServoParams(2.0 * np.pi * rng.uniform(6.0, 12.0, 6), rng.uniform(0.6, 0.9, 6))


def work_centre_mm(spec: RobotSpec) -> np.ndarray:
    """Centre of a cell's working volume, base frame, mm: the ISO cube centre for ``industrial-3100``, else the
    nominal TCP at home."""
    if spec.name == "industrial-3100":
        return np.array(ISO_CUBE_CENTRE_MM, dtype=float)
    return np.asarray(kin.tool_position(spec.dh_nominal, spec.home_q_rad), dtype=float)


def draw_tracker_pose(centre: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Tracker 2-4 m (horizontally) from ``centre``, levelled, random heading.

    Rejects spots within 1.5 m of the robot's base axis. Height 1.0-1.7 m
    above the base (a tripod).
    """
    for _ in range(1000):  # rejection sampling of one spot
        r = rng.uniform(2000.0, 4000.0)
        az = rng.uniform(0.0, 2.0 * np.pi)
        xy = centre[:2] + r * np.array([np.cos(az), np.sin(az)])
        if np.hypot(*xy) >= 1500.0:
            break
    z = rng.uniform(1000.0, 1700.0)
    yaw = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [xy[0], xy[1], z]
    return T


def make_world(
    robot: str | RobotSpec = "industrial-3100",
    seed: int = 0,
    time_scale: float = 1.0,
    clock=None,
    effects: str | EffectSet | None = "realistic",
    tracker_rate_hz: float = 1000.0,
    *,
    servo: str | ServoParams | None = "realistic",
    stop_sigma_mm: str | float | None = "auto",
    payload_kg: float = 0.0,
    profile: str | None = None,
    history_s: float = 3600.0,
    tracker_mpe_a_um: float = 15.0,
    tracker_mpe_b_um_per_m: float = 6.0,
    tracker_latency_s: float | None = None,
    tracker_clock_offset_s: float = 0.0,
    tracker_noise: TrackerNoise | None = None,
    beam_breaks=(),
    random_breaks_per_hour: float = 0.0,
    base_T_tracker=None,
    jig: CornerJig | None = None,
    base_T_scanner=None,
    start_s: float = 0.0,
    joint_defect=None,
    warmup=None,
    motion_model: MotionModel | None = None,
    arm_rise=None,
) -> World:
    """Build a simulated cell.

    Parameters
    ----------
    robot : str or RobotSpec
        Robot name (:func:`station.models.robots.get_robot`) or a spec.
    seed : int
        Seed of every random choice (>= 0).
    time_scale : float
        Simulated seconds per real second of a new :class:`SimClock`
        (ignored when ``clock`` is given).
    clock : SimClock or ManualClock, optional
        Use this clock (e.g. ``ManualClock()`` for offline runs).
    effects : "realistic", EffectSet or None
        Error effects of the true arm (``"realistic"``: drawn by
        :func:`station.models.effects.realistic_effects`; ``None``: nominal).
    tracker_rate_hz : float
        Tracker output rate, 10-3000 Hz.
    servo : "realistic", ServoParams or None
        Axis dynamics (``None``: perfect tracking).
    stop_sigma_mm : "auto", "realistic", float or None
        Repeatability scatter per stop (TCP, 1 sigma per coordinate at home).
        ``"realistic"``: drawn from the model's ``robot.stop_scatter_mm``;
        ``"auto"``: realistic when ``effects`` is ``"realistic"``, else none.
    payload_kg : float
        Mass at the TCP.
    profile : {"scurve", "trapezoid"}, optional
        Velocity profile of the arm's moves (default: trapezoid for a UR
        controller, which plans its moves so, else S-curve).
    history_s : float
        Past the arm keeps for queries (see :mod:`fakes.sim.arm`).
    tracker_mpe_a_um, tracker_mpe_b_um_per_m : float
        Tracker MPE ``a + b R`` (2 sigma per coordinate): the session's systematic error.
    tracker_latency_s, tracker_clock_offset_s : float
        Tracker timing (see :mod:`fakes.sim.tracker`; latency default the noise model's).
    tracker_noise : TrackerNoise, optional
        Reading noise (white + wander; default the measured Leica figures of
        :mod:`station.models.tracker_noise`).
    beam_breaks : iterable of (float, float)
        Scheduled beam breaks, simulated seconds.
    random_breaks_per_hour : float
        Rate of random beam breaks.
    base_T_tracker : array_like, shape (4, 4), optional
        Tracker pose; default drawn 2-4 m from the work centre.
    jig : CornerJig, optional
        Jig on the tool (default 60 mm edges, corner at the TCP).
    base_T_scanner : array_like, shape (4, 4), optional
        Scanner pose; default 700 mm from the TCP at home, facing the tool.
    start_s : float
        Simulated time at which the new clock starts (>= 0; ignored when
        ``clock`` is given). The cell was built at 0 (``warmup_origin_s``):
        a cell started again to resume a run continues the time of the one
        before, so device time never repeats (its arm cold at the start
        unless ``arm_rise`` says how warm the last cell left it).
    joint_defect : dict or JointDefect, optional
        A localised flaw of one joint (``{"joint", "centre_deg", "width_deg",
        "amplitude_deg"}``, :mod:`fakes.sim.joint_defect`): the "one pose out"
        robot of the acceptance fixtures.
    warmup : (float, float), optional
        The arm's thermal drift ``(dT_max_K, tau_s)`` in place of the one drawn with the effects (a drift test's
        known truth; needs effects): its links (steel) warm while its joints move and cool at rest, to the
        steady rise ``dT_max`` under the heat input of continuous ISO 9283 cycling, with the time constant
        ``tau`` (:mod:`fakes.sim.heat`); the arm is cold when the cell is built.
    arm_rise : (float, float), optional
        ``(t_s, dT_K)``: the arm's temperature rise ``dT_K`` at simulated time ``t_s`` (what a cell that ran
        before left, :meth:`World.carried`): a cell started again to resume a run starts with its arm that
        warm, cooled at rest from ``t_s`` to the new clock's start (default: cold).
    motion_model : MotionModel, optional
        A diagnosed arm's motion (``station diagnose motion --model-out``,
        :mod:`station.models.motion_effects`): its loop on every axis (instead
        of ``servo``), its profile when ``profile`` is not given (trapezoid when
        its jerk time is short), and its creep, structural mode and the
        tracker's drift on the readings along each move
        (:mod:`fakes.sim.motion_offsets`).

    Returns
    -------
    World
        The arm rests at ``robot.home_q_rad``.

    Raises
    ------
    ConfigError
        Any bad option; the message names it. Nothing is left half-built.
    """
    # ---- validate everything first
    if isinstance(robot, RobotSpec):
        spec = robot
    elif isinstance(robot, str):
        spec = get_robot(robot)
    else:
        raise ConfigError(f"`robot` must be a robot name or a RobotSpec, got {type(robot).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"`seed` must be a non-negative integer, got {seed!r}")
    seed = int(seed)
    if clock is None:
        time_scale = finite_number(time_scale, "time_scale", positive=True)
        start_s = finite_number(start_s, "start_s", nonneg=True)
    elif not (hasattr(clock, "now") and hasattr(clock, "sleep_until")):
        raise ConfigError(f"`clock` must be a SimClock or ManualClock, got {type(clock).__name__}")
    if not (isinstance(effects, EffectSet) or effects is None or effects == "realistic"):
        raise ConfigError(f"`effects` must be 'realistic', an EffectSet or None, got {effects!r}")
    tracker_rate_hz = finite_number(tracker_rate_hz, "tracker_rate_hz", positive=True)
    lo, hi = TRACKER_RATE_RANGE_HZ
    if not (lo <= tracker_rate_hz <= hi):
        raise ConfigError(f"`tracker_rate_hz` must be within {lo:g}-{hi:g} Hz, got {tracker_rate_hz!r}")
    if not (isinstance(servo, ServoParams) or servo is None or servo == "realistic"):
        raise ConfigError(f"`servo` must be 'realistic', a ServoParams or None, got {servo!r}")
    if motion_model is not None:
        if not isinstance(motion_model, MotionModel):
            raise ConfigError(f"`motion_model` must be a MotionModel, got {type(motion_model).__name__}")
        servo = ServoParams.uniform(*servo_of(motion_model))
        if profile is None:
            profile = "trapezoid" if motion_model.jerk_time_s < MODEL_TRAPEZOID_JERK_S else "scurve"
    if stop_sigma_mm in ("auto", "realistic") or stop_sigma_mm is None:
        pass
    else:
        stop_sigma_mm = finite_number(stop_sigma_mm, "stop_sigma_mm", nonneg=True)
    payload_kg = finite_number(payload_kg, "payload_kg", nonneg=True)
    if profile is None:
        profile = "trapezoid" if spec.controller == "ur" else "scurve"
    if profile not in PROFILE_KINDS:
        raise ConfigError(f"`profile` must be one of {PROFILE_KINDS}, got {profile!r}")
    history_s = finite_number(history_s, "history_s", positive=True)
    for name, val in (("tracker_mpe_a_um", tracker_mpe_a_um), ("tracker_mpe_b_um_per_m", tracker_mpe_b_um_per_m),
                      ("tracker_latency_s", 0.0 if tracker_latency_s is None else tracker_latency_s),
                      ("random_breaks_per_hour", random_breaks_per_hour)):
        finite_number(val, name, nonneg=True)
    if tracker_noise is not None and not isinstance(tracker_noise, TrackerNoise):
        raise ConfigError(f"`tracker_noise` must be a TrackerNoise, got {type(tracker_noise).__name__}")
    finite_number(tracker_clock_offset_s, "tracker_clock_offset_s")
    try:
        breaks = [(float(a), float(b)) for a, b in beam_breaks]
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"`beam_breaks` must be (t_start, t_end) pairs: {exc}") from exc
    if warmup is not None:
        try:
            dT_max, tau = (float(v) for v in warmup)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"`warmup` must be (dT_max_K, tau_s), got {warmup!r}") from exc
        finite_number(dT_max, "warmup dT_max_K", nonneg=True)
        finite_number(tau, "warmup tau_s", positive=True)
        if effects is None:
            raise ConfigError("`warmup` needs the arm's effects (effects=None is the nominal arm)")
        warmup = (dT_max, tau)
    if arm_rise is not None:
        try:
            rise_t, rise_K = (float(v) for v in arm_rise)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"`arm_rise` must be (t_s, dT_K), got {arm_rise!r}") from exc
        finite_number(rise_t, "arm_rise t_s")
        finite_number(rise_K, "arm_rise dT_K", nonneg=True)
        arm_rise = (rise_t, rise_K)
    if jig is not None and not isinstance(jig, CornerJig):
        raise ConfigError(f"`jig` must be a CornerJig, got {type(jig).__name__}")

    # ---- independent random streams
    ss = np.random.SeedSequence(seed)
    s_eff, s_servo, s_track, s_stop, s_scan, s_user, s_trailer, s_tnoise = ss.spawn(8)

    if effects == "realistic":
        effect_set = realistic_effects(spec, np.random.default_rng(s_eff))
    else:
        effect_set = effects
    if warmup is not None:
        effect_set = effect_set.with_params("thermal_drift", warmup).switched("thermal_drift", True)
    servo_params = realistic_servo(np.random.default_rng(s_servo), spec) if servo == "realistic" else servo
    rng_stop = np.random.default_rng(s_stop)
    if stop_sigma_mm == "auto":
        stop_sigma_mm = "realistic" if effects == "realistic" else None
    if stop_sigma_mm is None:
        stop_sigma = np.zeros(6)
    elif stop_sigma_mm == "realistic":
        stop_sigma = realistic_stop_sigma_rad(spec, rng_stop)
    else:
        stop_sigma = realistic_stop_sigma_rad(spec, rng_stop, sigma_mm=float(stop_sigma_mm))

    centre = work_centre_mm(spec)
    rng_track = np.random.default_rng(s_track)
    T_track = draw_tracker_pose(centre, rng_track) if base_T_tracker is None else base_T_tracker
    tracker_seed = int(np.random.default_rng(s_tnoise).integers(0, 2**31 - 1))
    try:
        tracker = TrackerModel(
            T_track,
            tracker_rate_hz,
            mpe_a_um=tracker_mpe_a_um,
            mpe_b_um_per_m=tracker_mpe_b_um_per_m,
            latency_s=tracker_latency_s,
            clock_offset_s=tracker_clock_offset_s,
            beam_breaks=breaks,
            random_breaks_per_hour=random_breaks_per_hour,
            seed=tracker_seed,
            noise=tracker_noise,
        )
    except ConfigError as exc:
        raise ConfigError(f"tracker: {exc}") from exc

    jig = jig or CornerJig()
    if base_T_scanner is None:
        T_home = kin.fk(spec.dh_nominal, spec.home_q_rad)
        fp = T_home[:3, :3] @ jig.feature_point_tool_mm + T_home[:3, 3]
        eye = fp + 700.0 * T_home[:3, 2]
        base_T_scanner = look_at(eye, fp)
    try:
        scanner = SimScanner(base_T_scanner, jig)
    except ConfigError as exc:
        raise ConfigError(f"scanner: {exc}") from exc

    clk = clock if clock is not None else SimClock(time_scale, start=start_s, lockstep=True)
    arm = SimArm(
        spec,
        clk,
        effects=effect_set,
        servo=servo_params,
        stop_sigma_rad=stop_sigma,
        rng=rng_stop,
        profile=profile,
        history_s=history_s,
        payload_kg=payload_kg,
        joint_defect=None if joint_defect is None else JointDefect.from_dict(joint_defect),
    )
    if clock is None:
        arm.warmup_origin_s = 0.0
    if arm_rise is not None and arm.heat is not None:
        arm.heat = arm.heat.cooled_from(*arm_rise)
    return World(
        clock=clk,
        robot=spec,
        arm=arm,
        tracker=tracker,
        scanner=scanner,
        rng=np.random.default_rng(s_user),
        seed=seed,
        work_centre_mm=np.asarray(centre, dtype=float),
        motion_model=motion_model,
        _scan_rng=np.random.default_rng(s_scan),
        _trailer_rng=np.random.default_rng(s_trailer),
    )


__all__ += ["ManualClock", "SimClock"]
