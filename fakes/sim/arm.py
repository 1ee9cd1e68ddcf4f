"""The simulated arm: a move queue on the world clock, servo dynamics, true kinematics.

The controller side (what a robot controller believes) plans every move with
the **nominal** model ``robot.dh_nominal`` (:mod:`station.models.motion`).
The true arm then follows that reference through

1. a random **stopping error** per stop (repeatability scatter: each move's
   end gets an independent Gaussian joint offset ``N(0, stop_sigma_rad)``,
   blended in along the move's path parameter, so consecutive visits of one
   pose scatter like ISO 9283 RP),
2. the per-axis **servo** (equation (S1) of :mod:`station.models.motion`,
   exact closed form; ``servo=None`` tracks perfectly),
3. the **error effects** (:class:`station.models.effects.EffectSet`) with a
   context of the direction of the last motion of each joint (sign of the
   commanded velocity, kept while the joint rests; the small stopping
   offsets do not flip it: they stay inside the reducer's dead band), the links' temperature
   rise from the joints' motion (:mod:`fakes.sim.heat`: moves warm the arm, rest cools it), the
   time since ``warmup_origin_s`` and the payload,
4. forward kinematics (``kinematics.fk``) of the resulting true table and
   joint angles.

The queue is analytic: queueing a move computes its whole reference (piecewise
cubic segments) and the servo state at each segment boundary at once, so any
time can be queried afterwards, vectorised (:meth:`SimArm.actual_q_rad`,
:meth:`SimArm.tool_pose`, :meth:`SimArm.tool_position_mm`). A move starts at
``max(clock.now(), end of the previous move)``. Nothing runs in a thread; the
arm is thread-safe (one lock around the queue).

Memory
------
Each segment costs about 540 bytes (two sets of cubic coefficients, the servo
state and the motion direction at its start). A joint move has at most 8
segments (7 profile segments + the hold after it); a linear move has one per
interpolation knot (50 per second of motion at the default 20 ms). Segments
that ended more than ``history_s`` (default 3600 s) before the clock's present
are dropped when new moves are queued (in batches: once at least 1024 of them,
and half the store, are that old), so a long run keeps at most about twice
that window, however long it runs (an hour of ISO 9283 cycles with joint moves
is ~16,000 segments, ~9 MB). Asking for a time before the retained history
raises :class:`~station.errors.DataError`.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from station.errors import DataError, DeviceFault, DeviceTimeout
from station.models import kinematics as kin
from station.models import motion
from station.models.effects import EffectContext, EffectSet
from station.models.motion import PiecewiseCubic, ServoParams
from fakes.sim.heat import ArmHeat, heat_input

__all__ = ["Move", "SimArm", "ARM_STATES"]

#: values of :attr:`SimArm.state`
ARM_STATES = ("idle", "moving", "protective_stop")

_N = 6
#: in-position band of a stop point ("fine"), rad: every axis's servo error, and its rate over the axis's
#: bandwidth, within it (about 0.01 mm at a metre; below the arm's repeatability scatter)
IN_POSITION_RAD = 1e-5
_CHUNK = 32768  # samples per FK chunk (bounds peak memory of queries)


@dataclass
class Move:
    """A queued motion.

    Attributes
    ----------
    kind : str
        ``"joint"``, ``"linear"``, ``"dwell"``, ``"settle"`` (in position at a stop point) or ``"stop"``.
    t_start, t_end : float
        Simulated start and end of the commanded profile, s.
    q_target_rad : ndarray, shape (6,)
        Commanded joint angles at the end (the controller's belief).
    move_id : int
        Sequence number on this arm.
    cancelled : bool
        Set when a protective stop cut the move short.
    """

    kind: str
    t_start: float
    t_end: float
    q_target_rad: np.ndarray
    move_id: int
    cancelled: bool = field(default=False)
    #: the identity the move was queued with (its stopping error and its measurement noise), if any
    noise_key: tuple | None = field(default=None)

    @property
    def duration_s(self) -> float:
        return self.t_end - self.t_start


class _Segments:
    """Growing arrays of reference segments; segment k spans [t0[k], t0[k+1])."""

    def __init__(self, t0: float, q_rad: np.ndarray, capacity: int = 256) -> None:
        self.t0 = np.empty(capacity)
        self.c_cmd = np.zeros((capacity, 4, _N))
        self.c_srv = np.zeros((capacity, 4, _N))
        self.E = np.zeros((capacity, _N))
        self.Ed = np.zeros((capacity, _N))
        self.dir = np.zeros((capacity, _N))
        self.n = 1
        self.t0[0] = t0
        self.c_cmd[0, 0] = q_rad
        self.c_srv[0, 0] = q_rad

    def _grow(self, need: int) -> None:
        cap = self.t0.size
        if need <= cap:
            return
        new = max(need, 2 * cap)
        for name in ("t0", "c_cmd", "c_srv", "E", "Ed", "dir"):
            old = getattr(self, name)
            arr = np.zeros((new,) + old.shape[1:])
            arr[: self.n] = old[: self.n]
            setattr(self, name, arr)

    def append(self, t0, c_cmd, c_srv, E, Ed, dirs) -> None:
        k = len(t0)
        self._grow(self.n + k)
        sl = slice(self.n, self.n + k)
        self.t0[sl] = t0
        self.c_cmd[sl] = c_cmd
        self.c_srv[sl] = c_srv
        self.E[sl] = E
        self.Ed[sl] = Ed
        self.dir[sl] = dirs
        self.n += k

    def truncate(self, n: int) -> None:
        self.n = max(1, min(n, self.n))

    def drop_before(self, t: float) -> int:
        """Drop segments that ended before ``t`` (keep at least the last one)."""
        m = int(np.searchsorted(self.t0[: self.n], t, side="right")) - 1
        m = min(max(m, 0), self.n - 1)
        if m < max(1024, self.n // 2):
            return 0
        for name in ("t0", "c_cmd", "c_srv", "E", "Ed", "dir"):
            arr = getattr(self, name)
            setattr(self, name, arr[m : self.n].copy())
        self.n -= m
        self._grow(2 * self.n)
        return m

    def locate(self, t: np.ndarray) -> np.ndarray:
        idx = np.searchsorted(self.t0[: self.n], t, side="right") - 1
        if idx.size and idx.min() < 0:
            raise DataError(
                f"time {float(t[idx < 0][0]):.6g} s is before the arm's retained history "
                f"(starts at {self.t0[0]:.6g} s)"
            )
        return idx


def _poly(c: np.ndarray, tau: np.ndarray, deriv: int = 0) -> np.ndarray:
    tau = tau[:, None]
    if deriv == 0:
        return c[:, 0] + tau * (c[:, 1] + tau * (c[:, 2] + tau * c[:, 3]))
    if deriv == 1:
        return c[:, 1] + tau * (2.0 * c[:, 2] + 3.0 * tau * c[:, 3])
    return 2.0 * c[:, 2] + 6.0 * tau * c[:, 3]


def _end_directions(traj: PiecewiseCubic, dir_start: np.ndarray) -> np.ndarray:
    """Direction of the last motion at the start of each segment and after the last one.

    Returns (K + 1, 6): row k is the direction entering segment k, the last
    row the direction after the move.
    """
    K = traj.n_segments
    out = np.empty((K + 1, _N))
    out[0] = dir_start
    if K == 0:
        return out
    d = np.diff(traj.t_knots)
    c = traj.coeffs
    end = _poly(c, d)
    before = _poly(c, 0.9 * d)
    step = np.sign(end - before)  # (K, 6): direction at each segment's end, 0 if at rest
    for k in range(K):  # forward fill over segments (not samples)
        out[k + 1] = np.where(step[k] != 0, step[k], out[k])
    return out


class SimArm:
    """Simulated 6-axis arm driven on a simulated clock.

    Parameters
    ----------
    robot : RobotSpec
    clock : SimClock or ManualClock
    effects : EffectSet, optional
        True-arm error effects (``None``: the nominal arm).
    servo : ServoParams, optional
        Axis dynamics (``None``: perfect tracking).
    stop_sigma_rad : array_like, shape (6,), optional
        1-sigma of the random joint offset at each stop (``None``: zero).
    rng : numpy.random.Generator, optional
        Source of the stopping errors.
    profile : {"scurve", "trapezoid"}
        Velocity profile of every move.
    jerk_time_s : float
        Time to ramp the acceleration up (scurve jerk limit).
    ipo_period_s : float
        Interpolation knot spacing of linear moves.
    history_s : float
        How much past the arm keeps for queries (see module docstring).
    payload_kg : float
        Mass at the TCP (joint compliance).
    joint_defect : JointDefect, optional
        A localised flaw of one joint (a damaged gear tooth): off by up to its
        amplitude over a few degrees, exact elsewhere.
    """

    def __init__(
        self,
        robot,
        clock,
        *,
        effects: EffectSet | None = None,
        servo: ServoParams | None = None,
        stop_sigma_rad=None,
        rng: np.random.Generator | None = None,
        profile: str = "scurve",
        jerk_time_s: float = 0.1,
        ipo_period_s: float = 0.02,
        history_s: float = 3600.0,
        payload_kg: float = 0.0,
        joint_defect=None,
    ) -> None:
        if profile not in motion.PROFILE_KINDS:
            raise DataError(f"`profile` must be one of {motion.PROFILE_KINDS}, got {profile!r}")
        for name, val in (("jerk_time_s", jerk_time_s), ("ipo_period_s", ipo_period_s), ("history_s", history_s)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise DataError(f"`{name}` must be a finite number > 0, got {val!r}")
        if effects is not None and not isinstance(effects, EffectSet):
            raise DataError(f"`effects` must be an EffectSet or None, got {type(effects).__name__}")
        if servo is not None and not isinstance(servo, ServoParams):
            raise DataError(f"`servo` must be a ServoParams or None, got {type(servo).__name__}")
        sigma = np.zeros(_N) if stop_sigma_rad is None else np.asarray(stop_sigma_rad, dtype=float)
        if sigma.shape != (_N,) or not np.all(np.isfinite(sigma)) or np.any(sigma < 0):
            raise DataError(f"`stop_sigma_rad` must be 6 finite values >= 0, got {stop_sigma_rad!r}")
        self.robot = robot
        self.clock = clock
        self.effects = effects
        #: a localised flaw of one joint (:class:`fakes.sim.joint_defect.JointDefect`), or None
        self.joint_defect = joint_defect
        self.servo = servo
        self.stop_sigma_rad = sigma
        self.profile = profile
        self.jerk_time_s = float(jerk_time_s)
        self.ipo_period_s = float(ipo_period_s)
        self.history_s = float(history_s)
        self._rng = rng if rng is not None else np.random.default_rng(0)
        #: root of the keyed stopping errors (a move that names itself draws from its own stream)
        self._stop_root = int(self._rng.integers(0, 2**63))
        self._lock = threading.RLock()
        t_now = float(clock.now())
        self.warmup_origin_s = t_now
        #: the links' temperature rise from the joints' motion (fakes.sim.heat), with a thermal drift only
        self.heat = None
        if effects is not None and effects.is_enabled("thermal_drift"):
            dT_max, tau = (float(v) for v in effects.get("thermal_drift"))
            self.heat = ArmHeat(dT_max, tau, t_now)
        self.payload_kg = payload_kg
        q_home = np.asarray(robot.home_q_rad, dtype=float).copy()
        # the arm has rested at home "forever" before the clock's start, so
        # instruments with latency can look a little into the past
        self._seg = _Segments(t_now - 1e6, q_home)
        self._t_end = t_now
        self._q_cmd_end = q_home.copy()
        self._delta_end = np.zeros(_N)
        self._protective = False
        self._moves: list[Move] = []
        self._next_id = 0
        self._max_moves_kept = 10000
        # start and key of every motion (noise epochs of the instruments that measure the arm); (0,) is the
        # rest since the arm was made
        self._epoch_t: list[float] = [-math.inf]
        self._epoch_key: list[tuple] = [(0,)]
        # external force on the TCP (base frame, N) from each instant on: the load of a static compliance test
        self._force_t: list[float] = [-math.inf]
        self._force_N: list[np.ndarray] = [np.zeros(3)]

    # ------------------------------------------------------------------ state
    @property
    def payload_kg(self) -> float:
        return self._payload_kg

    @payload_kg.setter
    def payload_kg(self, value: float) -> None:
        v = float(value)
        if not (math.isfinite(v) and v >= 0):
            raise DataError(f"`payload_kg` must be finite and >= 0, got {value!r}")
        self._payload_kg = v

    @property
    def state(self) -> str:
        """``"idle"``, ``"moving"`` or ``"protective_stop"`` at the clock's present."""
        with self._lock:
            if self._protective:
                return "protective_stop"
            return "moving" if self.clock.now() < self._t_end else "idle"

    @property
    def queue_end_s(self) -> float:
        """Simulated time at which the last queued move ends."""
        with self._lock:
            return self._t_end

    @property
    def moves(self) -> list[Move]:
        """The most recent queued moves (oldest first; bounded list)."""
        with self._lock:
            return list(self._moves)

    def in_position_s(self, tol_rad: float = IN_POSITION_RAD, step_s: float = 0.002, horizon_s: float = 2.0) -> float:
        """Simulated time at which the arm, holding its queue's last target, is in position: every axis's servo
        error ``e`` and ``|de/dt| / omega`` within ``tol_rad`` (S1), as a controller's fine stop point waits for
        before the program goes on. The queue's end with an ideal servo; at most ``horizon_s`` after it."""
        with self._lock:
            t_end = float(self._t_end)
            if self.servo is None:
                return t_end
            seg = self._seg
            k = seg.n - 1  # the hold after the queue's last move
            dt = np.arange(int(horizon_s / step_s) + 1) * step_s
            e, ed = motion.servo_step(seg.E[k : k + 1], seg.Ed[k : k + 1], -2.0 * seg.c_srv[k : k + 1, 2],
                                      -6.0 * seg.c_srv[k : k + 1, 3], t_end - seg.t0[k] + dt, self.servo)
            inside = np.all(np.hypot(e, ed / np.asarray(self.servo.omega_rad_s)) < tol_rad, axis=1)
            return t_end + float(dt[np.argmax(inside)] if inside.any() else horizon_s)

    # ---------------------------------------------------------------- queueing
    def _check_ready(self) -> None:
        if self._protective:
            raise DeviceFault("the arm is in protective stop; call reset() before moving")

    def _check_joint_target(self, q: np.ndarray) -> None:
        lim = np.asarray(self.robot.joint_limits_rad)
        bad = np.nonzero((q < lim[:, 0] - 1e-12) | (q > lim[:, 1] + 1e-12))[0]
        if bad.size:
            j = int(bad[0])
            raise DeviceFault(
                f"joint {j + 1} target {math.degrees(q[j]):.4f} deg is outside the joint limits "
                f"[{math.degrees(lim[j, 0]):.4f}, {math.degrees(lim[j, 1]):.4f}] deg"
            )

    def _draw_delta(self, noise_key=None) -> np.ndarray:
        """The stopping error of the next move: from the move's own stream when it names itself
        (``noise_key``: integers, e.g. program, run, cycle, instruction), else the next draw of the arm's."""
        if not np.any(self.stop_sigma_rad):
            return np.zeros(_N)
        rng = self._rng if noise_key is None else np.random.default_rng([self._stop_root, *map(int, noise_key)])
        return rng.normal(0.0, 1.0, _N) * self.stop_sigma_rad

    def _state_at(self, t: float):
        """Reference and servo state of the store at time ``t`` (scalar)."""
        seg = self._seg
        k = int(seg.locate(np.array([t]))[0])
        tau = np.array([t - seg.t0[k]])
        c_cmd = seg.c_cmd[k : k + 1]
        c_srv = seg.c_srv[k : k + 1]
        if self.servo is not None:
            e, ed = motion.servo_step(seg.E[k : k + 1], seg.Ed[k : k + 1], -2.0 * c_srv[:, 2], -6.0 * c_srv[:, 3], tau, self.servo)
        else:
            e = ed = np.zeros((1, _N))
        v_srv = _poly(c_srv, tau, 1)[0]
        v_cmd = _poly(c_cmd, tau, 1)[0]
        direction = np.where(np.abs(v_cmd) > 1e-12, np.sign(v_cmd), seg.dir[k])
        return {
            "k": k,
            "r_cmd": _poly(c_cmd, tau)[0],
            "v_cmd": v_cmd,
            "r_srv": _poly(c_srv, tau)[0],
            "v_srv": v_srv,
            "e": e[0],
            "ed": ed[0],
            "dir": direction,
        }

    def _append(self, t_start: float, traj_cmd: PiecewiseCubic, traj_srv: PiecewiseCubic, kind: str,
                noise_key=None) -> Move:
        """Append a planned move (cmd and srv share knots) at ``t_start``, then a hold."""
        seg = self._seg
        st = self._state_at(t_start)
        # the hold in force at t_start ends there (overwrite it if it starts there)
        if seg.t0[seg.n - 1] >= t_start and seg.n > 1:
            seg.truncate(seg.n - 1)
        K = traj_srv.n_segments
        if self.servo is not None:
            E, Ed = motion.propagate_servo(traj_srv, st["e"], st["ed"], self.servo)
        else:
            E = Ed = np.zeros((K + 1, _N))
        dirs = _end_directions(traj_cmd, st["dir"])
        hold_cmd = np.zeros((1, 4, _N))
        hold_cmd[0, 0] = traj_cmd.q_end
        hold_srv = np.zeros((1, 4, _N))
        hold_srv[0, 0] = traj_srv.q_end
        t0 = t_start + traj_srv.t_knots  # K + 1 starts (the last one is the hold's)
        seg.append(
            t0,
            np.concatenate([traj_cmd.coeffs, hold_cmd]),
            np.concatenate([traj_srv.coeffs, hold_srv]),
            E,
            Ed,
            dirs,
        )
        t_end = t_start + traj_srv.duration_s
        if self.heat is not None:  # the move heats the arm by its joints' travel over its time (fakes.sim.heat)
            q_knots = np.concatenate([traj_srv.coeffs[:, 0, :], traj_srv.q_end[None]])
            travel = np.sum(np.abs(np.diff(q_knots, axis=0)), axis=0)
            self.heat.add_move(t_start, t_end, heat_input(travel, traj_srv.duration_s,
                                                          self.robot.joint_speed_limits_rad_s))
        self._t_end = t_end
        self._q_cmd_end = traj_cmd.q_end.copy()
        self._delta_end = traj_srv.q_end - traj_cmd.q_end
        move = Move(kind, t_start, t_end, traj_cmd.q_end.copy(), self._next_id,
                    noise_key=None if noise_key is None else tuple(int(v) for v in noise_key))
        self._next_id += 1
        self._moves.append(move)
        if kind != "dwell":
            self._epoch_t.append(t_start)
            self._epoch_key.append((1, *move.noise_key) if move.noise_key is not None else (2, move.move_id))
        if len(self._moves) > self._max_moves_kept:
            del self._moves[: len(self._moves) - self._max_moves_kept]
        seg.drop_before(float(self.clock.now()) - self.history_s)
        return move

    def noise_epochs(self, t) -> tuple[np.ndarray, np.ndarray, dict]:
        """The motion in progress (or last ended) at each time ``t`` (N,): ``(epoch (N,), start_s (N,),
        {epoch: key})``; the key is the move's ``noise_key`` (or its number on this arm).

        A sample at a motion's very start still belongs to the one before (it
        does not depend on whether the next move was queued when it was taken).
        """
        tt = np.asarray(t, dtype=float).reshape(-1)
        with self._lock:
            starts = np.asarray(self._epoch_t)
            i = np.maximum(np.searchsorted(starts, tt, side="left") - 1, 0)
            keys = {int(j): self._epoch_key[j] for j in np.unique(i)}
        s = starts[i]
        return i, np.where(np.isfinite(s), s, 0.0), keys

    def _start_time(self) -> float:
        return max(float(self.clock.now()), self._t_end)

    def move_joint(self, q_rad, speed_frac: float = 1.0, accel_frac: float = 1.0, *, noise_key=None,
                   profile: str | None = None) -> Move:
        """Queue a synchronised joint move to ``q_rad`` (commanded, nominal model).

        Parameters
        ----------
        q_rad : array_like, shape (6,)
        speed_frac, accel_frac : float
            Fractions of the rated joint speed and acceleration, in (0, 1].
        noise_key : tuple of int, optional
            Identity of the move (see :meth:`_draw_delta`): the same key draws
            the same stopping error in any world of the same seed, whatever
            moved before (a resumed run meets the stops of the run it resumes).
        profile : {"scurve", "trapezoid"}, optional
            This move's velocity profile (default the arm's).

        Returns
        -------
        Move

        Raises
        ------
        DataError
            Malformed target or fractions.
        DeviceFault
            Target outside the joint limits, or the arm is in protective stop.
        """
        q1 = np.asarray(q_rad, dtype=float)
        if q1.shape != (_N,) or not np.all(np.isfinite(q1)):
            raise DataError(f"`q_rad` must be 6 finite joint angles, got {q_rad!r}")
        with self._lock:
            self._check_ready()
            self._check_joint_target(q1)
            plan = motion.plan_joint_move(
                self._q_cmd_end,
                q1,
                self.robot.joint_speed_limits_rad_s,
                self.robot.joint_accel_limits_rad_s2,
                speed_frac=speed_frac,
                accel_frac=accel_frac,
                jerk_time_s=self.jerk_time_s,
                profile=self.profile if profile is None else profile,
            )
            t_start = self._start_time()
            if plan.duration_s == 0:
                return self._append(t_start, plan.trajectory, motion.hold(self._q_cmd_end + self._delta_end), "joint",
                                    noise_key)
            delta = self._draw_delta(noise_key)
            traj_srv = motion.trajectory_from_profile(plan.profile, self._q_cmd_end + self._delta_end, q1 + delta)
            return self._append(t_start, plan.trajectory, traj_srv, "joint", noise_key)

    def move_linear(self, target, speed_mm_s: float = 250.0, accel_mm_s2: float = 2500.0, *,
                    noise_key=None, profile: str | None = None, orientation_speed_rad_s: float | None = None,
                    orientation_accel_rad_s2: float | None = None) -> Move:
        """Queue a straight-line TCP move (nominal model, fixed or slerped orientation).

        Parameters
        ----------
        target : array_like, shape (4, 4) or (3,)
            TCP pose in the base frame, or a position (mm) that keeps the
            current commanded orientation.
        speed_mm_s : float
            Path speed, at most ``robot.max_tcp_speed_mm_s``.
        accel_mm_s2 : float
            Path acceleration.
        noise_key : tuple of int, optional
            As in :meth:`move_joint`.
        profile : {"scurve", "trapezoid"}, optional
            This move's path profile (default the arm's).
        orientation_speed_rad_s, orientation_accel_rad_s2 : float, optional
            The programmed speed and acceleration of the tool's turn
            (:func:`station.models.motion.plan_linear_move`); a move that only
            turns is timed by them, its TCP held.

        Returns
        -------
        Move

        Raises
        ------
        DataError
            Malformed target, speed or acceleration.
        DeviceFault
            Target or path unreachable within the joint limits, or the arm is
            in protective stop.
        """
        v = float(speed_mm_s)
        if not (math.isfinite(v) and 0 < v <= self.robot.max_tcp_speed_mm_s):
            raise DataError(
                f"`speed_mm_s` must be in (0, {self.robot.max_tcp_speed_mm_s}] mm/s "
                f"(the robot's maximum TCP speed), got {speed_mm_s!r}"
            )
        with self._lock:
            self._check_ready()
            try:
                plan = motion.plan_linear_move(
                    self.robot.dh_nominal,
                    self._q_cmd_end,
                    target,
                    speed_mm_s=v,
                    accel_mm_s2=accel_mm_s2,
                    joint_limits_rad=self.robot.joint_limits_rad,
                    joint_speed_limits_rad_s=self.robot.joint_speed_limits_rad_s,
                    joint_accel_limits_rad_s2=self.robot.joint_accel_limits_rad_s2,
                    jerk_time_s=self.jerk_time_s,
                    profile=self.profile if profile is None else profile,
                    ipo_period_s=self.ipo_period_s,
                    orientation_speed_rad_s=orientation_speed_rad_s,
                    orientation_accel_rad_s2=orientation_accel_rad_s2,
                )
            except motion.UnreachableTarget as exc:
                raise DeviceFault(f"linear move refused: {exc}") from exc
            t_start = self._start_time()
            if plan.duration_s == 0:
                return self._append(t_start, plan.trajectory, motion.hold(self._q_cmd_end + self._delta_end), "linear",
                                    noise_key)
            delta = self._draw_delta(noise_key)
            d0 = self._delta_end
            q_srv = plan.q_knots + d0 + plan.s_knots[:, None] * (delta - d0)
            traj_srv = motion.spline_trajectory(plan.t_knots, q_srv)
            return self._append(t_start, plan.trajectory, traj_srv, "linear", noise_key)

    def move_knots(self, t_knots, q_knots, *, noise_key=None) -> Move:
        """Queue a path the controller interpolated itself: joint knots ``q_knots`` (K + 1, 6) at times
        ``t_knots`` from the move's start (a run of blended path moves, :mod:`station.models.cartesian_path`).

        The first knot must be where the queue ends; the stopping error is blended in along the knots as
        in :meth:`move_linear`.
        """
        t = np.asarray(t_knots, dtype=float).reshape(-1)
        q = np.asarray(q_knots, dtype=float)
        if q.shape != (t.size, _N) or t.size < 2 or not (np.all(np.isfinite(q)) and np.all(np.diff(t) > 0)) or t[0]:
            raise DataError("`t_knots` must rise from 0 and `q_knots` hold 6 finite angles per knot")
        with self._lock:
            self._check_ready()
            if np.max(np.abs(q[0] - self._q_cmd_end)) > 1e-6:
                raise DataError("a path's first knot must be where the arm's queue ends")
            for qk in q[:: max(1, len(q) // 64)]:
                self._check_joint_target(qk)
            self._check_joint_target(q[-1])
            t_start = self._start_time()
            delta = self._draw_delta(noise_key)
            d0 = self._delta_end
            s = (t / t[-1])[:, None]
            traj_cmd = motion.spline_trajectory(t, q)
            traj_srv = motion.spline_trajectory(t, q + d0 + s * (delta - d0))
            return self._append(t_start, traj_cmd, traj_srv, "linear", noise_key)

    def dwell(self, seconds: float, *, kind: str = "dwell") -> Move:
        """Queue a pause of ``seconds`` at the current target (``kind="settle"``: a controller's wait for the arm
        to come in position at a stop point, not a pause the program asked for)."""
        if kind not in ("dwell", "settle"):
            raise DataError(f"`kind` must be 'dwell' or 'settle', got {kind!r}")
        d = float(seconds)
        if not (math.isfinite(d) and d >= 0):
            raise DataError(f"`seconds` must be finite and >= 0, got {seconds!r}")
        with self._lock:
            self._check_ready()
            t_start = self._start_time()
            self._t_end = t_start + d
            move = Move(kind, t_start, t_start + d, self._q_cmd_end.copy(), self._next_id)
            self._next_id += 1
            self._moves.append(move)
            return move

    def protective_stop(self) -> Move:
        """Decelerate every axis to rest now and refuse moves until :meth:`reset`.

        Queued moves that had not finished are marked ``cancelled``. Returns
        the stop as a :class:`Move` (``kind="stop"``).
        """
        with self._lock:
            t_s = float(self.clock.now())
            self._protective = True
            if t_s >= self._t_end:
                move = Move("stop", t_s, t_s, self._q_cmd_end.copy(), self._next_id)
                self._next_id += 1
                return move
            for m in self._moves:
                if m.t_end > t_s:
                    m.cancelled = True
            if self.heat is not None:  # the moves cut short do not heat the arm
                self.heat.cut(t_s)
            st = self._state_at(t_s)
            seg = self._seg
            # drop every segment that starts after the stop
            k_keep = int(np.searchsorted(seg.t0[: seg.n], t_s, side="right"))
            seg.truncate(k_keep)
            acc = np.asarray(self.robot.joint_accel_limits_rad_s2)
            stop_srv = motion.stop_trajectory(st["r_srv"], st["v_srv"], acc)
            T = stop_srv.duration_s
            if T > 0:
                c = np.zeros((1, 4, _N))
                c[0, 0] = st["r_cmd"]
                c[0, 1] = st["v_cmd"]
                c[0, 2] = -st["v_cmd"] / (2.0 * T)
                stop_cmd = PiecewiseCubic(np.array([0.0, T]), c, st["r_cmd"] + 0.5 * st["v_cmd"] * T)
            else:
                stop_cmd = motion.hold(st["r_cmd"])
                stop_srv = motion.hold(st["r_srv"])
            # _append must not see the future segments' end as the queue end
            self._t_end = t_s
            was = self._protective
            self._protective = False
            try:
                move = self._append(t_s, stop_cmd, stop_srv, "stop")
            finally:
                self._protective = was
            return move

    def reset(self) -> None:
        """Leave the protective stop (new moves start after the stop ramp ends)."""
        with self._lock:
            self._protective = False

    def wait_idle(self, stop_event: threading.Event | None = None, timeout_s: float | None = None) -> bool:
        """Block on the clock until the queue is done.

        Parameters
        ----------
        stop_event : threading.Event, optional
            Returns False as soon as it is set.
        timeout_s : float, optional
            Real (host) seconds to wait at most.

        Returns
        -------
        bool
            True when the queue has ended (or a protective stop has halted
            the arm), False if ``stop_event`` was set.

        Raises
        ------
        DeviceTimeout
            ``timeout_s`` elapsed first.
        """
        deadline = None if timeout_s is None else time.monotonic() + float(timeout_s)
        scale = getattr(self.clock, "time_scale", 1.0)
        while True:
            with self._lock:
                end = self._t_end
            now = float(self.clock.now())
            if now >= end:
                return True
            if stop_event is not None and stop_event.is_set():
                return False
            if deadline is not None and time.monotonic() >= deadline:
                raise DeviceTimeout(f"arm still moving after {timeout_s} s (queue ends at t = {end:.3f} s sim)")
            if math.isinf(scale):
                target = end
            else:
                step = 0.02 * scale  # re-check the queue every ~20 ms of host time
                if deadline is not None:
                    step = min(step, max(deadline - time.monotonic(), 1e-3) * scale)
                target = min(end, now + step)
            if not self.clock.sleep_until(target, stop_event):
                return False

    # ----------------------------------------------------------------- queries
    def _gather(self, t: np.ndarray):
        with self._lock:
            seg = self._seg
            k = seg.locate(t)
            return (
                t - seg.t0[k],
                seg.c_cmd[k],
                seg.c_srv[k],
                seg.E[k],
                seg.Ed[k],
                seg.dir[k],
            )

    def commanded_q_rad(self, t=None) -> np.ndarray:
        """What the controller commands (nominal, no scatter, no servo lag).

        Parameters
        ----------
        t : float or array_like, shape (N,), optional
            Simulated time(s); default the clock's present.

        Returns
        -------
        ndarray, shape (6,) or (N, 6)
        """
        tt, scalar = self._times(t)
        tau, c_cmd, *_ = self._gather(tt)
        q = _poly(c_cmd, tau)
        return q[0] if scalar else q

    def _times(self, t):
        if t is None:
            t = float(self.clock.now())
        arr = np.asarray(t, dtype=float)
        scalar = arr.ndim == 0
        arr = np.atleast_1d(arr)
        if arr.ndim != 1 or not np.all(np.isfinite(arr)):
            raise DataError("`t` must be a finite scalar or 1-D array of simulated times")
        return arr, scalar

    def _actual(self, t: np.ndarray):
        tau, c_cmd, c, E, Ed, d0 = self._gather(t)
        r = _poly(c, tau)
        v = _poly(c_cmd, tau, 1)
        if self.servo is not None:
            e, _ed = motion.servo_step(E, Ed, -2.0 * c[:, 2], -6.0 * c[:, 3], tau, self.servo)
            q = r + e
        else:
            q = r
        direction = np.where(np.abs(v) > 1e-12, np.sign(v), d0)
        return q, direction

    def actual_q_rad(self, t=None) -> np.ndarray:
        """Joint angles the encoders read (reference + stopping error + servo lag).

        Parameters
        ----------
        t : float or array_like, shape (N,), optional

        Returns
        -------
        ndarray, shape (6,) or (N, 6)
        """
        tt, scalar = self._times(t)
        q, _ = self._actual(tt)
        return q[0] if scalar else q

    def apply_tcp_force(self, force_N, t_s: float | None = None) -> None:
        """An external force on the TCP (N, base frame) from ``t_s`` (default now) on, until the next one:
        what a person pulling on the tool with a force gauge applies (ISO 9283 clause 10). The arm gives
        way through its joint compliance (:class:`station.models.effects.JointCompliance`)."""
        F = np.asarray(force_N, dtype=float).reshape(-1)
        if F.shape != (3,) or not np.all(np.isfinite(F)):
            raise DataError(f"`force_N` must be 3 finite values (N, base frame), got {force_N!r}")
        with self._lock:
            t = float(self.clock.now()) if t_s is None else float(t_s)
            if not (math.isfinite(t) and t >= self._force_t[-1]):
                raise DataError(f"a force is applied from t = {t!r}, before the last change at {self._force_t[-1]}")
            self._force_t.append(t)
            self._force_N.append(F.copy())

    def tcp_force_N(self, t=None) -> np.ndarray:
        """The external force on the TCP at ``t`` (N, base frame): (3,) or (N, 3)."""
        tt, scalar = self._times(t)
        with self._lock:
            idx = np.searchsorted(np.asarray(self._force_t), tt, side="right") - 1
            out = np.asarray(self._force_N)[idx]
        return out[0] if scalar else out

    def compliance_mm_per_N(self, t=None) -> np.ndarray:
        """The truth of a static compliance test at ``t`` (the arm at rest): the TCP's compliance matrix
        (mm/N, base frame) of the arm's joint compliance at its true table and joint angles; zeros without it."""
        from station.models.effects import tcp_compliance_mm_per_N

        if self.effects is None or not self.effects.is_enabled("joint_compliance"):
            return np.zeros((3, 3))
        dh, q = self.true_model(float(self.clock.now()) if t is None else float(t))
        dh = np.asarray(dh)
        return tcp_compliance_mm_per_N(dh[0] if dh.ndim == 3 else dh, q[0], self.effects.get("joint_compliance"))

    def effect_context(self, t, direction) -> EffectContext:
        """Context of the error effects at times ``t`` (N,)."""
        loaded = len(self._force_t) > 1
        return EffectContext(
            robot=self.robot,
            last_dir=direction,
            warmup_s=np.asarray(t, dtype=float) - self.warmup_origin_s,
            temperature_rise_K=None if self.heat is None else self.temperature_rise_K(t),
            payload_kg=self.payload_kg,
            tcp_force_N=self.tcp_force_N(np.asarray(t, dtype=float)) if loaded else None,
        )

    def temperature_rise_K(self, t=None) -> np.ndarray:
        """The links' temperature rise at ``t`` from the joints' motion (:mod:`fakes.sim.heat`), K: (N,) (zeros
        without a thermal drift)."""
        tt, _ = self._times(t)
        if self.heat is None:
            return np.zeros(tt.size)
        with self._lock:
            return self.heat.rise_K(tt)

    def true_model(self, t=None):
        """True kinematic table and joint angles at ``t``: ``(dh_eff, q_eff)``.

        ``dh_eff`` is (7, 5) or (N, 7, 5), ``q_eff`` (N, 6).
        """
        tt, _ = self._times(t)
        q, direction = self._actual(tt)
        if self.effects is None:
            dh, q_true = np.asarray(self.robot.dh_nominal), q
        else:
            dh, q_true = self.effects.apply(self.robot.dh_nominal, q, self.effect_context(tt, direction))
        if self.joint_defect is not None:
            q_true = self.joint_defect.apply(q, q_true)
        return dh, q_true

    def tool_pose(self, t=None) -> np.ndarray:
        """True TCP pose in the robot base frame.

        Parameters
        ----------
        t : float or array_like, shape (N,), optional

        Returns
        -------
        ndarray, shape (4, 4) or (N, 4, 4)
        """
        return self._true_fk(t, position_only=False)

    def tool_position_mm(self, t=None) -> np.ndarray:
        """True TCP position in the robot base frame, mm.

        Parameters
        ----------
        t : float or array_like, shape (N,), optional

        Returns
        -------
        ndarray, shape (3,) or (N, 3)
        """
        return self._true_fk(t, position_only=True)

    def _true_fk(self, t, position_only: bool) -> np.ndarray:
        tt, scalar = self._times(t)
        out = np.empty((tt.size, 3) if position_only else (tt.size, 4, 4))
        for i in range(0, tt.size, _CHUNK):  # chunks of samples bound the memory of FK
            sl = slice(i, i + _CHUNK)
            T = kin.fk(*self.true_model(tt[sl]))
            out[sl] = T[:, :3, 3] if position_only else T
        return out[0] if scalar else out

    def commanded_tool_pose(self, t=None) -> np.ndarray:
        """Where the controller believes the TCP is (nominal FK of the command)."""
        q = self.commanded_q_rad(t)
        return kin.fk(self.robot.dh_nominal, q)
