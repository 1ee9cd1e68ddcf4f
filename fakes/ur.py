"""Fake Universal Robots e-Series controller that the real ``ur_rtde`` connects to.

Three servers on one loopback address of its own (``ur_rtde`` fixes the
ports, so several fakes run side by side on 127.0.0.2, 127.0.0.3, ...):

* **RTDE** (30004): protocol version 2 handshake, controller version 5.11,
  output recipes with the types of the UR RTDE guide (``NOT_FOUND`` for an
  unknown variable), input recipes (``IN_USE`` for an input another client
  owns), start/pause, and data packages at the requested frequency (1..500
  Hz) on the **world's clock**: sample ``k`` is the state at simulated time
  ``t0 + k / f``, its ``timestamp`` is that time, and every due sample is
  sent (a late sender catches up, it never skips). Text messages (``M``)
  report refused scripts and faults to every started session.
* **Dashboard** (29999): the line protocol of PolyScope 5.11 (``play``,
  ``stop``, ``pause``, ``load``, ``running``, ``programState``,
  ``robotmode``, ``safetymode``, ``power on``/``off``, ``brake release``,
  ``unlock protective stop``, ``PolyscopeVersion``, ``get serial number``...);
  anything else gets ``could not understand: '<line>'``. ``play`` goes on
  with a paused program, one sent to the script port too (as the pendant's
  play does); otherwise it starts the loaded ``.urp``.
* **Script** (30003): a URScript subset, one program per ``def ... end``
  block or per bare line. A new program replaces the running one (as on the
  real controller). Supported: ``movej``/``movel``/``movec`` (joint list or ``p[...]``
  pose; ``a``, ``v``, ``t``, ``r`` by position or keyword), ``stopj``,
  ``stopl``, ``sleep``, ``sync``, ``textmsg``,
  ``write_output_{integer,float,boolean}_register``; numbers, ``pi``, lists,
  poses, strings, ``True``/``False``. This port does not stream the legacy
  realtime state (``ur_rtde``'s script client only writes).

**Refusals** (documented behaviour): a script the fake does not understand
(unknown function, expression, statement) is *not run*; the fake sends an
RTDE text message ``Compile error: ...`` (level error) and records it in
``handle.script_errors``. A program that fails while running (unreachable
pose, joint target outside the limits, robot not ready) stops with a
``Runtime error: ...`` text message; the robot halts, no protective stop.
Blend radii ``r`` blend: consecutive ``movel``/``movec`` calls whose radius
is > 0 run as one path, their corners rounded by ``r`` and one speed profile
to rest at the run's last target (:mod:`fakes.sim.path_follow`); register
writes between them take effect when the run ends. ``movec(pose_via,
pose_to, a, v, r, mode)`` moves on the circle through the start, the via
pose's position and the target (fixed orientation).
``movej`` speed ``v`` (rad/s) and acceleration ``a`` (rad/s^2) are taken as
fractions of the robot's slowest joint limits; ``movel``'s are the path speed
and acceleration (m/s, m/s^2), and a ``movel`` that only turns the tool (its
TCP held, within a micrometre) takes them as the turn's speed and
acceleration (rad/s, rad/s^2: the station's reading of UR's pure rotations,
whose script manual names m/s only); ``t`` > 0 stretches either move to about that
duration (trapezoid estimate; never faster than the limits allow).

The reported ``actual_TCP_pose`` is what a controller computes: the nominal
forward kinematics of ``actual_q`` (metres, axis-angle rotation vector); the
true tool pose (with the world's error effects) is what a tracker sees.

Fault injection (``faults`` dict, string values):

``protective_stop_move=N``
    protective stop during the N-th motion command the fake executes (1-based);
``protective_stop_fraction=F``
    where in that move, as a fraction of its commanded duration (default 0.5);
``rtde_drop_after_s=S``
    the first RTDE session that starts streaming is closed abruptly S
    simulated seconds after its start (later sessions are not dropped);
``dashboard_refuse=CMD[,CMD...]``
    those dashboard commands (first word, e.g. ``play``, ``stop``, ``load``)
    answer ``Failed to execute: <cmd>``; ``connect`` closes every dashboard
    connection at once, without the greeting.
``emergency_stop_move=N``
    the emergency stop is pressed during the N-th motion (at
    ``protective_stop_fraction`` of it): the arm halts, safety mode
    ROBOT_EMERGENCY_STOP, the emergency bits of ``safety_status_bits`` set,
    robot mode IDLE (brakes on); it stays so until ``sim_release_emergency_stop()``
    (the button turned back), after which ``brake release`` makes the robot RUNNING;
``refuse_script=N``
    the N-th program that reaches the script port is refused as if it did not
    compile (``Compile error: ...`` text message, not run).

Dashboard ``pause`` halts the arm (controlled stop) and ``play`` resumes the
program, re-issuing the interrupted move to the same target; ``stop``,
``stopj``/``stopl`` and a replacing program halt it likewise. A protective
stop can be unlocked 5 simulated seconds after it occurred (earlier, the
dashboard answers as PolyScope does). The controller starts powered on with
the brakes released (robot mode RUNNING); ``power off``, ``power on``,
``brake release`` walk POWER_OFF -> IDLE -> RUNNING. One program is stored:
``/programs/station_idle.urp`` (sleeps, never moves).

**Lockstep** (``start_fake(world, lockstep=True)``, the fake cells; the
driver's ``ur://HOST?lockstep=1``): the fake does not keep the world's clock
running; programs run it. The interpreter waits on the clock for each move,
dwell and ``sync``, and after a program's last statement (or its abort) for
the arm to come to rest, :data:`SETTLE_S` after its last motion ends; only
then is the program stopped. Between programs the clock stands still however
long the station takes, so every program starts at the same simulated
instant at any load or pace. Besides the samples at ``t0 + k / f`` the RTDE
stream sends one at the instant it started and one at each instant a program
stopped (the clock stands there, and the client must see the program
stopped); while nothing is due it repeats its newest sample at the output
frequency, as a controller at rest sends the same state (``ur_rtde`` ends a
session that receives nothing). While a client owns
``input_double_register_22``
(:data:`~station.protocols.ur.LOCKSTEP_STORED_REGISTER`; the driver's receive
process does) the stream goes **one package at a time**: the next is sent
only once the client wrote there the timestamp of the last one it kept, and
the clock is held at the next package's instant until it is sent (a
producer, as the tracker's stream). A client that keeps only the newest
package then still sees every one, and a seed gives the same stored readings
at any load. A dashboard ``pause`` lets the clock run until the halted arm
rests. Without lockstep
(the default, ``station fakes serve ur``) the clock runs while the fake
serves, as a real controller's.

Test-only controls start with ``sim_``: ``sim_add_program(path, urscript)``
stores a program for ``load``/``play``; ``sim_drop_rtde()`` resets every RTDE
connection now. ``packets_sent``, ``scripts_received``, ``script_errors``,
``messages``, ``protocol_errors`` and ``rtde_drops`` record what happened.
"""

from __future__ import annotations

import math
import re
import select
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from station.models.rotation import T_to_ur_pose, rotvec_of, ur_pose_to_T

from fakes import rtde_protocol as rp
from fakes.sim.clock import keep_running, stop_running
from fakes.sim import path_follow
from fakes.urscript import Call, Pose, ScriptError, ScriptProgram, ScriptSplitter, bind_arguments, parse_program
from station.errors import ConfigError, DataError, ProtocolError
from station.models import kinematics
from station.models.cartesian_path import Segment
from station.programs.urscript import TURN_ONLY_MM
from station.protocols.ur import LOCKSTEP_STORED_REGISTER, JointMode, RobotMode, RuntimeState, SafetyMode

#: the robot a UR fake simulates unless told otherwise (`station fakes serve ur --robot ...`)
DEFAULT_ROBOT = "ur5e"
PORTS = {"rtde": 30004, "dashboard": 29999, "script": 30003}
CONTROLLER_VERSION = (5, 11, 0, 108318)
POLYSCOPE_VERSION = "URSoftware 5.11.0.108318 (Mar 08 2021)"
SERIAL_NUMBER = "20215300001"
MAX_FREQUENCY_HZ = 500.0
TICK_S = 0.002  # controller cycle (e-Series 500 Hz)
UNLOCK_DELAY_S = 5.0  # protective stop may be unlocked 5 s after it occurred

# the protocol's mode numbers (shared with the driver)
ROBOT_MODE = {m.value: m.name for m in RobotMode}
SAFETY_MODE = {m.value: m.name for m in SafetyMode}
MODE_POWER_OFF, MODE_IDLE, MODE_RUNNING = RobotMode.POWER_OFF, RobotMode.IDLE, RobotMode.RUNNING
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = SafetyMode.NORMAL, SafetyMode.PROTECTIVE_STOP
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = RuntimeState.STOPPED, RuntimeState.PLAYING, RuntimeState.PAUSED
JOINT_POWER_OFF, JOINT_IDLE, JOINT_RUNNING = JointMode.POWER_OFF, JointMode.IDLE, JointMode.RUNNING

MAX_DASHBOARD_LINE = 4096
FD_STEP_S = TICK_S  # backward difference for velocities
MAX_BATCH = 256  # data packages packed per send
_STORED_INPUT = f"input_double_register_{LOCKSTEP_STORED_REGISTER}"
STOP_LOOK_S = 0.002  # lockstep, one package at a time: how often the stream looks for a program's stop, real s


# ====================================================================== faults


@dataclass(frozen=True)
class FaultPlan:
    """Parsed fault-injection keys (see the module docstring)."""

    protective_stop_move: int | None = None
    protective_stop_fraction: float = 0.5
    rtde_drop_after_s: float | None = None
    dashboard_refuse: frozenset = frozenset()
    emergency_stop_move: int | None = None
    refuse_script: int | None = None

    KEYS = ("protective_stop_move", "protective_stop_fraction", "rtde_drop_after_s", "dashboard_refuse",
            "emergency_stop_move", "refuse_script")

    @classmethod
    def parse(cls, faults: dict | None) -> "FaultPlan":
        faults = dict(faults or {})
        unknown = sorted(set(faults) - set(cls.KEYS))
        if unknown:
            raise ConfigError(f"unknown UR fault key(s) {unknown}; known: {list(cls.KEYS)}")
        kw: dict = {}
        if "protective_stop_move" in faults:
            kw["protective_stop_move"] = _parse_number(faults, "protective_stop_move", int, lo=1)
        if "protective_stop_fraction" in faults:
            f = _parse_number(faults, "protective_stop_fraction", float, lo=0.0)
            if not 0.0 < f < 1.0:
                raise ConfigError(f"fault protective_stop_fraction must be in (0, 1), got {f!r}")
            kw["protective_stop_fraction"] = f
        for key in ("emergency_stop_move", "refuse_script"):
            if key in faults:
                kw[key] = _parse_number(faults, key, int, lo=1)
        if "rtde_drop_after_s" in faults:
            kw["rtde_drop_after_s"] = _parse_number(faults, "rtde_drop_after_s", float, lo=0.0)
        if "dashboard_refuse" in faults:
            words = {w.strip().lower() for w in str(faults["dashboard_refuse"]).split(",") if w.strip()}
            if not words:
                raise ConfigError("fault dashboard_refuse needs at least one command word")
            kw["dashboard_refuse"] = frozenset(words)
        return cls(**kw)


def _parse_number(faults: dict, key: str, kind, lo: float):
    raw = faults[key]
    try:
        val = kind(str(raw).strip())
    except ValueError as exc:
        raise ConfigError(f"fault {key} must be a {kind.__name__}, got {raw!r}") from exc
    if isinstance(val, float) and not math.isfinite(val):
        raise ConfigError(f"fault {key} must be finite, got {raw!r}")
    if val < lo:
        raise ConfigError(f"fault {key} must be >= {lo}, got {raw!r}")
    return val


# ====================================================================== URScript subset


def _angular_velocity(T_now: np.ndarray, T_prev: np.ndarray, dt: float) -> np.ndarray:
    dR = np.einsum("nij,nkj->nik", T_now[:, :3, :3], T_prev[:, :3, :3])
    return rotvec_of(dR) / dt


def _vector_query(fn, ts: np.ndarray) -> np.ndarray:
    """Call an arm query vectorised if it is, else one time at a time."""
    out = np.asarray(fn(ts), dtype=float)
    if out.shape == (len(ts), 6):
        return out
    return np.array([np.asarray(fn(float(t)), dtype=float).reshape(6) for t in ts])


def _query_with_history(fn, ts: np.ndarray, steps: int) -> np.ndarray:
    """``fn`` at ``ts, ts - h, ..., ts - steps h`` stacked ((steps + 1) N, 6).

    Times before the arm's history (a stream that starts within a few ms of
    the world's creation) repeat the sample itself: zero velocity there.
    """
    n = len(ts)
    try:
        return _vector_query(fn, np.concatenate([ts - k * FD_STEP_S for k in range(steps + 1)]))
    except DataError:
        now = _vector_query(fn, ts)
        return np.concatenate([now] * (steps + 1)) if n else now


#: lockstep: simulated seconds the world runs on after the arm's last motion, for it to come to rest
SETTLE_S = 2.0


class _Controller:
    """The controller's state shared by the three servers and the interpreter."""

    def __init__(self, world, plan: FaultPlan) -> None:
        self.world = world
        self.clock = world.clock
        self.arm = world.arm
        self.robot = world.robot
        self.dh = np.asarray(self.robot.dh_nominal, dtype=float)
        self.plan = plan
        self.lock = threading.RLock()
        self.robot_mode = MODE_RUNNING
        self.protective_stop_t: float | None = None
        self.emergency_stopped = False
        self.runtime_state = RUNTIME_STOPPED
        self.loaded_program: str | None = None
        self.programs: dict[str, str] = {
            "/programs/station_idle.urp": "def station_idle():\n  sleep(86400)\nend\n",
        }
        self.out_int = np.zeros(48, dtype=np.int64)
        self.out_double = np.zeros(48)
        self.out_bits = 0  # registers 64..127 as a 64-bit word
        self.in_int = np.zeros(48, dtype=np.int64)
        self.in_double = np.zeros(48)
        self.in_bits = 0
        self.inputs_in_use: set[str] = set()
        self.inputs_changed = threading.Condition(self.lock)  # an input register written, or given up
        self.stop_instants: deque = deque(maxlen=64)  # lockstep: when the last programs stopped (simulated s)
        self.script_line = 0
        self.motion_count = 0
        self.scripts_received: list[str] = []
        self.script_errors: list[str] = []
        self.messages: list[str] = []
        self._listeners: list[deque] = []
        self.rtde_drop_used = False
        self.packets_sent = 0
        self.lockstep = False  # set by the fake (module docstring)

    # ---------------------------------------------------------------- lockstep: when programs stopped
    def note_stop(self, t_s: float) -> None:
        """A program stopped at ``t_s``: the stream sends the state of that instant (module docstring)."""
        with self.lock:
            self.stop_instants.append(float(t_s))

    def stops_after(self, t_s: float) -> list[float]:
        """The instants programs stopped at after ``t_s``, in order."""
        with self.lock:
            return [t for t in self.stop_instants if t > t_s]

    # ---------------------------------------------------------------- lockstep: what the client kept
    def stored_register_in_use(self) -> bool:
        """A client owns the register where it says which sample it kept (:data:`LOCKSTEP_STORED_REGISTER`)."""
        with self.lock:
            return _STORED_INPUT in self.inputs_in_use

    def stored_up_to(self, t_s: float) -> bool:
        """The client kept the sample at ``t_s`` (or a later one), or gave the register up."""
        with self.lock:
            return _STORED_INPUT not in self.inputs_in_use or self.in_double[LOCKSTEP_STORED_REGISTER] >= t_s

    def await_stored(self, t_s: float, timeout_s: float) -> bool:
        with self.lock:
            return self.inputs_changed.wait_for(lambda: self.stored_up_to(t_s), timeout_s)

    # ---------------------------------------------------------------- messages
    def subscribe(self) -> deque:
        q: deque = deque(maxlen=256)
        with self.lock:
            self._listeners.append(q)
        return q

    def unsubscribe(self, q: deque) -> None:
        with self.lock:
            if q in self._listeners:
                self._listeners.remove(q)

    def message(self, text: str, level: int = rp.MESSAGE_ERROR) -> None:
        with self.lock:
            self.messages.append(text)
            for q in self._listeners:
                q.append((text, level))

    # ---------------------------------------------------------------- modes
    def safety_mode(self) -> int:
        with self.lock:
            if self.emergency_stopped:
                return SafetyMode.ROBOT_EMERGENCY_STOP
            if self.protective_stop_t is not None:
                return SAFETY_PROTECTIVE_STOP
            return SAFETY_NORMAL

    def enter_protective_stop(self, reason: str) -> None:
        with self.lock:
            if self.protective_stop_t is None:
                self.protective_stop_t = self.clock.now()
        self.message(f"C153A1: Protective stop: {reason}")

    def enter_emergency_stop(self, reason: str) -> None:
        with self.lock:
            self.emergency_stopped = True
            self.robot_mode = MODE_IDLE  # brakes on
        self.message(f"C150A0: Robot emergency stop: {reason}")

    def ready_to_move(self) -> str | None:
        """None when a program may move the arm, else why not."""
        with self.lock:
            if self.robot_mode != MODE_RUNNING:
                return f"robot is in mode {ROBOT_MODE.get(self.robot_mode, self.robot_mode)}"
            if self.emergency_stopped:
                return "robot is in emergency stop"
            if self.safety_mode() != SAFETY_NORMAL:
                return "robot is in protective stop"
            return None

    # ---------------------------------------------------------------- state
    def columns(self, names: list[str], ts: np.ndarray) -> dict:
        """Values of ``names`` at simulated times ``ts`` (N,): name -> (N,) or (N, w)."""
        need = set(names)
        n = len(ts)
        cols: dict = {}
        with self.lock:
            modes = (self.robot_mode, self.safety_mode(), self.runtime_state)
            out_int, out_double, out_bits = self.out_int.copy(), self.out_double.copy(), self.out_bits
            in_int, in_double, in_bits = self.in_int.copy(), self.in_double.copy(), self.in_bits
            line = self.script_line
        robot_mode, safety_mode, runtime = modes
        want_actual = need & {"actual_q", "actual_qd", "actual_TCP_pose", "actual_TCP_speed", "target_moment",
                              "target_current", "actual_current", "actual_tool_accelerometer", "elbow_position",
                              "elbow_velocity", "actual_current_window", "joint_control_output"}
        want_target = need & {"target_q", "target_qd", "target_qdd", "target_TCP_pose", "target_TCP_speed"}
        if want_actual:
            qa = _query_with_history(self.arm.actual_q_rad, ts, 1)
            q, q_prev = qa[:n], qa[n:]
            cols["actual_q"] = q
            cols["actual_qd"] = (q - q_prev) / FD_STEP_S
            if need & {"actual_TCP_pose", "actual_TCP_speed", "actual_tool_accelerometer"}:
                T = kinematics.fk(self.dh, qa)
                T_now, T_prev = T[:n], T[n:]
                cols["actual_TCP_pose"] = T_to_ur_pose(T_now)
                speed = np.empty((n, 6))
                speed[:, :3] = (T_now[:, :3, 3] - T_prev[:, :3, 3]) / 1000.0 / FD_STEP_S
                speed[:, 3:] = _angular_velocity(T_now, T_prev, FD_STEP_S)
                cols["actual_TCP_speed"] = speed
                cols["actual_tool_accelerometer"] = np.einsum("nji,j->ni", T_now[:, :3, :3], [0.0, 0.0, 9.80665])
            if need & {"elbow_position", "elbow_velocity"}:
                F = kinematics.frames(self.dh, qa)
                e = F[:, 3, :3, 3] / 1000.0
                cols["elbow_position"] = e[:n]
                cols["elbow_velocity"] = (e[:n] - e[n:]) / FD_STEP_S
            if need & {"target_moment", "target_current", "actual_current", "joint_control_output",
                       "actual_current_window"}:
                from station.models.robots import gravity_torques

                tau = np.asarray(gravity_torques(self.robot, self.dh, q)).reshape(n, 6)
                cols["target_moment"] = tau
                amps = tau / 10.0  # illustrative torque constant x gear ratio, N m / A
                cols["target_current"] = amps
                cols["actual_current"] = amps
                cols["joint_control_output"] = amps
                cols["actual_current_window"] = np.zeros((n, 6))
        if want_target:
            qt = _query_with_history(self.arm.commanded_q_rad, ts, 2)
            q0, q1, q2 = qt[:n], qt[n:2 * n], qt[2 * n:]
            cols["target_q"] = q0
            cols["target_qd"] = (q0 - q1) / FD_STEP_S
            cols["target_qdd"] = (q0 - 2 * q1 + q2) / FD_STEP_S**2
            if need & {"target_TCP_pose", "target_TCP_speed"}:
                T = kinematics.fk(self.dh, qt[: 2 * n])
                cols["target_TCP_pose"] = T_to_ur_pose(T[:n])
                sp = np.empty((n, 6))
                sp[:, :3] = (T[:n, :3, 3] - T[n:, :3, 3]) / 1000.0 / FD_STEP_S
                sp[:, 3:] = _angular_velocity(T[:n], T[n:], FD_STEP_S)
                cols["target_TCP_speed"] = sp
        powered = robot_mode in (4, 5, 6, 7)
        running = runtime == RUNTIME_PLAYING
        pstop = safety_mode == SAFETY_PROTECTIVE_STOP
        estop = safety_mode == SafetyMode.ROBOT_EMERGENCY_STOP
        joint_mode = JOINT_RUNNING if robot_mode == MODE_RUNNING else (JOINT_IDLE if powered else JOINT_POWER_OFF)
        scalars = {
            "timestamp": ts,
            "robot_mode": robot_mode,
            "safety_mode": safety_mode,
            "safety_status": safety_mode,
            "runtime_state": runtime,
            "robot_status_bits": (1 if powered else 0) | (2 if running else 0),
            "safety_status_bits": (4 | (1 << 10)) if pstop else (((1 << 6) | (1 << 7)) if estop else 1),
            "joint_mode": [joint_mode] * 6,
            "speed_scaling": 0.0 if (pstop or estop) else 1.0,
            "target_speed_fraction": 1.0,
            "actual_execution_time": 0.3,
            "actual_momentum": 0.0,
            "actual_main_voltage": 48.0,
            "actual_robot_voltage": 48.0 if powered else 0.0,
            "actual_robot_current": 0.6 if powered else 0.0,
            "actual_joint_voltage": [48.0 if powered else 0.0] * 6,
            "joint_temperatures": [30.0] * 6,
            "actual_TCP_force": [0.0] * 6,
            "ft_raw_wrench": [0.0] * 6,
            "payload": 0.0,
            "payload_cog": [0.0] * 3,
            "payload_inertia": [0.0] * 6,
            "script_control_line": line,
            "output_bit_registers0_to_31": 0,
            "output_bit_registers32_to_63": 0,
            "input_bit_registers0_to_31": 0,
            "input_bit_registers32_to_63": 0,
            "joint_position_deviation_ratio": [0.0] * 6,
            "collision_detection_ratio": 0.0,
            "time_scale_source": 0,
            "tool_output_voltage": 0,
            "tool_temperature": 30.0,
        }
        for name in need:
            if name in cols:
                continue
            if name in scalars:
                cols[name] = scalars[name]
                continue
            m = re.match(r"^(input|output)_(int|double|bit)_register_(\d+)$", name)
            if m:
                io, kind, idx = m.group(1), m.group(2), int(m.group(3))
                if kind == "int":
                    cols[name] = int((out_int if io == "output" else in_int)[idx])
                elif kind == "double":
                    cols[name] = float((out_double if io == "output" else in_double)[idx])
                else:
                    bits = out_bits if io == "output" else in_bits
                    cols[name] = bool((bits >> (idx - 64)) & 1)
                continue
            width = rp.TYPE_WIDTHS[rp.output_type(name)]
            cols[name] = 0 if width == 1 else [0] * width
        return cols


# ====================================================================== interpreter


class _Abort(Exception):
    """The running program was stopped (new program, stop, protective stop)."""


class _Interpreter:
    """Runs one program at a time on the simulated arm (its own thread)."""

    def __init__(self, ctl: _Controller, stop: threading.Event) -> None:
        self.ctl = ctl
        self.stop_all = stop
        self.cond = threading.Condition(ctl.lock)
        self.pending: ScriptProgram | None = None
        self.abort_reason: str | None = None
        self.paused = False
        self.pause_epoch = 0  # a pause halts the arm; the move is re-issued on resume
        self.wake = threading.Event()
        self.busy = False
        self.thread = threading.Thread(target=self._run, name="ur-fake-interpreter")

    # ------------------------------------------------------------ commands
    def submit(self, program: ScriptProgram) -> None:
        with self.cond:
            self.pending = program
            if self.busy:
                self.abort_reason = "replaced by a new program"
            self.paused = False
            self.wake.set()
            self.cond.notify_all()

    def abort(self, reason: str) -> bool:
        with self.cond:
            self.pending = None
            self.paused = False
            if not self.busy:
                return False
            self.abort_reason = reason
            self.wake.set()
            self.cond.notify_all()
            return True

    def _active(self) -> bool:
        """A program is running or accepted by play and about to run (the thread picks it up)."""
        return self.busy or self.pending is not None

    def executing(self) -> bool:
        """:meth:`_active`, for a caller that does not hold the lock (in lockstep a program's waits run the
        clock)."""
        with self.cond:
            return self._active()

    def stoppable(self) -> bool:
        """A program runs (and is not already being stopped) or waits to start."""
        with self.cond:
            return (self.busy and self.abort_reason is None) or self.pending is not None

    def pause(self) -> bool:
        with self.cond:
            if not self._active() or self.paused:
                return False
            self.paused = True
            self.pause_epoch += 1
            self.ctl.runtime_state = RUNTIME_PAUSED
            self.wake.set()
            return True

    def resume(self) -> bool:
        with self.cond:
            if not self._active() or not self.paused:
                return False
            self.paused = False
            self.ctl.runtime_state = RUNTIME_PLAYING
            self.cond.notify_all()
            return True

    # ------------------------------------------------------------ thread
    def _run(self) -> None:
        while not self.stop_all.is_set():
            with self.cond:
                while self.pending is None and not self.stop_all.is_set():
                    self.cond.wait(0.1)
                if self.stop_all.is_set():
                    return
                program, self.pending = self.pending, None
                self.abort_reason = None
                self.wake.clear()
                why = self.ctl.ready_to_move()
                if why is not None:
                    self.ctl.message(f"Runtime error: cannot start program {program.name}: {why}")
                    self.paused = False
                    continue
                self.busy = True
                # paused between play and this pickup: it starts paused
                self.ctl.runtime_state = RUNTIME_PAUSED if self.paused else RUNTIME_PLAYING
            try:
                self._execute(program)
            except _Abort:
                pass
            except ScriptError as exc:
                self.ctl.message(f"Runtime error in program {program.name}: {exc}")
                _halt(self.ctl.arm)
            finally:
                if self.ctl.lockstep:  # the program ends when the arm rests (module docstring)
                    self.ctl.clock.sleep_until(self.ctl.arm.queue_end_s + SETTLE_S, self.stop_all)
                with self.cond:
                    self.busy = False
                    self.paused = False
                    self.ctl.runtime_state = RUNTIME_STOPPED
                    self.ctl.script_line = 0
                    self.cond.notify_all()
                if self.ctl.lockstep:
                    self.ctl.note_stop(self.ctl.clock.now())

    def _check(self) -> None:
        """Raise _Abort if told to stop; block while paused."""
        with self.cond:
            while True:
                if self.stop_all.is_set():
                    raise _Abort()
                if self.abort_reason is not None:
                    raise _Abort()
                if self.ctl.safety_mode() != SAFETY_NORMAL:
                    raise _Abort()
                if not self.paused:
                    return
                self.cond.wait(0.05)

    def _wait_until(self, t_sim: float) -> None:
        """Sleep on the world's clock until ``t_sim``, interruptible."""
        clock = self.ctl.clock
        while True:
            self._check()
            if clock.now() >= t_sim:
                return
            self.wake.clear()
            self._check()
            clock.sleep_until(t_sim, self.wake)

    def _execute(self, program: ScriptProgram) -> None:
        calls = list(program.statements)
        i = 0
        while i < len(calls):
            call = calls[i]
            i += 1
            self._check()
            with self.ctl.lock:
                self.ctl.script_line = call.line
            b = bind_arguments(call)
            name = call.name
            if name == "movec" or (name == "movel" and float(b.get("r", 0.0)) > 0):
                run, deferred, i = _blended_run(calls, i - 1)
                self._move_path(program, run)
                for w in deferred:
                    self._write(w, bind_arguments(w))
            elif name in ("movej", "movel"):
                self._move(program, call, b)
            elif name in ("stopj", "stopl"):
                _halt(self.ctl.arm)
            elif name == "sleep":
                self._wait_until(self.ctl.clock.now() + float(b["t"]))
            elif name == "sync":
                self._wait_until(self.ctl.clock.now() + TICK_S)
            elif name == "textmsg":
                self.ctl.message(f"{b['s1']}{b.get('s2', '')}", rp.MESSAGE_INFO)
            elif name.startswith("write_output_"):
                self._write(call, b)

    def _write(self, call: Call, b: dict) -> None:
        name = call.name
        with self.ctl.lock:
            if name == "write_output_integer_register":
                self.ctl.out_int[int(b["address"])] = int(b["value"])
            elif name == "write_output_float_register":
                self.ctl.out_double[int(b["address"])] = float(b["value"])
            else:
                bit = 1 << (int(b["address"]) - 64)
                self.ctl.out_bits = (self.ctl.out_bits | bit) if b["value"] else (self.ctl.out_bits & ~bit)

    def _move_path(self, program: ScriptProgram, run: list) -> None:
        """A run of blended ``movel``/``movec`` calls, interpolated as one path (:mod:`fakes.sim.path_follow`):
        corners rounded by each move's ``r``, one speed profile to rest at the last target. The run is one
        motion to the fault plan's counters and to a pause (a paused run is halted, not taken up again)."""
        ctl, arm, robot = self.ctl, self.ctl.arm, self.ctl.robot
        why = ctl.ready_to_move()
        if why is not None:
            raise ScriptError(f"line {run[0].line}: {run[0].name}: {why}")
        segs = []
        for call in run:
            b = bind_arguments(call)
            T = ur_pose_to_T((b["pose_to"] if call.name == "movec" else b["pose"]).values)
            v = float(b.get("v", 0.25)) * 1000.0
            v = min(v, float(robot.max_tcp_speed_mm_s)) if v > 0 else float(robot.max_tcp_speed_mm_s)
            via = ur_pose_to_T(b["pose_via"].values)[:3, 3] if call.name == "movec" else None
            segs.append(Segment(T, v, float(b.get("r", 0.0)) * 1000.0, via))
        a = float(bind_arguments(run[0]).get("a", 1.2)) * 1000.0
        with ctl.lock:
            ctl.motion_count += 1
            count = ctl.motion_count
        try:
            move = path_follow.queue_segments(arm, robot, segs, accel_mm_s2=a if a > 0 else 1200.0,
                                              ripple=path_follow.ripple_of(ctl.world.seed, (count,)))
        except Exception as exc:  # the path leaves the reach: a runtime error
            raise ScriptError(f"line {run[0].line}: {run[0].name}: {exc}") from exc
        try:
            self._wait_until(move.t_end)
        except _Abort:
            if ctl.safety_mode() == SAFETY_NORMAL:
                _halt(arm)
            raise

    def _move(self, program: ScriptProgram, call: Call, b: dict) -> None:
        ctl, arm, robot = self.ctl, self.ctl.arm, self.ctl.robot
        why = ctl.ready_to_move()
        if why is not None:
            raise ScriptError(f"line {call.line}: {call.name}: {why}")
        lim = np.asarray(robot.joint_limits_rad, dtype=float)
        q_now = _vector_query(arm.commanded_q_rad, np.array([ctl.clock.now()]))[0]
        if call.name == "movej":
            target = b["q"]
            if isinstance(target, Pose):
                res = kinematics.ik(ctl.dh, ur_pose_to_T(target.values), q_now, lim)
                if not bool(res.success[0]):
                    raise ScriptError(f"line {call.line}: movej: inverse kinematics failed for p{list(target.values)}")
                q = res.q_rad[0]
            else:
                q = np.asarray(target, dtype=float)
            bad = np.nonzero((q < lim[:, 0]) | (q > lim[:, 1]))[0]
            if bad.size:
                j = int(bad[0])
                raise ScriptError(f"line {call.line}: movej: joint {j + 1} target {q[j]:.6g} rad outside its limits")
            v_lim = float(np.min(robot.joint_speed_limits_rad_s))
            a_lim = float(np.min(robot.joint_accel_limits_rad_s2))
            speed_frac = min(1.0, float(b.get("v", 1.05)) / v_lim) if b.get("v", 1.05) > 0 else 1.0
            accel_frac = min(1.0, float(b.get("a", 1.4)) / a_lim) if b.get("a", 1.4) > 0 else 1.0
            t_req = float(b.get("t", 0.0))
            if t_req > 0:
                speed_frac = _speed_frac_for_time(q - q_now, t_req, robot, accel_frac)
            start = lambda: arm.move_joint(q, speed_frac=speed_frac, accel_frac=accel_frac)  # noqa: E731
        else:
            target = b["pose"]
            if isinstance(target, Pose):
                T = ur_pose_to_T(target.values)
            else:
                T = kinematics.fk(ctl.dh, np.asarray(target, dtype=float))
            v = float(b.get("v", 0.25)) * 1000.0
            a = float(b.get("a", 1.2)) * 1000.0
            turn = {}
            p_now = kinematics.tool_position(ctl.dh, q_now)
            if float(np.linalg.norm(T[:3, 3] - p_now)) < TURN_ONLY_MM:  # only turns: v rad/s, a rad/s^2
                turn = {"orientation_speed_rad_s": v / 1000.0 if v > 0 else 0.25,
                        "orientation_accel_rad_s2": a / 1000.0 if a > 0 else 1.2}
            v = min(v, float(robot.max_tcp_speed_mm_s)) if v > 0 else float(robot.max_tcp_speed_mm_s)
            a = a if a > 0 else 1200.0
            t_req = float(b.get("t", 0.0))
            if t_req > 0:  # the path speed whose trapezoid over the straight distance lasts t
                dist = np.array([float(np.linalg.norm(T[:3, 3] - p_now))])
                if dist[0] > 0 and _trap_time(dist, np.array([v]), np.array([a])) < t_req:
                    frac = _speed_frac_for_time_1d(dist, t_req, v, a)
                    v = max(frac * v, 1e-3)
            start = lambda: arm.move_linear(T, speed_mm_s=v, accel_mm_s2=a, **turn)  # noqa: E731
        with ctl.lock:
            ctl.motion_count += 1
            count = ctl.motion_count
        plan = ctl.plan
        while True:
            epoch = self.pause_epoch
            try:
                move = start()
            except Exception as exc:  # the arm refuses (unreachable, limits): a runtime error
                raise ScriptError(f"line {call.line}: {call.name}: {exc}") from exc
            try:
                if count in (plan.protective_stop_move, plan.emergency_stop_move):
                    t_stop = move.t_start + plan.protective_stop_fraction * (move.t_end - move.t_start)
                    self._wait_until(t_stop)
                    if self.pause_epoch == epoch:
                        arm.protective_stop()  # the arm's halt on a stop of either category
                        why = f"fault injected during motion {count} (program {program.name} line {call.line})"
                        if count == plan.emergency_stop_move:
                            ctl.enter_emergency_stop(why)
                        else:
                            ctl.enter_protective_stop(why)
                        raise _Abort()
                self._wait_until(move.t_end)
            except _Abort:
                if ctl.safety_mode() == SAFETY_NORMAL:
                    _halt(arm)
                raise
            if self.pause_epoch == epoch:
                return
            # paused during the move: the arm was halted; go on to the same target


def _blended_run(calls: list, i: int) -> tuple[list, list, int]:
    """The blended run of motion calls starting at ``calls[i]``: it goes on while its last move has a blend
    radius and the next motion (register writes between are deferred to the run's end) is a movel or movec.
    Returns ``(motions, deferred writes, index after the run)``."""
    run, deferred = [calls[i]], []
    j = i + 1
    while float(bind_arguments(run[-1]).get("r", 0.0)) > 0:
        k, writes = j, []
        while k < len(calls) and calls[k].name.startswith("write_output_"):
            writes.append(calls[k])
            k += 1
        if k < len(calls) and calls[k].name in ("movel", "movec"):
            run.append(calls[k])
            deferred += writes
            j = k + 1
        else:
            break
    return run, deferred, j


def _trap_time(d: np.ndarray, v: np.ndarray, a: np.ndarray) -> float:
    """Longest trapezoid/triangle time over joints for displacements d."""
    d = np.abs(d)
    tri = d <= v * v / a
    t = np.where(tri, 2.0 * np.sqrt(d / a), d / v + v / a)
    return float(np.max(t)) if len(t) else 0.0


def _speed_frac_for_time(dq, t_req: float, robot, accel_frac: float) -> float:
    """Speed fraction whose synchronised joint move lasts ``t_req`` (bisection)."""
    vmax = np.asarray(robot.joint_speed_limits_rad_s, dtype=float)
    amax = accel_frac * np.asarray(robot.joint_accel_limits_rad_s2, dtype=float)
    if _trap_time(dq, vmax, amax) >= t_req:
        return 1.0
    lo, hi = 1e-4, 1.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if _trap_time(dq, mid * vmax, amax) > t_req:
            lo = mid
        else:
            hi = mid
    return hi


def _speed_frac_for_time_1d(dist: np.ndarray, t_req: float, v: float, a: float) -> float:
    lo, hi = 1e-6, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _trap_time(dist, np.array([mid * v]), np.array([a])) > t_req:
            lo = mid
        else:
            hi = mid
    return hi


def _halt(arm) -> None:
    """Bring the arm to a controlled stop (stopj/stopl, program stop, pause).

    The simulated arm's stop ramp (``protective_stop``) decelerates every axis
    at its rated acceleration; ``reset`` right after lets the next move queue
    behind the ramp. The controller's safety mode is its own flag, so this
    ordinary stop is never reported as a protective stop.
    """
    if getattr(arm, "state", "idle") == "protective_stop":
        return  # a real protective stop is already bringing the arm to rest
    arm.protective_stop()
    arm.reset()


# ====================================================================== servers


class _Session(threading.Thread):
    def __init__(self, fake: "URFake", sock: socket.socket, kind: str) -> None:
        super().__init__(name=f"ur-fake-{kind}", daemon=False)
        self.fake, self.ctl, self.sock, self.kind = fake, fake.ctl, sock, kind
        self.stop = fake.stop_event
        sock.setblocking(True)
        sock.settimeout(2.0)  # bounds sendall to a client that does not read
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

        self.drop = threading.Event()  # set by sim_drop_rtde: the session thread aborts its link

    def close(self) -> None:
        """Close the socket; call from the session's own thread (or after it ended)."""
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()

    def abort(self) -> None:
        """Drop the link without a goodbye (TCP reset), as a pulled cable or a crash would."""
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        except OSError:
            pass
        self.sock.close()

    def readable(self, timeout: float) -> bool:
        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        return bool(r)


class _RtdeSession(_Session):
    """One RTDE client: handshake, recipes, streaming."""

    def run(self) -> None:
        ctl = self.ctl
        buf = bytearray()
        recipe: rp.Recipe | None = None
        freq = 0.0
        inputs: dict[int, rp.Recipe] = {}
        owned: set[str] = set()
        streaming = False
        t0 = started_at = 0.0
        next_k = 0
        drop_at: float | None = None
        messages = ctl.subscribe()
        clock = ctl.clock
        scale = getattr(clock, "time_scale", 1.0)
        # lockstep: the newest sample's time and bytes, and when a packet last left (host clock)
        last_t, last_packet, last_sent = -math.inf, b"", 0.0
        producer = None  # lockstep, one package at a time: holds the clock at the next unsent sample
        try:
            while not self.stop.is_set():
                wait = 0.05
                if self.drop.is_set():
                    self.abort()
                    return
                if streaming:
                    now = clock.now()
                    if drop_at is not None and now >= drop_at:
                        self.fake.rtde_drops += 1
                        self.abort()
                        return
                    # lockstep with a client that says what it kept (LOCKSTEP_STORED_REGISTER): one at a time
                    one_by_one = ctl.lockstep and ctl.stored_register_in_use()
                    if one_by_one and producer is None:
                        producer = clock.producer("ur-rtde")
                        producer.hold_until(t0 + next_k / freq)
                    elif not one_by_one and producer is not None:
                        producer.release()
                        producer = None
                    kept = not one_by_one or ctl.stored_up_to(last_t)
                    k_due = math.floor((now - t0) * freq + 1e-9)
                    # lockstep: the stream's start and the instants programs stopped at are samples too (the
                    # clock may stand there)
                    # (never one before the stream started: a new client sees no state older than itself)
                    stops = sorted(t for t in ctl.stops_after(last_t) + [started_at]
                                   if last_t < t <= now and t >= started_at) if ctl.lockstep else []
                    ts = None
                    if (k_due >= next_k or stops) and kept:
                        hi = min(k_due, next_k if one_by_one else next_k + MAX_BATCH - 1)
                        ts = t0 + np.arange(next_k, hi + 1) / freq
                        due_to = now if hi == k_due else ts[-1]  # every instant up to here goes now
                        ts = np.union1d(ts, [t for t in stops if t <= due_to])
                        if one_by_one:
                            ts = ts[:1]
                        next_k = max(next_k, math.floor((ts[-1] - t0) * freq + 1e-9) + 1)
                        ts = ts[ts > last_t]  # grid instants before a stop already sent
                    elif ctl.lockstep and last_packet and time.monotonic() - last_sent >= 1.0 / freq:
                        self.sock.sendall(last_packet)  # at rest, or not yet kept: the same state again
                        last_sent = time.monotonic()
                    if producer is not None:  # before the package leaves: the client may ask the world on at once
                        producer.hold_until(t0 + next_k / freq)
                    if ts is not None and len(ts):
                        cols = ctl.columns(recipe.names, ts)
                        data = recipe.encode_batch(cols, len(ts))
                        self.sock.sendall(data)
                        last_t, last_packet, last_sent = float(ts[-1]), data[-recipe.packet_size:], time.monotonic()
                        self.fake.count_sent(len(ts))
                    while messages:
                        text, level = messages.popleft()
                        self.sock.sendall(rp.encode_text_message(text, "Controller", level))
                    if one_by_one:  # wait for the client to keep the last one, then for the next instant
                        beat = max(0.0, last_sent + 1.0 / freq - time.monotonic())
                        if not ctl.stored_up_to(last_t):
                            ctl.await_stored(last_t, beat)
                        elif ts is None or not len(ts):  # short: a program may stop meanwhile
                            clock.wait_for(t0 + next_k / freq, min(beat, STOP_LOOK_S))
                        wait = 0.0
                    else:
                        left_sim = t0 + next_k / freq - clock.now()
                        wait = 0.0 if left_sim <= 0 else (min(0.05, left_sim / scale) if math.isfinite(scale) else 0.005)
                        if ctl.lockstep:
                            wait = min(wait, 1.0 / freq)
                if not self.readable(wait):
                    continue
                data = self.sock.recv(65536)
                if not data:
                    return
                buf += data
                while True:
                    n, pkt = rp.decode(buf)
                    if not n:
                        break
                    del buf[:n]
                    c = pkt.command
                    if c == rp.CMD_REQUEST_PROTOCOL_VERSION:
                        version = rp.parse_protocol_version_request(pkt.payload)
                        self.sock.sendall(rp.encode_protocol_version_reply(version == rp.PROTOCOL_VERSION))
                    elif c == rp.CMD_GET_URCONTROL_VERSION:
                        self.sock.sendall(rp.encode_controller_version(*CONTROLLER_VERSION))
                    elif c == rp.CMD_SETUP_OUTPUTS:
                        f, names = rp.parse_setup_outputs(pkt.payload)
                        types = [rp.output_type(nm) for nm in names]
                        ok = rp.NOT_FOUND not in types and f <= MAX_FREQUENCY_HZ and not streaming
                        if ok:
                            recipe, freq = rp.Recipe(1, names, types), f
                        elif f > MAX_FREQUENCY_HZ:
                            ctl.message(f"RTDE output frequency {f:g} Hz above {MAX_FREQUENCY_HZ:g} Hz", rp.MESSAGE_ERROR)
                        self.sock.sendall(rp.encode_setup_reply(c, 1 if ok else 0, types))
                    elif c == rp.CMD_SETUP_INPUTS:
                        names = rp.parse_setup_inputs(pkt.payload)
                        with ctl.lock:
                            types = [
                                rp.IN_USE if (nm in ctl.inputs_in_use and nm not in owned) else rp.input_type(nm)
                                for nm in names
                            ]
                            ok = not ({rp.NOT_FOUND, rp.IN_USE} & set(types)) and len(inputs) < 255
                            rid = len(inputs) + 1 if ok else 0
                            if ok:
                                inputs[rid] = rp.Recipe(rid, names, types)
                                owned.update(names)
                                ctl.inputs_in_use.update(names)
                                if _STORED_INPUT in names:  # a new owner has kept nothing yet
                                    ctl.in_double[LOCKSTEP_STORED_REGISTER] = -math.inf
                        self.sock.sendall(rp.encode_setup_reply(c, rid, types))
                    elif c == rp.CMD_START:
                        ok = recipe is not None or bool(inputs)
                        self.sock.sendall(rp.encode_start_reply(ok))
                        if ok and recipe is not None and not streaming:
                            streaming = True
                            started_at = clock.now()
                            t0 = math.ceil(started_at / TICK_S) * TICK_S
                            next_k = 0
                            with ctl.lock:
                                if ctl.plan.rtde_drop_after_s is not None and not ctl.rtde_drop_used:
                                    ctl.rtde_drop_used = True
                                    drop_at = t0 + ctl.plan.rtde_drop_after_s
                    elif c == rp.CMD_PAUSE:
                        streaming = False
                        if producer is not None:  # a paused stream holds the clock no more
                            producer.release()
                            producer = None
                        self.sock.sendall(rp.encode_pause_reply(True))
                    elif c == rp.CMD_DATA_PACKAGE:
                        rid = rp.data_recipe_id(pkt.payload)
                        if rid not in inputs:
                            raise ProtocolError(f"RTDE data package for unknown input recipe {rid}")
                        self._apply_inputs(inputs[rid].decode(pkt.payload))
                    elif c == rp.CMD_TEXT_MESSAGE:
                        text, source, _level = rp.parse_text_message(pkt.payload)
                        ctl.message(f"client {source}: {text}", rp.MESSAGE_INFO)
        except (ProtocolError, DataError) as exc:
            self.fake.protocol_errors.append(str(exc))
            try:
                self.sock.sendall(rp.encode_text_message(f"RTDE protocol error: {exc}", "Controller", rp.MESSAGE_ERROR))
            except OSError:
                pass
        except OSError:
            pass
        finally:
            if producer is not None:
                producer.release()
            ctl.unsubscribe(messages)
            with ctl.lock:
                ctl.inputs_in_use.difference_update(owned)
                ctl.inputs_changed.notify_all()
            self.close()

    def _apply_inputs(self, values: dict) -> None:
        ctl = self.ctl
        with ctl.lock:
            ctl.inputs_changed.notify_all()  # its waiters look once this lock is released, values written
            for name, v in values.items():
                m = re.match(r"^input_(int|double|bit)_register_(\d+)$", name)
                if not m:
                    continue
                idx = int(m.group(2))
                if m.group(1) == "int":
                    ctl.in_int[idx] = int(v)
                elif m.group(1) == "double":
                    ctl.in_double[idx] = float(v)
                else:
                    bit = 1 << (idx - 64)
                    ctl.in_bits = (ctl.in_bits | bit) if v else (ctl.in_bits & ~bit)


class _DashboardSession(_Session):
    GREETING = "Connected: Universal Robots Dashboard Server"

    def run(self) -> None:
        try:
            if "connect" in self.ctl.plan.dashboard_refuse:
                return
            self.sock.sendall((self.GREETING + "\n").encode())
            buf = b""
            while not self.stop.is_set():
                if not self.readable(0.1):
                    continue
                data = self.sock.recv(4096)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    raw, buf = buf.split(b"\n", 1)
                    line = raw.decode("utf-8", "replace").strip()
                    reply, close = self.fake.dashboard_reply(line)
                    self.sock.sendall((reply + "\n").encode("utf-8"))
                    if close:
                        return
                if len(buf) > MAX_DASHBOARD_LINE:
                    buf = b""
                    self.sock.sendall(b"could not understand: line too long\n")
        except OSError:
            pass
        finally:
            self.close()


class _ScriptSession(_Session):
    def run(self) -> None:
        splitter = ScriptSplitter()
        try:
            while not self.stop.is_set():
                if not self.readable(0.1):
                    continue
                data = self.sock.recv(65536)
                if not data:
                    break
                try:
                    programs = splitter.feed(data)
                except ScriptError as exc:
                    self.fake.refuse_script(str(exc))
                    continue
                for text in programs:
                    self.fake.run_script(text)
            if splitter.pending():
                self.fake.refuse_script("program not terminated by 'end' when the connection closed")
        except OSError:
            pass
        finally:
            self.close()


class _Listener(threading.Thread):
    def __init__(self, fake: "URFake", sock: socket.socket, kind: str, session_cls) -> None:
        super().__init__(name=f"ur-fake-listen-{kind}", daemon=False)
        self.fake, self.sock, self.kind, self.session_cls = fake, sock, kind, session_cls

    def run(self) -> None:
        while not self.fake.stop_event.is_set():
            r, _, _ = select.select([self.sock], [], [], 0.1)
            if not r:
                continue
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            session = self.session_cls(self.fake, conn, self.kind)
            if not self.fake.add_session(session):
                conn.close()
                return
            session.start()
        self.sock.close()


# ====================================================================== the fake


def _bind_all(host: str, ports: dict) -> dict[str, socket.socket]:
    socks: dict[str, socket.socket] = {}
    try:
        for kind, port in ports.items():
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            socks[kind] = s
            s.bind((host, port))
            s.listen(8)
    except OSError:
        for s in socks.values():
            s.close()
        raise
    return socks


def _check_loopback(host: str) -> None:
    parts = host.split(".")
    if len(parts) != 4 or not all(p.isdigit() and 0 <= int(p) <= 255 for p in parts) or parts[0] != "127":
        raise ConfigError(f"UR fake host must be an IPv4 loopback address 127.x.y.z, got {host!r}")


class URFake:
    """Handle of a running UR fake: ``endpoint``, ``close()`` and ``sim_`` controls.

    Attributes
    ----------
    endpoint : dict
        ``{"host": "127.0.0.N", "rtde": 30004, "dashboard": 29999, "script": 30003}``
    scripts_received : list of str
        Every program text that reached the script port, in order.
    script_errors : list of str
        Refusals (compile errors), in order.
    messages : list of str
        Every text message the controller emitted.
    """

    def __init__(self, world, host: str, plan: FaultPlan, socks: dict[str, socket.socket], *,
                 lockstep: bool = False) -> None:
        self.world = world
        self.plan = plan
        self.ctl = _Controller(world, plan)
        # real time: the clock runs while served, as a real controller's; lockstep: programs run it
        self.lockstep = self.ctl.lockstep = bool(lockstep)
        self._running = None if self.lockstep else keep_running(world.clock)
        self.stop_event = threading.Event()
        self.endpoint = {"host": host, **{k: socks[k].getsockname()[1] for k in ("rtde", "dashboard", "script")}}
        self.protocol_errors: list[str] = []
        self.rtde_drops = 0
        self._sent_lock = threading.Lock()
        self._packets_sent = 0
        self._sessions: list[_Session] = []
        self._sessions_lock = threading.Lock()
        self._closed = False
        self.interpreter = _Interpreter(self.ctl, self.stop_event)
        self._listeners = [
            _Listener(self, socks["rtde"], "rtde", _RtdeSession),
            _Listener(self, socks["dashboard"], "dashboard", _DashboardSession),
            _Listener(self, socks["script"], "script", _ScriptSession),
        ]
        self.interpreter.thread.start()
        for t in self._listeners:
            t.start()

    # ------------------------------------------------------------ bookkeeping
    @property
    def scripts_received(self) -> list[str]:
        with self.ctl.lock:
            return list(self.ctl.scripts_received)

    @property
    def script_errors(self) -> list[str]:
        with self.ctl.lock:
            return list(self.ctl.script_errors)

    @property
    def messages(self) -> list[str]:
        with self.ctl.lock:
            return list(self.ctl.messages)

    @property
    def packets_sent(self) -> int:
        """RTDE data packages sent to all sessions so far."""
        with self._sent_lock:
            return self._packets_sent

    def count_sent(self, n: int) -> None:
        with self._sent_lock:
            self._packets_sent += n

    def add_session(self, s: _Session) -> bool:
        with self._sessions_lock:
            if self._closed:
                return False
            self._sessions = [x for x in self._sessions if x.is_alive()]
            self._sessions.append(s)
            return True

    def sim_drop_rtde(self) -> int:
        """Close every RTDE connection abruptly now (test-only control); how many."""
        with self._sessions_lock:
            victims = [s for s in self._sessions if isinstance(s, _RtdeSession) and s.is_alive()]
        for s in victims:
            s.drop.set()
        self.rtde_drops += len(victims)
        return len(victims)

    def sim_release_emergency_stop(self) -> None:
        """The emergency stop button turned back (test-only control): safety mode NORMAL, robot still IDLE
        (``brake release`` on the dashboard makes it RUNNING)."""
        with self.ctl.lock:
            self.ctl.emergency_stopped = False
            if getattr(self.ctl.arm, "state", "") == "protective_stop":
                self.ctl.arm.reset()

    def sim_add_program(self, path: str, urscript: str) -> None:
        """Store a program that ``load <path>`` then ``play`` runs (test-only control)."""
        parse_program(urscript, "program")  # refuse at once what could never run
        if not path.startswith("/"):
            path = "/programs/" + path
        with self.ctl.lock:
            self.ctl.programs[path] = urscript

    # ------------------------------------------------------------ script port
    def refuse_script(self, why: str) -> None:
        with self.ctl.lock:
            self.ctl.script_errors.append(why)
        self.ctl.message(f"Compile error: {why}")

    def run_script(self, text: str) -> None:
        with self.ctl.lock:
            self.ctl.scripts_received.append(text)
            n = len(self.ctl.scripts_received)
        if self.plan.refuse_script == n:
            first = text.strip().splitlines()[0] if text.strip() else ""
            self.refuse_script(f"fault injected: program {n} ({first[:40]!r}) refused")
            return
        try:
            program = parse_program(text)
        except ScriptError as exc:
            self.refuse_script(str(exc))
            return
        self.interpreter.submit(program)

    # ------------------------------------------------------------ dashboard
    def dashboard_reply(self, line: str) -> tuple[str, bool]:
        """Reply to one dashboard command line; (reply, close connection).

        Commands are looked up in :data:`DASHBOARD_COMMANDS` (whole line) or
        :data:`DASHBOARD_PREFIXES` (first word), case-insensitively.
        """
        low = line.lower()
        word = low.split(" ", 1)[0] if low else ""
        if word in self.plan.dashboard_refuse or low in self.plan.dashboard_refuse:
            return f"Failed to execute: {line}", False
        handler = DASHBOARD_COMMANDS.get(low) or DASHBOARD_PREFIXES.get(word)
        if handler is None:
            return f"could not understand: '{line}'", False
        with self.ctl.lock:
            reply = handler(self, self.ctl, line)
        return reply if isinstance(reply, tuple) else (reply, False)

    def _program_names(self) -> tuple[str | None, str]:
        name = self.ctl.loaded_program
        return name, (name.rsplit("/", 1)[-1] if name else "<unnamed>")

    # the dashboard's commands: (fake, controller state, line) -> reply or (reply, close)
    def _dash_play(self, ctl, line):
        if ctl.ready_to_move() is not None:
            return "Failed to execute: play"
        if ctl.runtime_state == RUNTIME_PAUSED and self.interpreter.resume():  # a paused program (a script too)
            return "Starting program"
        name, base = self._program_names()
        if name is None:
            return "Failed to execute: play"
        if ctl.runtime_state == RUNTIME_PLAYING:
            return "Failed to execute: play"
        self.interpreter.submit(parse_program(ctl.programs[name], base.rsplit(".", 1)[0]))
        ctl.runtime_state = RUNTIME_PLAYING
        return "Starting program"

    def _dash_stop(self, ctl, line):
        if ctl.runtime_state == RUNTIME_STOPPED and not self.interpreter.stoppable():
            return "Failed to execute: stop"
        self.interpreter.abort("stopped from the dashboard")
        ctl.runtime_state = RUNTIME_STOPPED
        return "Stopped"

    def _dash_pause(self, ctl, line):
        if ctl.runtime_state != RUNTIME_PLAYING or not self.interpreter.pause():
            return "Failed to execute: pause"
        _halt(ctl.arm)
        if self.lockstep:  # the halted arm comes to rest while the program is paused
            ctl.clock.schedule(ctl.arm.queue_end_s + SETTLE_S)
        return "Pausing program"

    def _dash_load(self, ctl, line):
        path = line[5:].strip()
        full = path if path.startswith("/") else "/programs/" + path
        if full not in ctl.programs:
            return f"File not found: {path}"
        if ctl.runtime_state != RUNTIME_STOPPED:
            return f"Error while loading program: {path}"
        ctl.loaded_program = full
        return f"Loading program: {path}"

    def _dash_program_state(self, ctl, line):
        state = {RUNTIME_PLAYING: "PLAYING", RUNTIME_PAUSED: "PAUSED"}.get(ctl.runtime_state, "STOPPED")
        return f"{state} {self._program_names()[1]}"

    def _dash_loaded_program(self, ctl, line):
        name = ctl.loaded_program
        return f"Loaded program: {name}" if name else "No program loaded"

    def _dash_power_on(self, ctl, line):
        if ctl.robot_mode == MODE_POWER_OFF:
            ctl.robot_mode = MODE_IDLE
        return "Powering on"

    def _dash_power_off(self, ctl, line):
        self.interpreter.abort("robot powered off")
        ctl.robot_mode = MODE_POWER_OFF
        return "Powering off"

    def _dash_brake_release(self, ctl, line):
        if ctl.robot_mode == MODE_IDLE:
            ctl.robot_mode = MODE_RUNNING
        return "Brake releasing"

    def _dash_unlock_protective_stop(self, ctl, line):
        if ctl.safety_mode() == SAFETY_PROTECTIVE_STOP:
            since = ctl.clock.now() - (ctl.protective_stop_t if ctl.protective_stop_t is not None else -1e9)
            if since < UNLOCK_DELAY_S:
                return ("Cannot unlock protective stop until 5s after occurrence. "
                        "Always inspect cause of protective stop before unlocking")
            if getattr(ctl.arm, "state", "") == "protective_stop":
                ctl.arm.reset()
            ctl.protective_stop_t = None
        return "Protective stop releasing"

    def _dash_robot_model(self, ctl, line):
        return ctl.robot.name.upper().rstrip("E") if ctl.robot.controller == "ur" else "UR5"

    def _dash_shutdown(self, ctl, line):
        self.interpreter.abort("shutdown")
        ctl.robot_mode = MODE_POWER_OFF
        return "Shutting down", True

    # ------------------------------------------------------------ lifetime
    def close(self, timeout_s: float = 5.0) -> None:
        """Stop the servers and the interpreter; join every thread."""
        with self._sessions_lock:
            if self._closed:
                return
            self._closed = True
            sessions = list(self._sessions)
        self.stop_event.set()
        self.interpreter.wake.set()
        with self.interpreter.cond:
            self.interpreter.cond.notify_all()
        for t in self._listeners:
            t.join(timeout_s)
        for s in sessions:  # each session sees stop_event within 0.1 s and closes its own socket
            s.join(timeout_s)
        self.interpreter.thread.join(timeout_s)
        stop_running(self._running)
        alive = [t.name for t in (*self._listeners, *sessions, self.interpreter.thread) if t.is_alive()]
        if alive:
            raise RuntimeError(f"UR fake threads did not stop: {alive}")

    def __enter__(self) -> "URFake":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_fake(world, *, host: str | None = None, port: int | None = None, faults: dict | None = None,
               lockstep: bool = False) -> URFake:
    """Start the UR fake on a loopback address of its own.

    Parameters
    ----------
    world : World
        Supplies ``clock``, ``robot`` and ``arm``.
    host : str, optional
        ``127.x.y.z``; default: the first of 127.0.0.2 .. 127.0.0.254 whose
        three ports are free.
    port : int, optional
        Must be None or 30004: ``ur_rtde`` fixes the ports.
    faults : dict of str, optional
        Fault injection keys (module docstring).
    lockstep : bool
        Leave the world's clock to the programs (module docstring); its driver then needs
        ``?lockstep=1``.
    """
    if port not in (None, PORTS["rtde"]):
        raise ConfigError(f"the UR fake serves the fixed ur_rtde ports {PORTS}; port {port!r} cannot be chosen")
    plan = FaultPlan.parse(faults)
    if host is not None:
        _check_loopback(host)
        try:
            socks = _bind_all(host, PORTS)
        except OSError as exc:
            raise ConfigError(f"cannot bind the UR ports {sorted(PORTS.values())} on {host}: {exc}") from exc
        return URFake(world, host, plan, socks, lockstep=lockstep)
    for n in range(2, 255):
        candidate = f"127.0.0.{n}"
        try:
            socks = _bind_all(candidate, PORTS)
        except OSError:
            continue
        return URFake(world, candidate, plan, socks, lockstep=lockstep)
    raise ConfigError("no free loopback address 127.0.0.2..254 has the UR ports free")


def _const(reply: str, close: bool = False):
    return lambda fake, ctl, line: (reply, close)


#: dashboard commands matched on the whole (lower-cased) line
DASHBOARD_COMMANDS = {
    "play": URFake._dash_play,
    "stop": URFake._dash_stop,
    "pause": URFake._dash_pause,
    "running": lambda fake, ctl, line: f"Program running: {'true' if ctl.runtime_state == RUNTIME_PLAYING else 'false'}",
    "programstate": URFake._dash_program_state,
    "get loaded program": URFake._dash_loaded_program,
    "isprogramsaved": lambda fake, ctl, line: f"true {fake._program_names()[1]}",
    "robotmode": lambda fake, ctl, line: f"Robotmode: {ROBOT_MODE[ctl.robot_mode]}",
    "safetymode": lambda fake, ctl, line: f"Safetymode: {SAFETY_MODE[ctl.safety_mode()]}",
    "safetystatus": lambda fake, ctl, line: f"Safetystatus: {SAFETY_MODE[ctl.safety_mode()]}",
    "power on": URFake._dash_power_on,
    "power off": URFake._dash_power_off,
    "brake release": URFake._dash_brake_release,
    "unlock protective stop": URFake._dash_unlock_protective_stop,
    "close safety popup": _const("closing safety popup"),
    "restart safety": _const("Restarting safety"),
    "is in remote control": _const("true"),
    "polyscopeversion": _const(POLYSCOPE_VERSION),
    "get serial number": _const(SERIAL_NUMBER),
    "get robot model": URFake._dash_robot_model,
    "close popup": _const("closing popup"),
    "quit": _const("Disconnected", True),
    "shutdown": URFake._dash_shutdown,
}

#: dashboard commands matched on the first word (they take an argument)
DASHBOARD_PREFIXES = {
    "load": URFake._dash_load,
    "popup": _const("showing popup"),
    "addtolog": _const("Added log message"),
}
