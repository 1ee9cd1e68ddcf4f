"""Universal Robots e-Series cobot driver built on the real ``ur_rtde`` package.

* **State** from ``rtde_receive.RTDEReceiveInterface``: timestamp (the
  controller's clock), joint positions, commanded joints, TCP pose and speed,
  robot mode, safety mode and status bits, runtime state, and two output
  integer registers the driver's programs write.
* **Motion** by URScript sent to the script port (``script_client``): every
  move is a small ``def ... end`` program that writes a sequence number to
  output register ``register_base`` when it starts and to
  ``register_base + 1`` when its motion is done, so the driver knows from the
  RTDE stream alone that *its* program ran. **The safety gate checks every
  target, path and speed before a byte is sent** (:class:`station.safety.SafetyGate`).
* **Programs run whole** (:meth:`URDriver.run`, the robot interface of
  :mod:`drivers.robot`): a station :class:`~station.programs.program.Program`
  is gated move by move from the joints RTDE reports, rendered as one
  URScript program (:mod:`station.programs.urscript`; registers
  ``register_base + 2`` and ``+ 3`` carry the moves and cycles done) and
  watched on RTDE until the arm rests on its last target.
* **Program and power state** through ``dashboard_client.DashboardClient``.

``RTDEReceiveInterface``'s constructor holds the Python GIL while it waits
for the controller's handshake replies, so a controller served by the same
process (the station's simulated world and its fakes) could never answer. The
receive interface therefore lives in a small **sidecar process** owned by the
driver (``multiprocessing`` spawn context): it polls the interface's getters,
keeps every new timestamp's sample and ships them to the driver on request.
With a simulated controller in lockstep it also says, through ``ur_rtde``'s IO
interface, which sample it kept, and is sent the next only then (every sample
reaches the driver; :data:`station.protocols.ur.LOCKSTEP_STORED_REGISTER`).
The dashboard and script clients release the GIL and stay in-process.

Errors (:mod:`station.errors`)::

    target, path or speed refused            -> SafetyError (nothing sent)
    robot powered off / in protective stop   -> DeviceNotReady
    protective stop during a move            -> DeviceFault (robot halted, program stopped)
    dashboard refusal, program not started   -> DeviceError
    RTDE stream lost or stale                -> ConnectionLost (motion halted if possible)
    no reply / motion not done in time       -> DeviceTimeout

Units: joint angles rad, positions mm, TCP rotations as rotation vectors
(rad), speeds mm/s; the controller's wire units (m, m/s) are converted here.
"""

from __future__ import annotations

import math
import os
import re
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Collection

import numpy as np

from drivers.transport import Deadline, ListeningDeadline, run_queue_delay_s
from station.device_urls import parse_device_url
from station.models.rotation import matrix_to_rotvec, ur_pose_to_T
from station.protocols.ur import (LOCKSTEP_STORED_REGISTER, SAFETY_BIT_PROTECTIVE, SAFETY_BITS_EMERGENCY, RobotMode,
                                  RuntimeState, SafetyMode)
from station.errors import (
    ConfigError,
    ConnectionLost,
    DeviceError,
    DeviceFault,
    DeviceNotReady,
    DeviceTimeout,
    SafetyError,
)

DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003

# the protocol's mode numbers (shared with the fake)
ROBOT_MODE_POWER_OFF, ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING = RobotMode.POWER_OFF, RobotMode.IDLE, RobotMode.RUNNING
SAFETY_MODE_NORMAL, SAFETY_MODE_REDUCED = SafetyMode.NORMAL, SafetyMode.REDUCED
RUNTIME_STOPPED, RUNTIME_PLAYING, RUNTIME_PAUSED = RuntimeState.STOPPED, RuntimeState.PLAYING, RuntimeState.PAUSED
_SAFETY_BIT_PROTECTIVE = SAFETY_BIT_PROTECTIVE
_SAFETY_BITS_EMERGENCY = SAFETY_BITS_EMERGENCY

# sample row layout shipped by the sidecar
_C_T = 0
_C_Q = slice(1, 7)
_C_QT = slice(7, 13)
_C_POSE = slice(13, 19)
_C_SPEED = slice(19, 25)
_C_ROBOT_MODE, _C_SAFETY_MODE, _C_SAFETY_BITS, _C_RUNTIME, _C_STATUS, _C_REG_START, _C_REG_DONE = range(25, 32)
_C_REG_MOVES, _C_REG_CYCLES = 32, 33
N_COLUMNS = 34


def rtde_variables(register_base: int) -> list[str]:
    """Output variables the driver's receive interface asks for."""
    return [
        "timestamp", "actual_q", "target_q", "actual_TCP_pose", "actual_TCP_speed",
        "robot_mode", "safety_mode", "safety_status_bits", "runtime_state", "robot_status_bits",
        f"output_int_register_{register_base}", f"output_int_register_{register_base + 1}",
        f"output_int_register_{register_base + 2}", f"output_int_register_{register_base + 3}",
    ]


# ====================================================================== sidecar


def _sidecar_main(conn, host: str, frequency_hz: float, register_base: int, poll_s: float, max_samples: int,
                  stored_register: int | None = None):
    """Child process: own the RTDE receive interface, buffer every new sample.

    ``stored_register``: a simulated controller in lockstep
    (:data:`~station.protocols.ur.LOCKSTEP_STORED_REGISTER`): after each new
    sample the child writes its timestamp to that input double register
    (``ur_rtde``'s IO interface), and the controller sends the next one only then.

    Returns the interface (still connected) so that the caller decides when it
    is destroyed (its destructor sleeps 0.5 s).
    """
    parent = os.getppid()
    io = None
    try:
        import rtde_io
        import rtde_receive

        # the interpreter is up and has imported what it needs: from here on the time is the device's
        conn.send(("started", None))
        if stored_register is not None:  # first: the stream goes one by one from its first package
            io = rtde_io.RTDEIOInterface(host)
        rtde = rtde_receive.RTDEReceiveInterface(host, float(frequency_hz), rtde_variables(register_base))
    except Exception as exc:  # noqa: BLE001 - reported to the parent verbatim
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        conn.close()
        return None
    lock = threading.Lock()
    buf: deque = deque()
    state = {"dropped": 0, "connected": True}
    stop = threading.Event()
    r0, r1 = register_base, register_base + 1

    def read_row(ts: float):
        row = [ts]
        row += rtde.getActualQ()
        row += rtde.getTargetQ()
        row += rtde.getActualTCPPose()
        row += rtde.getActualTCPSpeed()
        row += [rtde.getRobotMode(), rtde.getSafetyMode(), rtde.getSafetyStatusBits(),
                rtde.getRuntimeState(), rtde.getRobotStatus(),
                rtde.getOutputIntRegister(r0), rtde.getOutputIntRegister(r1),
                rtde.getOutputIntRegister(r0 + 2), rtde.getOutputIntRegister(r0 + 3)]
        return row

    def sample() -> None:
        last = None
        while not stop.is_set():
            ts = rtde.getTimestamp()
            if ts == last:
                connected = rtde.isConnected()
                with lock:
                    state["connected"] = connected
                time.sleep(poll_s)
                continue
            if ts > 0:
                row = read_row(ts)
                for _ in range(5):  # the receive thread may update between getters: twice the same, or the last
                    ts2 = rtde.getTimestamp()
                    row2 = read_row(ts2)
                    if row2 == row:
                        break
                    ts, row = ts2, row2
                if len(row) == N_COLUMNS:
                    with lock:
                        if len(buf) >= max_samples:
                            buf.popleft()
                            state["dropped"] += 1
                        buf.append(row)
                    if io is not None:
                        io.setInputDoubleRegister(stored_register, ts)
            last = ts

    sampler = threading.Thread(target=sample, name="ur-rtde-sampler")
    sampler.start()
    conn.send(("ready", None))
    try:
        while True:
            if not conn.poll(0.1):
                if os.getppid() != parent:
                    break  # the driver's process is gone
                continue
            msg = conn.recv()
            if msg[0] == "drain":
                with lock:
                    rows = list(buf)
                    buf.clear()
                    dropped, state["dropped"] = state["dropped"], 0
                    connected = state["connected"]
                arr = np.array(rows, dtype=float).reshape(-1, N_COLUMNS)
                conn.send(("samples", arr, dropped, connected))
            elif msg[0] == "close":
                break
    except (EOFError, OSError):
        pass
    stop.set()
    sampler.join()
    try:
        conn.send(("closed", None))
        conn.close()
    except (OSError, ValueError):
        pass
    return rtde


def _sidecar_entry() -> None:
    """``python -c 'import drivers.ur as m; m._sidecar_entry()' FD HOST FREQ BASE POLL MAX STORED`` (-1: none)."""
    from multiprocessing.connection import Connection

    fd, host, freq, base, poll, max_samples, stored = sys.argv[1:8]
    rtde = _sidecar_main(Connection(int(fd)), host, float(freq), int(base), float(poll), int(max_samples),
                         int(stored) if int(stored) >= 0 else None)
    # leave at once, rtde still referenced: ur_rtde's disconnect() sleeps 0.5 s; the kernel closes the socket
    sys.stdout.flush()
    os._exit(0)


#: the longest a fresh receive process may take to start and import ``ur_rtde`` (real s): the host's time, not the
#: device's; an idle host takes about 0.3 s, one loaded by two busy processes per core several seconds
SIDECAR_START_S = 120.0
#: the driver looks at the receive process at least this often while it waits for the controller (the
#: handshake, a sample, a program's start and end, the arm's rest; real s): a longer gap between two looks is
#: a host that did not run the driver (nor a simulated controller in its process), and only this much of it
#: counts; nor does the time the receive process waited for this host (:class:`drivers.transport.ListeningDeadline`)
LISTEN_SLICE_S = 0.1
#: lockstep: the host's own wait for the handshake lasts at least this (real s). A simulated controller's clock
#: stands still through a handshake, so no device time can bound it, and it runs on this host, whose load
#: alone makes it late (a real controller is never in lockstep; its handshake keeps the driver's timeout)
LOCKSTEP_HANDSHAKE_S = 60.0


class RtdeSidecar:
    """``ur_rtde``'s receive interface in a child process (see module docstring).

    The child is a fresh interpreter (``subprocess``) that imports only this
    module and ``rtde_receive``; it talks to the driver over a socket pair
    wrapped in ``multiprocessing.connection.Connection``.

    Parameters
    ----------
    host : str
    frequency_hz : float
        RTDE output frequency to ask for (e-Series: up to 500 Hz).
    register_base : int
        First of the two output integer registers the driver's programs write.
    poll_s : float
        How often the child polls the interface's timestamp (real seconds).
    max_samples : int
        Samples the child keeps between two drains (older ones are counted as dropped).
    stored_register : int or None
        A simulated controller in lockstep: the input double register where the child says which sample it
        kept (:data:`~station.protocols.ur.LOCKSTEP_STORED_REGISTER`), so that it receives every one.
    """

    def __init__(self, host: str, frequency_hz: float = 500.0, register_base: int = 12,
                 poll_s: float = 2e-4, max_samples: int = 200_000, stored_register: int | None = None) -> None:
        self.host = host
        self.stored_register = stored_register
        self.frequency_hz = float(frequency_hz)
        self.register_base = int(register_base)
        self.poll_s = float(poll_s)
        self.max_samples = int(max_samples)
        self._proc: subprocess.Popen | None = None
        self._conn = None
        self._lock = threading.Lock()

    def start(self, timeout_s: float) -> None:
        from multiprocessing.connection import Connection

        ours, theirs = socket.socketpair()
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
        try:
            proc = subprocess.Popen(
                [sys.executable, "-c", "import drivers.ur as m; m._sidecar_entry()", str(theirs.fileno()),
                 self.host, repr(self.frequency_hz), str(self.register_base), repr(self.poll_s),
                 str(self.max_samples), str(-1 if self.stored_register is None else int(self.stored_register))],
                pass_fds=(theirs.fileno(),),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                env=env,
            )
        except OSError as exc:
            ours.close()
            theirs.close()
            raise DeviceNotReady(f"RTDE {self.host}: cannot start the receive process: {exc}") from exc
        theirs.close()
        self._proc, self._conn = proc, Connection(ours.detach())
        # two waits: the start of a fresh interpreter is this host's time (seconds on a loaded host), bounded
        # apart; the device's handshake gets timeout_s from the moment the process is ready to connect,
        # counted only while this host ran both the driver and the receive process (a loaded host's run
        # queue is not the device's silence); a simulated controller's at least LOCKSTEP_HANDSHAKE_S
        kind, info = self._handshake_message(Deadline(SIDECAR_START_S), SIDECAR_START_S,
                                             "the receive process did not start")
        if kind == "started":
            wait_s = max(timeout_s, LOCKSTEP_HANDSHAKE_S) if self.stored_register is not None else timeout_s
            deadline = ListeningDeadline(wait_s, LISTEN_SLICE_S, host_delay=lambda: run_queue_delay_s(proc.pid))
            kind, info = self._handshake_message(deadline, wait_s, "no handshake")
        if kind != "ready":
            self._kill()
            raise ConnectionLost(f"RTDE {self.host}:30004: ur_rtde could not connect: {info}")

    def host_delay_s(self) -> float:
        """Seconds the receive process has waited for this host to run it (0.0 when none runs)."""
        proc = self._proc
        return run_queue_delay_s(proc.pid) if proc is not None else 0.0

    def _handshake_message(self, deadline, timeout_s: float, what: str):
        """The receive process's next message during the start, or the process killed and an error."""
        while not self._conn.poll(min(LISTEN_SLICE_S, deadline.time_left())):
            if deadline.expired():
                self._kill()
                raise DeviceTimeout(f"RTDE {self.host}:30004: {what} within {timeout_s:g} s")
        try:
            return self._conn.recv()
        except (EOFError, OSError) as exc:
            self._kill()
            raise ConnectionLost(f"RTDE {self.host}:30004: receive process ended during the handshake") from exc

    def drain(self, timeout_s: float = 5.0) -> tuple[np.ndarray, int, bool]:
        """``(rows (N, 34), dropped, connected)`` since the last drain."""
        with self._lock:
            if self._conn is None:
                raise ConnectionLost(f"RTDE {self.host}: receive process not running")
            try:
                self._conn.send(("drain",))
                if not self._conn.poll(timeout_s):
                    raise DeviceTimeout(f"RTDE {self.host}: receive process did not answer within {timeout_s} s")
                kind, rows, dropped, connected = self._conn.recv()
            except (EOFError, OSError) as exc:
                raise ConnectionLost(f"RTDE {self.host}: receive process ended") from exc
        return rows, dropped, connected

    def close(self, timeout_s: float = 5.0) -> None:
        with self._lock:
            conn, proc = self._conn, self._proc
            self._conn = self._proc = None
        if proc is None:
            return
        try:
            conn.send(("close",))
            if conn.poll(timeout_s):
                conn.recv()
        except (EOFError, OSError):
            pass
        conn.close()
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)

    def _kill(self) -> None:
        proc, conn = self._proc, self._conn
        self._proc = self._conn = None
        if proc is not None:
            proc.kill()
            proc.wait(5.0)
        if conn is not None:
            conn.close()


# ====================================================================== state


@dataclass(frozen=True)
class URState:
    """One RTDE sample.

    Attributes
    ----------
    t_s : float
        Controller timestamp, s.
    q_rad, target_q_rad : ndarray, shape (6,)
        Measured and commanded joint angles.
    tcp_T : ndarray, shape (4, 4)
        TCP pose reported by the controller (its nominal kinematics), mm.
    tcp_rotvec_rad : ndarray, shape (3,)
    tcp_speed : ndarray, shape (6,)
        Linear mm/s and angular rad/s.
    robot_mode, safety_mode, safety_status_bits, runtime_state, robot_status_bits : int
    register_start, register_done : int
        The driver's program sequence registers.
    register_moves, register_cycles : int
        Moves and cycles done by the running (or last) program (:mod:`station.programs.urscript`).
    """

    t_s: float
    q_rad: np.ndarray
    target_q_rad: np.ndarray
    tcp_T: np.ndarray
    tcp_rotvec_rad: np.ndarray
    tcp_speed: np.ndarray
    robot_mode: int
    safety_mode: int
    safety_status_bits: int
    runtime_state: int
    robot_status_bits: int
    register_start: int
    register_done: int
    register_moves: int = 0
    register_cycles: int = 0

    @classmethod
    def from_row(cls, row: np.ndarray) -> "URState":
        pose = row[_C_POSE]
        speed = row[_C_SPEED].copy()
        speed[:3] *= 1000.0
        return cls(
            t_s=float(row[_C_T]),
            q_rad=row[_C_Q].copy(),
            target_q_rad=row[_C_QT].copy(),
            tcp_T=ur_pose_to_T(pose),
            tcp_rotvec_rad=pose[3:].copy(),
            tcp_speed=speed,
            robot_mode=int(row[_C_ROBOT_MODE]),
            safety_mode=int(row[_C_SAFETY_MODE]),
            safety_status_bits=int(row[_C_SAFETY_BITS]),
            runtime_state=int(row[_C_RUNTIME]),
            robot_status_bits=int(row[_C_STATUS]),
            register_start=int(row[_C_REG_START]),
            register_done=int(row[_C_REG_DONE]),
            register_moves=int(row[_C_REG_MOVES]),
            register_cycles=int(row[_C_REG_CYCLES]),
        )

    @property
    def tcp_xyz_mm(self) -> np.ndarray:
        return self.tcp_T[:3, 3].copy()

    @property
    def protective_stopped(self) -> bool:
        return bool(self.safety_status_bits & _SAFETY_BIT_PROTECTIVE)

    @property
    def emergency_stopped(self) -> bool:
        return bool(self.safety_status_bits & _SAFETY_BITS_EMERGENCY)

    @property
    def program_running(self) -> bool:
        return self.runtime_state == RUNTIME_PLAYING

    @property
    def ready_to_move(self) -> bool:
        return (
            self.robot_mode == ROBOT_MODE_RUNNING
            and self.safety_mode in (SAFETY_MODE_NORMAL, SAFETY_MODE_REDUCED)
            and not self.protective_stopped
            and not self.emergency_stopped
        )


@dataclass(frozen=True)
class URSamples:
    """RTDE samples collected by the driver, in time order.

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Controller timestamps.
    q_rad : ndarray, shape (N, 6)
    tcp_xyz_mm : ndarray, shape (N, 3)
    tcp_rotvec_rad : ndarray, shape (N, 3)
    dropped : int
        Samples lost to full buffers since the previous collection.
    missed : int
        Controller periods (``1 / rtde_frequency_hz``) without a sample
        between consecutive timestamps, the previous collection's last one
        included: packages ``ur_rtde`` superseded by newer ones before the
        driver read them (it keeps only the newest), or never sent.
    """

    t_s: np.ndarray
    q_rad: np.ndarray
    tcp_xyz_mm: np.ndarray
    tcp_rotvec_rad: np.ndarray
    dropped: int
    missed: int


@dataclass(frozen=True)
class URProgramStatus:
    """Progress of a program the driver runs (:meth:`URDriver.run`), in the controller status's terms."""

    state: str
    moves_done: int
    cycle_count: int
    line: int
    q_deg: np.ndarray
    t_s: float
    #: the program was paused on the controller (pendant or dashboard) while it ran, and played on
    paused: bool = False

    @classmethod
    def of(cls, st: URState, seq: int, done: bool = False, paused: bool = False) -> "URProgramStatus":
        ours = st.register_start == seq
        moves = st.register_moves if ours else 0
        return cls(state="finished" if done else "running", moves_done=int(moves),
                   cycle_count=int(st.register_cycles if ours else 0), line=int(moves),
                   q_deg=np.degrees(st.q_rad), t_s=st.t_s, paused=paused)

    def summary(self) -> str:
        return f"{self.state}, moves {self.moves_done}, cycles {self.cycle_count}"


class _RestWatch:
    """Whether the arm has been at rest for ``hold_s`` of controller time, sample by sample."""

    def __init__(self, hold_s: float) -> None:
        self.hold_s = hold_s
        self.since: float | None = None

    def update(self, t_s: float, resting: bool) -> bool:
        if not resting:
            self.since = None
            return False
        if self.since is None:
            self.since = t_s
        return t_s - self.since >= self.hold_s


def _with_position(T: np.ndarray, xyz) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, 3] = xyz
    return out


# ====================================================================== driver


def parse_ur_url(url) -> str:
    """``ur://HOST`` -> HOST (ports are fixed by ur_rtde; :mod:`station.device_urls`)."""
    return parse_device_url(url, scheme="ur").host


def _fmt(x: float) -> str:
    if not math.isfinite(x):
        raise SafetyError(f"non-finite number {x!r} in a UR program")
    return repr(float(x))


class URDriver:
    """A UR cobot through ``ur_rtde``, every motion checked by the safety gate.

    Parameters
    ----------
    host : str
        Controller address.
    robot : RobotSpec
        The arm (nominal model, speed limits).
    gate : SafetyGate
        Checks every target, path and speed before anything is sent.
    rtde_frequency_hz : float
        RTDE output frequency (e-Series: <= 500).
    register_base : int
        Output integer registers ``register_base`` .. ``+3`` (0..44) carry the
        driver's program sequence numbers, moves and cycles done.
    trusted_programs : collection of str
        Controller programs (``.urp``) that :meth:`play` may start; the gate
        cannot see inside them, so nothing else is played.
    tcp_accel_limit_mm_s2 : float
        Rated linear acceleration; ``accel_mm_s2 / this`` is checked against
        the gate's acceleration cap.
    connect_timeout_s, start_timeout_s, motion_timeout_s, stale_after_s, settle_timeout_s : float
        Real seconds: handshake; until a sent program reports that it
        started; until it reports done; without a new RTDE sample before the
        link counts as lost; for the arm to settle on its target. Each counts
        only while this host runs the driver and its receive process
        (:data:`LISTEN_SLICE_S`): a loaded host's gaps are not the controller's.
    q_tol_rad, rest_speed_mm_s, rest_hold_s : float
        A move is done when every joint is within ``q_tol_rad`` of the target
        and the TCP slower than ``rest_speed_mm_s``, for ``rest_hold_s`` of
        controller time (an arm still settling passes through zero speed at
        every swing: one slow sample is not rest).
    status_period_s : float
        While :meth:`run` runs a program, its ``on_status`` is called at most this often (real s) and
        whenever a move is done.
    lockstep : bool
        A simulated controller in lockstep with its world (``ur://HOST?lockstep=1``; never a real one): its
        clock stands still between programs, so a sample is not stale for its age (only a lost link
        counts), and a move is done when the program has stopped, which it does once the arm rests. The
        receive process says which sample it kept (:data:`~station.protocols.ur.LOCKSTEP_STORED_REGISTER`),
        so it gets every one the controller streams and a seed gives the same stored readings.
    rtde, dashboard, script : optional
        Injected clients (default: the sidecar, ``DashboardClient``, ``ScriptClient``).
    """

    def __init__(
        self,
        host: str,
        robot,
        gate,
        *,
        rtde_frequency_hz: float = 500.0,
        register_base: int = 12,
        trusted_programs: Collection[str] = (),
        tcp_accel_limit_mm_s2: float = 2500.0,
        connect_timeout_s: float = 15.0,
        start_timeout_s: float = 3.0,
        motion_timeout_s: float = 300.0,
        stale_after_s: float = 1.5,
        settle_timeout_s: float = 10.0,
        q_tol_rad: float = 1e-3,
        rest_speed_mm_s: float = 1.0,
        rest_hold_s: float = 0.1,
        max_buffer_samples: int = 200_000,
        status_period_s: float = 0.02,
        lockstep: bool = False,
        rtde=None,
        dashboard=None,
        script=None,
    ) -> None:
        if not isinstance(host, str) or not re.fullmatch(r"[A-Za-z0-9.\-]+", host):
            raise ConfigError(f"UR host must be a host name or IPv4 address, got {host!r}")
        if not (0 < float(rtde_frequency_hz) <= 500):
            raise ConfigError(f"rtde_frequency_hz must be in (0, 500], got {rtde_frequency_hz!r}")
        if not (isinstance(register_base, int) and 0 <= register_base <= 44):
            raise ConfigError(f"register_base must be an integer 0..44, got {register_base!r}")
        for name, val in (("tcp_accel_limit_mm_s2", tcp_accel_limit_mm_s2), ("connect_timeout_s", connect_timeout_s),
                          ("start_timeout_s", start_timeout_s), ("motion_timeout_s", motion_timeout_s),
                          ("stale_after_s", stale_after_s), ("settle_timeout_s", settle_timeout_s),
                          ("q_tol_rad", q_tol_rad), ("rest_speed_mm_s", rest_speed_mm_s),
                          ("rest_hold_s", rest_hold_s)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise ConfigError(f"{name} must be a finite number > 0, got {val!r}")
        self.host = host
        self.robot = robot
        self.gate = gate
        self.rtde_frequency_hz = float(rtde_frequency_hz)
        self.register_base = register_base
        self.trusted_programs = frozenset(trusted_programs)
        self.tcp_accel_limit_mm_s2 = float(tcp_accel_limit_mm_s2)
        self.connect_timeout_s = float(connect_timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self.motion_timeout_s = float(motion_timeout_s)
        self.stale_after_s = float(stale_after_s)
        self.settle_timeout_s = float(settle_timeout_s)
        self.q_tol_rad = float(q_tol_rad)
        self.rest_speed_mm_s = float(rest_speed_mm_s)
        self.rest_hold_s = float(rest_hold_s)
        self.max_buffer_samples = int(max_buffer_samples)
        self.status_period_s = float(status_period_s)
        self.lockstep = bool(lockstep)
        self._rtde = rtde
        self._dashboard = dashboard
        self._script = script
        self._chunks: deque = deque()  # arrays of sample rows not yet collected by samples()
        self._n_rows = 0
        self._dropped = 0
        #: samples received with the program paused (runtime_state PAUSED), every one counted as it arrives
        self._n_paused = 0
        self._latest: np.ndarray | None = None
        self._silence: ListeningDeadline | None = None  # stale_after_s from the newest sample's arrival
        self._last_collected_t: float | None = None
        self._seq = 0
        self._lock = threading.RLock()
        self._connected = False

    @classmethod
    def from_url(cls, url, *, gate, timeout_s: float | None = None, robot=None, **kwargs) -> "URDriver":
        """Driver for ``ur://HOST[?rtde_hz=F][&lockstep=1]`` (the RTDE output frequency, default 500 Hz; a
        CB3 streams at 125; ``lockstep``: a simulated controller, see the class); ``robot`` defaults to the
        gate's; ``timeout_s`` bounds the handshake and a sent program's start."""
        u = parse_device_url(url, scheme="ur")
        kwargs.setdefault("rtde_frequency_hz", float(u.int_option("rtde_hz")))
        kwargs.setdefault("lockstep", u.flag_option("lockstep"))
        if timeout_s is not None:
            kwargs.setdefault("connect_timeout_s", timeout_s)
            kwargs.setdefault("start_timeout_s", timeout_s)
        return cls(u.host, robot if robot is not None else gate.robot, gate, **kwargs)

    # ------------------------------------------------------------------ lifetime
    def connect(self) -> "URDriver":
        """Open RTDE (sidecar), dashboard and script connections."""
        import dashboard_client
        import script_client

        if self._rtde is None:
            self._rtde = RtdeSidecar(self.host, self.rtde_frequency_hz, self.register_base,
                                     max_samples=self.max_buffer_samples,
                                     stored_register=LOCKSTEP_STORED_REGISTER if self.lockstep else None)
        self._rtde.start(self.connect_timeout_s)
        try:
            if self._dashboard is None:
                self._dashboard = dashboard_client.DashboardClient(self.host, DASHBOARD_PORT)
            try:
                self._dashboard.connect()
            except RuntimeError as exc:
                raise ConnectionLost(f"dashboard {self.host}:{DASHBOARD_PORT}: {exc}") from exc
            version = self._dashboard_call("PolyscopeVersion", self._dashboard.polyscopeVersion)
            m = re.search(r"(\d+)\.(\d+)", version)
            major, minor = (int(m.group(1)), int(m.group(2))) if m else (5, 11)
            if self._script is None:
                self._script = script_client.ScriptClient(self.host, major, minor, SCRIPT_PORT)
            try:
                self._script.connect()
            except RuntimeError as exc:
                raise ConnectionLost(f"script port {self.host}:{SCRIPT_PORT}: {exc}") from exc
            self._connected = True
            st = self.state(timeout_s=self.connect_timeout_s)
            self._seq = max(st.register_start, st.register_done, 0)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Close every connection and the sidecar (idempotent)."""
        self._connected = False
        if self._rtde is not None:
            self._rtde.close()
        if self._dashboard is not None:
            try:
                self._dashboard.disconnect()
            except RuntimeError:
                pass
        if self._script is not None:
            try:
                self._script.disconnect()
            except RuntimeError:
                pass

    def __enter__(self) -> "URDriver":
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ state
    def _listening(self, timeout_s: float) -> ListeningDeadline:
        """A timeout on the controller's silence or slowness: it counts while this host runs the driver, looking
        every :data:`LISTEN_SLICE_S`, and the receive process (its wait for the host does not count)."""
        delay = getattr(self._rtde, "host_delay_s", None)
        return ListeningDeadline(max(0.0, float(timeout_s)), LISTEN_SLICE_S, host_delay=delay)

    def _pull(self) -> None:
        rows, dropped, connected = self._rtde.drain()
        with self._lock:
            self._dropped += dropped
            if len(rows):
                fresh = rows[rows[:, _C_T] > (self._latest[_C_T] if self._latest is not None else -np.inf)]
                if len(fresh):
                    self._chunks.append(fresh)
                    self._n_rows += len(fresh)
                    self._n_paused += int(np.count_nonzero(fresh[:, _C_RUNTIME] == RUNTIME_PAUSED))
                    self._latest = fresh[-1]
                    self._silence = self._listening(self.stale_after_s)
                while self._n_rows > self.max_buffer_samples:  # oldest first, counted
                    excess = self._n_rows - self.max_buffer_samples
                    head = self._chunks[0]
                    cut = min(excess, len(head))
                    self._chunks[0] = head[cut:]
                    if not len(self._chunks[0]):
                        self._chunks.popleft()
                    self._n_rows -= cut
                    self._dropped += cut
        if not connected:
            raise ConnectionLost(
                f"RTDE connection to {self.host}:30004 lost"
                + (f" (last sample t = {self._latest[_C_T]:.3f} s)" if self._latest is not None else "")
            )

    def state(self, timeout_s: float | None = None) -> URState:
        """The newest RTDE sample; waits up to ``timeout_s`` for the first one (in lockstep at least
        :data:`LOCKSTEP_HANDSHAKE_S`: the simulated controller's first sample is late only by this host's load).

        Raises
        ------
        ConnectionLost
            The link dropped, or no new sample for ``stale_after_s`` (both counted while listening:
            :meth:`_listening`; time between two calls counts :data:`LISTEN_SLICE_S` at most).
        """
        wait_s = self.stale_after_s if timeout_s is None else timeout_s
        first_wait_s = max(wait_s, LOCKSTEP_HANDSHAKE_S) if self.lockstep else wait_s
        first, again = self._listening(first_wait_s), self._listening(wait_s)
        while True:
            self._pull()
            with self._lock:
                latest, silence = self._latest, self._silence
            first_left, again_left = first.time_left(), again.time_left()
            if latest is not None and (self.lockstep or silence.time_left() > 0.0):
                return URState.from_row(latest)  # lockstep: a standing clock sends no new sample
            if (first_left if latest is None else again_left) <= 0.0:
                if latest is None:
                    raise DeviceTimeout(f"RTDE {self.host}: no sample within {first_wait_s:g} s")
                raise ConnectionLost(
                    f"RTDE {self.host}: no new sample for {self.stale_after_s:g} s of listening "
                    f"(last t = {latest[_C_T]:.3f} s)"
                )
            time.sleep(0.002)

    def samples(self) -> URSamples:
        """Every sample received since the previous call (time order)."""
        self._pull()
        with self._lock:
            rows = np.concatenate(list(self._chunks)) if self._chunks else np.zeros((0, N_COLUMNS))
            self._chunks.clear()
            self._n_rows = 0
            dropped, self._dropped = self._dropped, 0
            t = rows[:, _C_T]
            if self._last_collected_t is not None:
                t = np.concatenate([[self._last_collected_t], t])
            periods = np.round(np.diff(t) * self.rtde_frequency_hz).astype(np.int64)
            missed = int(np.sum(np.clip(periods - 1, 0, None)))
            if len(rows):
                self._last_collected_t = float(rows[-1, _C_T])
        return URSamples(
            t_s=rows[:, _C_T].copy(),
            q_rad=rows[:, _C_Q].copy(),
            tcp_xyz_mm=1000.0 * rows[:, _C_POSE][:, :3],
            tcp_rotvec_rad=rows[:, _C_POSE][:, 3:].copy(),
            dropped=dropped,
            missed=missed,
        )

    # ------------------------------------------------------------------ motion
    def _require_ready(self, label: str) -> URState:
        if not self._connected:
            raise DeviceNotReady(f"{label}: UR driver is not connected")
        st = self.state()
        if not st.ready_to_move:
            raise DeviceNotReady(
                f"{label}: robot not ready to move (robot_mode {st.robot_mode}, safety_mode {st.safety_mode}, "
                f"protective stop {st.protective_stopped})"
            )
        return st

    def move_joint(self, q_rad, *, speed_frac: float = 0.25, accel_frac: float = 0.25,
                   label: str = "joint move") -> URState:
        """Move to joint angles (``movej``) after the gate; block until done.

        Speeds are fractions of the robot's slowest joint limits (``movej``'s
        ``v``/``a`` are the leading axis speed and acceleration).

        Returns
        -------
        URState
            The first sample with the arm settled on the target.
        """
        st = self._require_ready(label)
        q = self.gate.check_joint_target(q_rad, label)
        self.gate.check_speed(label, speed_frac=speed_frac, accel_frac=accel_frac)
        self.gate.check_joint_path(st.q_rad, q, label)
        peak = self.gate.joint_move_peak_tcp_speed(st.q_rad, q, speed_frac)
        if peak > self.gate.max_tcp_speed_mm_s * (1 + 1e-9):
            raise SafetyError(
                f"{label}: estimated peak TCP speed {peak:.0f} mm/s exceeds the cap {self.gate.max_tcp_speed_mm_s:.0f} mm/s"
            )
        v = speed_frac * float(np.min(self.robot.joint_speed_limits_rad_s))
        a = accel_frac * float(np.min(self.robot.joint_accel_limits_rad_s2))
        body = f"movej([{', '.join(_fmt(x) for x in q)}], a={_fmt(a)}, v={_fmt(v)})"
        return self._run_motion(body, q, label)

    def move_linear(self, target, *, speed_mm_s: float = 100.0, accel_mm_s2: float = 500.0,
                    label: str = "linear move") -> URState:
        """Straight TCP move (``movel``) after the gate; block until done.

        Parameters
        ----------
        target : array_like, shape (3,) or (4, 4)
            Position (mm; keeps the current orientation) or pose (mm).
        """
        st = self._require_ready(label)
        t = np.asarray(target, dtype=float)
        if t.shape == (3,):
            T = st.tcp_T.copy()
            T[:3, 3] = t
        elif t.shape == (4, 4):
            T = t
        else:
            raise SafetyError(f"{label}: target must be (3,) mm or a (4, 4) pose, got shape {t.shape}")
        q = self.gate.check_cartesian_target(T, label, q_seed=st.q_rad)
        self.gate.check_speed(label, tcp_speed_mm_s=speed_mm_s,
                              accel_frac=float(accel_mm_s2) / self.tcp_accel_limit_mm_s2)
        self.gate.check_linear_path(st.tcp_T, T, st.q_rad, q, label)
        pose = list(T[:3, 3] / 1000.0) + list(matrix_to_rotvec(T[:3, :3]))
        body = (f"movel(p[{', '.join(_fmt(x) for x in pose)}], a={_fmt(accel_mm_s2 / 1000.0)}, "
                f"v={_fmt(speed_mm_s / 1000.0)})")
        return self._run_motion(body, q, label)

    def _next_seq(self) -> int:
        with self._lock:
            self._seq = self._seq + 1 if self._seq < 2**31 - 2 else 1
            return self._seq

    def _send_script(self, text: str, label: str) -> None:
        try:
            ok = self._script.sendScriptCommand(text)
        except RuntimeError as exc:
            raise ConnectionLost(f"{label}: script port {self.host}:{SCRIPT_PORT}: {exc}") from exc
        if ok is False:
            raise ConnectionLost(f"{label}: script port {self.host}:{SCRIPT_PORT} refused the write")

    def _run_motion(self, body: str, q_target: np.ndarray, label: str) -> URState:
        seq = self._next_seq()
        r0, r1 = self.register_base, self.register_base + 1
        text = (
            f"def station_move_{seq}():\n"
            f"  write_output_integer_register({r0}, {seq})\n"
            f"  {body}\n"
            f"  write_output_integer_register({r1}, {seq})\n"
            f"end\n"
        )
        return self._execute(text, seq, q_target, label, f"station_move_{seq}")

    def _execute(self, text: str, seq: int, q_target: np.ndarray, label: str, name: str, *,
                 timeout_s: float | None = None, on_state=None, paused: list | None = None) -> URState:
        """Send one program whose registers carry ``seq``; watch RTDE until it is done and the arm settled.
        ``paused``: a list that gets ``True`` when any sample received while the program ran (not only the ones
        this loop looks at: a short pause falls between them) says it was paused."""
        timeout_s = self.motion_timeout_s if timeout_s is None else float(timeout_s)
        self._pull()
        with self._lock:
            n_paused = self._n_paused  # the program before this one ended: no pause of ours yet
        self._send_script(text, label)
        # both count while this host runs the driver and the receive process (a simulated controller's motion
        # waits for the host as the driver does); the time on_state takes is the caller's, not the motion's
        start, motion = self._listening(self.start_timeout_s), self._listening(timeout_s)
        started = False
        try:
            while True:
                st = self.state()
                if on_state is not None and started:
                    motion.time_left()
                    on_state(st)
                    motion.count_gap(0.0)
                if st.protective_stopped or st.emergency_stopped:
                    self._after_fault(label)
                    raise DeviceFault(
                        f"{label}: {'protective' if st.protective_stopped else 'emergency'} stop during the move "
                        f"(t = {st.t_s:.3f} s, q = {np.round(np.degrees(st.q_rad), 3).tolist()} deg); the robot is "
                        f"halted and the program stopped; inspect the cause, then unlock_protective_stop()"
                    )
                if st.register_done == seq:
                    if paused is not None and self._n_paused > n_paused:
                        paused.append(True)
                    break
                if st.register_start == seq:
                    started = True
                elif not started and start.expired():
                    raise DeviceError(
                        f"{label}: the controller did not start program {name} within "
                        f"{self.start_timeout_s} s (refused by the controller? robot_mode {st.robot_mode})"
                    )
                if started and st.runtime_state == RUNTIME_STOPPED and st.register_done != seq:
                    self._after_fault(label)
                    raise DeviceError(f"{label}: program {name} stopped before its motion finished "
                                      f"({st.register_moves} moves done); the robot is at rest")
                if motion.expired():
                    self.stop_motion()
                    raise DeviceTimeout(f"{label}: motion not done within {timeout_s:g} s; robot stopped")
                time.sleep(0.001)
            return self._settle(q_target, label)
        except ConnectionLost:
            self._halt_best_effort()
            raise

    def _settle(self, q_target: np.ndarray, label: str) -> URState:
        deadline = self._listening(self.settle_timeout_s)
        rest = _RestWatch(self.rest_hold_s)
        while True:
            st = self.state()
            err = float(np.max(np.abs(st.q_rad - q_target)))
            speed = float(np.linalg.norm(st.tcp_speed[:3]))
            resting = err <= self.q_tol_rad and speed <= self.rest_speed_mm_s
            if self.lockstep:  # the simulated program ends once the arm has come to rest: then the clock stands
                if resting and not st.program_running:
                    return st
            elif rest.update(st.t_s, resting):
                return st
            if st.protective_stopped:
                raise DeviceFault(f"{label}: protective stop while settling on the target")
            if deadline.expired():
                raise DeviceError(
                    f"{label}: arm did not come to rest within {self.q_tol_rad:g} rad of the target "
                    f"(off by {err:.3g} rad, TCP at {speed:.3g} mm/s after {self.settle_timeout_s} s)"
                )
            time.sleep(0.001)

    def _after_fault(self, label: str) -> None:
        """Leave a safe state: program stopped, arm at rest (waited for, bounded)."""
        try:
            if self._dashboard is not None and self._dashboard.running():
                self._dashboard.stop()
        except RuntimeError:
            pass
        deadline = self._listening(self.settle_timeout_s)
        rest = _RestWatch(self.rest_hold_s)
        while not deadline.expired():
            st = self.state()
            if self._rested(rest, st):
                return
            time.sleep(0.002)

    def _rested(self, rest: "_RestWatch", st: URState) -> bool:
        """No program runs and the TCP is slower than ``rest_speed_mm_s``: at once in lockstep (a simulated
        program ends after its arm rested, and the clock may then stand still), else for ``rest_hold_s``."""
        resting = not st.program_running and float(np.linalg.norm(st.tcp_speed[:3])) <= self.rest_speed_mm_s
        return resting if self.lockstep else rest.update(st.t_s, resting)

    def _halt_best_effort(self) -> None:
        try:
            self._send_script("stopj(2.0)\n", "halt")
        except ConnectionLost:
            pass
        try:
            if self._dashboard is not None:
                self._dashboard.stop()
        except RuntimeError:
            pass

    def stop_motion(self, decel_rad_s2: float = 2.0) -> None:
        """Halt the arm now (``stopj``; stopping needs no gate)."""
        self._send_script(f"stopj({_fmt(decel_rad_s2)})\n", "stop")

    # ------------------------------------------------------------------ the robot interface (drivers.robot)
    def _gate_program(self, program, q_start: np.ndarray) -> np.ndarray:
        """Every executed move of ``program`` through the gate from ``q_start``; the joint targets (M, 6)."""
        from station.programs.program import Move, Program, RenderedProgram
        from station.programs.urscript import executed

        prog = program.program if isinstance(program, RenderedProgram) else program
        if not isinstance(prog, Program):
            raise SafetyError(f"run needs a Program, got {type(program).__name__}")
        self.gate.check_program(prog, q_start=q_start)  # names, robot, speeds, accelerations, as every dialect
        q = np.asarray(q_start, dtype=float)
        out = []
        for i, ins in enumerate(executed(prog)):
            if isinstance(ins, Move):
                q, _ = self.gate.check_move(ins, q, prog, where=f"instruction {i + 1}")
                out.append(q)
        return np.array(out).reshape(-1, 6)

    def run(self, program, *, timeout_s: float | None = None, on_status=None) -> "URProgramStatus":
        """Gate every move of a :class:`~station.programs.program.Program` (or a rendered one) from the joints
        RTDE reports, send it as one URScript program, watch its progress on RTDE and return when it is done
        and the arm rests on the last target (:mod:`drivers.robot`)."""
        from station.programs.program import RenderedProgram
        from station.programs.urscript import render_urscript

        prog = program.program if isinstance(program, RenderedProgram) else program
        label = f"program {getattr(prog, 'name', '?')}"
        st = self._require_ready(label)
        q = self._gate_program(prog, st.q_rad)
        seq = self._next_seq()
        rendered = render_urscript(prog, q, robot=self.robot, seq=seq, register_base=self.register_base)
        report = None
        if on_status is not None:
            last = [-1.0, -1]

            def report(s: URState) -> None:  # progress at most every status_period_s, and at every move done
                now = time.monotonic()  # a pace of the caller's reports (host time), no deadline
                if now - last[0] >= self.status_period_s or s.register_moves != last[1]:
                    last[0], last[1] = now, s.register_moves
                    on_status(URProgramStatus.of(s, seq))
        paused: list = []
        final = self._execute(rendered.text, seq, q[-1] if len(q) else st.q_rad, label,
                              prog.name.lower(), timeout_s=timeout_s, on_state=report, paused=paused)
        return URProgramStatus.of(final, seq, done=True, paused=bool(paused))

    def move_to(self, target, *, speed_frac: float = 0.2, interpolation: str = "joint",
                timeout_s: float | None = None) -> URState:
        """One gated move: joints (6,) rad, or a Cartesian (4, 4) pose / (3,) position mm."""
        t = np.asarray(target, dtype=float)
        if interpolation == "linear":
            return self.move_linear(t, speed_mm_s=speed_frac * float(self.robot.max_tcp_speed_mm_s))
        if t.shape != (6,):
            st = self._require_ready("move")
            t = self.gate.check_cartesian_target(t if t.shape == (4, 4) else _with_position(st.tcp_T, t),
                                                 "move", q_seed=st.q_rad)
        return self.move_joint(t, speed_frac=speed_frac)

    def take_over(self) -> tuple[str, str]:
        """Stop a program an earlier session left running; refuse a stop a person must clear."""
        st = self.state(timeout_s=self.connect_timeout_s)
        if st.emergency_stopped:
            raise DeviceFault("UR: emergency stop engaged: release it on the pendant, then resume")
        if st.protective_stopped:
            raise DeviceFault("UR: protective stop: inspect its cause, unlock it on the pendant, then resume")
        if st.robot_mode != ROBOT_MODE_RUNNING:
            raise DeviceNotReady(f"UR: robot mode {st.robot_mode} (not RUNNING): power on and release the brakes")
        took = ""
        if st.program_running or float(np.linalg.norm(st.tcp_speed[:3])) > self.rest_speed_mm_s:
            self.release()
            took = "stopped a program left running by an earlier session"
        return self.summary(), took

    def release(self) -> None:
        """Halt the arm, stop any program, wait (bounded) for rest."""
        self.stop_motion()
        self._after_fault("release")

    def stop(self) -> URState:
        """The safe state: motion halted, program stopped, arm at rest (``stopj`` + dashboard stop)."""
        self.release()
        return self.state()

    def summary(self) -> str:
        st = self.state()
        return (f"robot mode {st.robot_mode}, safety mode {st.safety_mode}, "
                f"{'program running' if st.program_running else 'no program running'}")

    def wait_settled(self, timeout_s: float) -> URState:
        """Until no program runs and the TCP is slower than ``rest_speed_mm_s``; DeviceTimeout after ``timeout_s``
        (counted while listening: :meth:`_listening`)."""
        deadline = self._listening(timeout_s)
        rest = _RestWatch(self.rest_hold_s)
        while True:
            st = self.state()
            if self._rested(rest, st):
                return st
            if deadline.expired():
                raise DeviceTimeout(f"UR: arm not at rest within {timeout_s:g} s")
            time.sleep(0.002)

    def joints_rad(self) -> np.ndarray:
        return self.state().q_rad

    def tcp_mm(self) -> np.ndarray:
        return self.state().tcp_xyz_mm

    def fault_state(self) -> str | None:
        st = self.state()
        if st.emergency_stopped:
            return "emergency stop"
        if st.protective_stopped:
            return "protective stop"
        if not st.ready_to_move:
            return f"not ready (robot mode {st.robot_mode}, safety mode {st.safety_mode})"
        return None

    def readings(self):
        from drivers.robot import RobotReadings

        s = self.samples()
        return RobotReadings(t_s=s.t_s, q_rad=s.q_rad, tcp_xyz_mm=s.tcp_xyz_mm, dropped=s.dropped, missed=s.missed)

    # ------------------------------------------------------------------ dashboard
    def _dashboard_call(self, what: str, fn, *args):
        if self._dashboard is None:
            raise DeviceNotReady(f"dashboard {what}: not connected")
        try:
            return fn(*args)
        except (RuntimeError, ValueError) as exc:
            connected = True
            try:
                connected = bool(self._dashboard.isConnected())
            except RuntimeError:
                connected = False
            if not connected:
                raise ConnectionLost(f"dashboard {self.host}:{DASHBOARD_PORT} lost during {what!r}: {exc}") from exc
            raise DeviceError(f"dashboard {what!r} refused: controller replied {str(exc)!r}") from exc

    def load_program(self, name: str) -> None:
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_./\-]+\.urp", name):
            raise ConfigError(f"program name must be a .urp path of letters, digits, _ . / -, got {name!r}")
        self._dashboard_call(f"load {name}", self._dashboard.loadURP, name)

    def loaded_program(self) -> str | None:
        reply = self._dashboard_call("get loaded program", self._dashboard.getLoadedProgram)
        m = re.match(r"Loaded program:\s*(.+)$", reply.strip())
        return m.group(1) if m else None

    def play(self) -> None:
        """Start the loaded program (only a trusted one) or resume a paused one."""
        st = self.state()
        if st.runtime_state != RUNTIME_PAUSED:
            name = self.loaded_program()
            base = name.rsplit("/", 1)[-1] if name else None
            if name is None or (name not in self.trusted_programs and base not in self.trusted_programs):
                raise SafetyError(
                    f"play: program {name!r} is not in the driver's trusted_programs; the safety gate cannot "
                    f"check a controller-side program"
                )
        self._dashboard_call("play", self._dashboard.play)

    def pause(self) -> None:
        self._dashboard_call("pause", self._dashboard.pause)

    def stop_program(self) -> None:
        self._dashboard_call("stop", self._dashboard.stop)

    def is_running(self) -> bool:
        return bool(self._dashboard_call("running", self._dashboard.running))

    def program_state(self) -> str:
        return str(self._dashboard_call("programState", self._dashboard.programState))

    def _dashboard_command(self, command: str, expect: str) -> str:
        """Send a command whose reply ``ur_rtde`` does not check; check it here."""

        def call():
            self._dashboard.send(command + "\n")
            return self._dashboard.receive()

        reply = self._dashboard_call(command, call)
        if not reply.startswith(expect):
            raise DeviceError(f"dashboard {command!r} refused: controller replied {reply!r}")
        return reply

    def power_on(self, timeout_s: float = 30.0) -> URState:
        """Power on and release the brakes; wait for robot mode RUNNING."""
        self._dashboard_command("power on", "Powering on")
        self._wait_mode({ROBOT_MODE_IDLE, ROBOT_MODE_RUNNING}, timeout_s, "power on")
        self._dashboard_command("brake release", "Brake releasing")
        return self._wait_mode({ROBOT_MODE_RUNNING}, timeout_s, "brake release")

    def power_off(self, timeout_s: float = 30.0) -> URState:
        self._dashboard_command("power off", "Powering off")
        return self._wait_mode({ROBOT_MODE_POWER_OFF}, timeout_s, "power off")

    def _wait_mode(self, modes: set, timeout_s: float, what: str) -> URState:
        deadline = self._listening(timeout_s)
        while True:
            st = self.state()
            if st.robot_mode in modes:
                return st
            if deadline.expired():
                raise DeviceTimeout(f"{what}: robot mode still {st.robot_mode} after {timeout_s} s")
            time.sleep(0.005)

    def unlock_protective_stop(self, timeout_s: float = 30.0) -> URState:
        """Unlock a protective stop (the controller allows it 5 s after the stop).

        Retries while the controller answers that it is too early.
        """
        deadline = self._listening(timeout_s)
        while True:
            try:
                self._dashboard.unlockProtectiveStop()
            except (RuntimeError, ValueError) as exc:  # ur_rtde raises logic_error -> RuntimeError
                if "5s" not in str(exc) and "Cannot unlock" not in str(exc):
                    raise DeviceError(f"unlock protective stop refused: {exc}") from exc
                if deadline.expired():
                    raise DeviceTimeout(f"protective stop still locked after {timeout_s} s: {exc}") from exc
                time.sleep(0.05)
                continue
            break
        while True:
            st = self.state()
            if not st.protective_stopped:
                return st
            if deadline.expired():
                raise DeviceTimeout(f"protective stop still reported {timeout_s} s after unlocking")
            time.sleep(0.005)
