"""A simulated Leica emScon tracker server on loopback (TPI binary packets over TCP).

It measures ``world.tracker_source()`` (the simulated target through the
tracker measurement model) on the world's clock and answers the command
subset the station uses: GetSystemStatus, GetTrackerStatus, Set/GetUnits,
Initialize, Set/GetMeasurementMode (stationary, continuous time and 6D
continuous time), SetCoordinateSystemType (RHR),
SetStationaryModeParams, SetContinuousTimeModeParams, SetSystemSettings,
StartMeasurement, StopMeasurement. Anything else is answered with status
NotImplemented. Stationary measurements send a SingleMeasResultT after the
measurement time; continuous-time mode streams MultiMeasResultT packets
(``packet_rate_hz`` per simulated second) of samples on the device time grid
``t_k = k * lTimeSeparation`` (in the 6D continuous time mode, ES_MM_6DContinuousTime,
ProbeContinuousResultT packets instead: a T-Mac on the tool, its position the TCP's and its quaternion
the TCP's true rotation in the tracker frame with the tracker's angle noise, ``source.orientation``)
(the source's device clock when it has one:
``device_time``); beam breaks are announced with
SystemStatusChange MeasStatus_NotReady / MeasStatus_Ready and leave a hole
in the grid. The stream holds the world's clock (:mod:`fakes.sim.clock`): the clock
never passes the next packet not yet sent, so a client that reads too slowly
stalls simulated time and loses nothing; with nothing scheduled the clock
stands still and the fake sends everything up to it. Only on a clock that is
not held (a source without ``producer``) does a slow client overflow the device
buffer (``device_buffer_s``): the oldest samples are dropped, as a real device does.
A reply goes out after every sample due before the command.

The packet layouts are written here independently of ``drivers/`` (from the
TPI headers), so the driver's codec is checked against a second reading.

Fault injection (``faults`` dict, string values; times in simulated seconds
counted from the first StartMeasurement the fake receives, unless noted)::

    beam_break       "START:DURATION[,START:DURATION...]"  no target in these windows
    drop_connection  "START[:REFUSE][,...]"  close the client's socket at START and
                     refuse new sessions for REFUSE seconds (default 0)
    garbage          "N"      random 1..64 bytes before every Nth data packet
    truncate         "N"      every Nth data packet is cut short at a random byte
    truncate_tail    "L"      a packet cut short by ``truncate`` loses exactly its last L
                              bytes instead (at least 8 bytes are kept)
    huge_length      "N"      after the Nth data packet send a header declaring
                              2**31-1 bytes (nothing follows it)
    slow_reply_s     "X"      every command reply is delayed X seconds
    lose_reply       "C[:N]"  the replies to the first N (default 1) commands with id C
                              are not sent (emScon only)
    not_ready        "always" or "X"  tracker warming up until X s after the fake
                              started: Initialize fails (SensorNotWarmedUp), nothing measures
    device_buffer_s  "X"      samples the device holds for a slow client (default 2)
    packet_rate_hz   "X"      continuous packets per simulated second (default 10)
    bad_quaternion   "N"      every Nth 6-DoF packet's first sample carries a quaternion of
                              norm 0.9 (a malformed packet)
    seed             "N"      seed of the fault randomness (default 0)

``start_fake(world, host=None, port=None, faults=None)`` binds 127.0.0.1 and an
ephemeral port unless told otherwise (loopback only) and returns a handle
with ``endpoint``, ``stats`` and ``close()``.
"""

from __future__ import annotations

import ipaddress
import math
import select
import socket
import struct
import threading
from dataclasses import dataclass, field

import numpy as np

from fakes.sim.clock import keep_running, stop_running
from station.errors import ConfigError

# --- wire layout (TPI, little-endian, packed to 4) ----------------------------------
_HDR = struct.Struct("<ii")
_DT_COMMAND, _DT_ERROR, _DT_SINGLE, _DT_MULTI, _DT_STATUS_CHANGE = 0, 1, 2, 3, 8
_DT_PROBE_CONTINUOUS = 5
_MM_6D_CONTINUOUS_TIME = 7
_SSC_NOT_READY, _SSC_READY = 25, 27
_RS_OK, _RS_BUSY, _RS_NOT_IMPLEMENTED, _RS_WRONG_PARAMETER, _RS_WRONG_PARAMETER1 = 0, 1, 2, 3, 4
_RS_NOT_INITIALIZED, _RS_MEAS_NOT_READY, _RS_NOT_WARMED_UP = 39, 10004, 10012
_MEAS_VALUE = np.dtype([("status", "<i4"), ("time1", "<i4"), ("time2", "<i4"),
                        ("v1", "<f8"), ("v2", "<f8"), ("v3", "<f8")])
_MM_PER_UNIT = {0: 1000.0, 1: 1.0, 2: 1e-3, 3: 304.8, 4: 914.4, 5: 25.4}
#: commands are small; anything longer from a client is a protocol violation
_MAX_COMMAND_BYTES = 4096
_INIT_DURATION_S = 1.0
_SERIAL = 424242


# --- faults -------------------------------------------------------------------------
@dataclass
class TrackerFaults:
    """Parsed fault configuration shared by the tracker fakes."""

    beam_break: list = field(default_factory=list)        # [(start_s, duration_s)]
    drop_connection: list = field(default_factory=list)   # [(start_s, duration_s)]
    garbage_every: int = 0
    truncate_every: int = 0
    truncate_tail: int = 0                                # 0: cut at a random byte
    huge_length_after: int = 0
    slow_reply_s: float = 0.0
    lose_reply: dict = field(default_factory=dict)        # {command id: replies still to lose}
    not_ready_s: float = 0.0
    device_buffer_s: float = 2.0
    packet_rate_hz: float = 10.0
    bad_quaternion_every: int = 0
    seed: int = 0

    def beam_blocked(self, t_rel: np.ndarray) -> np.ndarray:
        """True where ``t_rel`` (s after the anchor) lies in a beam-break window."""
        blocked = np.zeros(np.shape(t_rel), dtype=bool)
        for start, dur in self.beam_break:
            blocked |= (t_rel >= start) & (t_rel < start + dur)
        return blocked


def _float(key: str, text: str, *, minimum: float = 0.0) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ConfigError(f"fault {key!r}: {text!r} is not a number") from None
    if not math.isfinite(value) or value < minimum:
        raise ConfigError(f"fault {key!r}: {text!r} must be a finite number >= {minimum}")
    return value


def _int(key: str, text: str, *, minimum: int = 1) -> int:
    try:
        value = int(text)
    except (TypeError, ValueError):
        raise ConfigError(f"fault {key!r}: {text!r} is not an integer") from None
    if value < minimum:
        raise ConfigError(f"fault {key!r}: {text!r} must be >= {minimum}")
    return value


def _windows(key: str, text: str, default_duration: float | None) -> list:
    out = []
    for item in str(text).split(","):
        start, sep, dur = item.strip().partition(":")
        if not sep:
            if default_duration is None:
                raise ConfigError(f"fault {key!r}: {item!r} must be START:DURATION (seconds)")
            dur = str(default_duration)
        out.append((_float(key, start), _float(key, dur)))
    return sorted(out)


def parse_tracker_faults(faults: dict | None, *, allowed: frozenset, drop_default_s: float) -> TrackerFaults:
    """Validate a fault dict (string values) into :class:`TrackerFaults`."""
    plan = TrackerFaults()
    for key, text in (faults or {}).items():
        if key not in allowed:
            raise ConfigError(f"unknown fault {key!r}; known: {', '.join(sorted(allowed))}")
        if key == "beam_break":
            plan.beam_break = _windows(key, text, None)
        elif key == "drop_connection":
            plan.drop_connection = _windows(key, text, drop_default_s)
        elif key == "garbage":
            plan.garbage_every = _int(key, text)
        elif key == "truncate":
            plan.truncate_every = _int(key, text)
        elif key == "truncate_tail":
            plan.truncate_tail = _int(key, text)
        elif key == "huge_length":
            plan.huge_length_after = _int(key, text)
        elif key == "slow_reply_s":
            plan.slow_reply_s = _float(key, text)
        elif key == "lose_reply":
            cmd, _, count = str(text).partition(":")
            plan.lose_reply[_int(key, cmd)] = _int(key, count) if count else 1
        elif key == "not_ready":
            plan.not_ready_s = math.inf if str(text).strip().lower() == "always" else _float(key, text)
        elif key == "device_buffer_s":
            plan.device_buffer_s = _float(key, text, minimum=1e-3)
        elif key == "packet_rate_hz":
            plan.packet_rate_hz = _float(key, text, minimum=1e-3)
        elif key == "bad_quaternion":
            plan.bad_quaternion_every = _int(key, text)
        elif key == "seed":
            plan.seed = _int(key, text, minimum=0)
    return plan


def check_loopback(host: str) -> str:
    """Refuse anything but a loopback address (never a wildcard or external one)."""
    try:
        ok = ipaddress.ip_address(host).is_loopback
    except ValueError:
        ok = False
    if not ok:
        raise ConfigError(f"fakes bind loopback addresses only (127.0.0.0/8 or ::1), got {host!r}")
    return host


EMSCON_FAULTS = frozenset({"beam_break", "drop_connection", "garbage", "truncate", "truncate_tail", "huge_length",
                           "slow_reply_s", "lose_reply", "not_ready", "device_buffer_s", "packet_rate_hz", "seed",
                           "bad_quaternion"})


# --- packets --------------------------------------------------------------------------
def _reply(command: int, status: int, data: bytes = b"") -> bytes:
    return _HDR.pack(16 + len(data), _DT_COMMAND) + struct.pack("<ii", command, status) + data


def _error(command: int, status: int) -> bytes:
    return _HDR.pack(16, _DT_ERROR) + struct.pack("<ii", command, status)


def _status_change(event: int) -> bytes:
    return _HDR.pack(12, _DT_STATUS_CHANGE) + struct.pack("<i", event)


def _multi(t_us: np.ndarray, xyz_unit: np.ndarray) -> bytes:
    n = len(t_us)
    values = np.zeros(n, dtype=_MEAS_VALUE)
    values["time1"], values["time2"] = np.divmod(t_us, 1_000_000)
    values["v1"], values["v2"], values["v3"] = xyz_unit.T
    head = _HDR.pack(48 + 36 * n, _DT_MULTI) + struct.pack("<iiii3d", 0, n, 1, 0, 20.0, 1013.25, 50.0)
    return head + values.tobytes()


#: ProbeMeasValueT: status, triggerStatus, lRotationStatus, lTime1, lTime2, then 24 doubles (position 3, its sd 4
#: and covariances 3, quaternion 4, rotation angles 3, their sd 4 and covariances 3)
_PROBE_VALUE = np.dtype([("status", "<i4"), ("trigger", "<i4"), ("rot_status", "<i4"), ("time1", "<i4"),
                         ("time2", "<i4"), ("pos", "<f8", (3,)), ("pos_stat", "<f8", (7,)), ("q", "<f8", (4,)),
                         ("rest", "<f8", (10,))])


def _probe_multi(t_us: np.ndarray, xyz_unit: np.ndarray, quat_wxyz: np.ndarray) -> bytes:
    """ProbeContinuousResultT: header, status, count, measMode 7, bIsTryMode, probe id 1, field 0, tip status,
    tip adapter id and interface, temperature, pressure, humidity; then the samples."""
    n = len(t_us)
    values = np.zeros(n, dtype=_PROBE_VALUE)
    values["time1"], values["time2"] = np.divmod(t_us, 1_000_000)
    values["rot_status"] = 1  # Status6D: rotation valid
    values["pos"] = xyz_unit
    values["q"] = quat_wxyz
    head = _HDR.pack(68 + 212 * n, _DT_PROBE_CONTINUOUS) + struct.pack(
        "<9i3d", 0, n, _MM_6D_CONTINUOUS_TIME, 0, 1, 0, 0, 0, 0, 20.0, 1013.25, 50.0)
    return head + values.tobytes()


def _single(xyz, std, temperature=20.0, pressure=1013.25, humidity=50.0) -> bytes:
    std_total = float(np.sqrt(np.sum(np.square(std))))
    values = [*xyz, *std, std_total, 0.0, 0.0, 0.0, *std, std_total, temperature, pressure, humidity]
    return _HDR.pack(156, _DT_SINGLE) + struct.pack("<iii17d", 0, 0, 0, *values)


class _SessionClosed(Exception):
    pass


class EmsconFake:
    """Handle of a running emScon fake: ``endpoint``, ``stats``, ``close()``."""

    def __init__(self, world, *, host: str | None = None, port: int | None = None,
                 faults: dict | None = None, drives_clock: bool = True) -> None:
        #: a tracker served on its own keeps the clock running while it streams; in a cell whose controller
        #: runs the programs (``drives_clock=False``) the stream only follows the clock
        self._drives_clock = drives_clock
        self._faults = parse_tracker_faults(faults, allowed=EMSCON_FAULTS, drop_default_s=0.0)
        self._source = world.tracker_source()
        self._clock = self._source.clock
        # device clock = world clock + offset (a source without ``device_time`` has none)
        device_time = getattr(self._source, "device_time", None)
        self._offset = float(np.ravel(device_time(np.zeros(1)))[0]) if device_time else 0.0
        self._rng = np.random.default_rng(self._faults.seed)
        host = check_loopback(host or "127.0.0.1")
        if port is not None and not (isinstance(port, int) and 0 <= port < 65536):
            raise ConfigError(f"port must be an integer in 0..65535, got {port!r}")
        self._listener = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port or 0))
        except OSError as exc:
            self._listener.close()
            raise ConfigError(f"cannot bind the emScon fake to {host}:{port}: {exc}") from exc
        self._listener.listen(4)
        self.endpoint = {"host": host, "port": self._listener.getsockname()[1]}
        self.stats = {"connections": 0, "refused": 0, "commands": 0, "data_packets": 0, "samples_sent": 0,
                      "samples_dropped": 0, "garbage_bytes": 0, "truncated_packets": 0, "lost_replies": 0,
                      "truncated_samples": 0, "truncated_spans": [], "huge_headers": 0, "drops": 0, "protocol_errors": [],
                      "anchor_t": None}
        # tracker state survives client sessions, as a real server's does
        self._t_started = self._clock.now()
        if math.isfinite(self._faults.not_ready_s) and self._faults.not_ready_s > 0:
            self._clock.schedule(self._t_started + self._faults.not_ready_s)  # the warm-up runs on its own
        self._initialised = False
        self._length_unit = 1
        self._meas_mode = 0
        self._stationary_ms = 1000
        self._separation_ms = 1
        self._drops_done = 0
        self._refuse_until = -math.inf
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="emscon-fake", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._listener.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._listener], [], [], 0.05)
            if not ready:
                continue
            try:
                conn, _ = self._listener.accept()
            except OSError:
                continue
            if self._clock.now() < self._refuse_until:
                self.stats["refused"] += 1
                conn.close()
                continue
            self.stats["connections"] += 1
            try:
                _Session(self, conn).run()
            except (_SessionClosed, OSError):
                pass
            finally:
                try:
                    conn.close()
                except OSError:
                    pass

    # ------------------------------------------------------------------ model
    def _not_ready(self) -> bool:
        return self._clock.now() - self._t_started < self._faults.not_ready_s

    def _orientation(self, t_dev: np.ndarray) -> np.ndarray:
        """Unit quaternions (N, 4), scalar first, of the 6-DoF target at device times (its frame into the
        tracker's); NaN rows where the source has no orientation."""
        from fakes.sim.six_dof import matrices_to_quat_wxyz

        t = np.asarray(t_dev, dtype=float) - self._offset
        return matrices_to_quat_wxyz(self._source.orientation(t))

    def _measure(self, t_dev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measure at device times (the source works in world times)."""
        t = np.asarray(t_dev, dtype=float) - self._offset
        xyz, valid = self._source.measure(t)
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        valid = np.asarray(valid, dtype=bool).ravel().copy()
        anchor = self.stats["anchor_t"]
        if anchor is not None and self._faults.beam_break:
            valid &= ~self._faults.beam_blocked(t - anchor)
        return xyz, valid


class _Session:
    """One client connection (the server serves one at a time)."""

    def __init__(self, fake: EmsconFake, conn: socket.socket) -> None:
        self.fake = fake
        self.conn = conn
        conn.settimeout(2.0)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.rx = bytearray()
        self.streaming = False
        self.next_k = 0
        self.beam_ok = True
        self.single_window: tuple[float, float] | None = None
        self.init_done_at: float | None = None
        self.packets = 0
        # while streaming, the clock never runs past the next packet the session has not sent
        self.producer = fake._clock.producer("emscon stream")
        self.running = None  # the stream's own demand when the fake drives the clock

    # ------------------------------------------------------------------ loop
    def run(self) -> None:
        try:
            self._loop()
        finally:
            self.producer.release()
            stop_running(self.running)

    def _loop(self) -> None:
        fake, clock = self.fake, self.fake._clock
        while not fake._stop.is_set():
            self._check_drop()
            # what is due goes out before any reply: a reply the client gets tells it that every
            # sample due before its command was sent ahead of it
            self._send_due()
            self._finish_pending()
            wait = 0.05
            now = clock.now()
            for t_due in (self._next_batch_due(), self.init_done_at,
                          self.single_window[1] if self.single_window else None):
                if t_due is not None:
                    wait = min(wait, max(0.0, clock.real_seconds(t_due - now)))
            ready, _, _ = select.select([self.conn], [], [], wait)
            if ready:
                data = self.conn.recv(65536)
                if not data:
                    return
                self.rx += data
                self._commands()

    def _send_due(self) -> None:
        """Send the samples due now. A lockstep clock with nothing scheduled stands still: what it has passed
        goes out whole, so a step's samples end where its program ended, not at the last full packet."""
        if self.streaming:
            clock = self.fake._clock
            self._stream(flush=bool(getattr(clock, "lockstep", False)) and clock.idle())

    def _send(self, data: bytes) -> None:
        try:
            self.conn.sendall(data)
        except (socket.timeout, OSError) as exc:
            raise _SessionClosed(str(exc)) from exc

    def _check_drop(self) -> None:
        fake = self.fake
        anchor = fake.stats["anchor_t"]
        if anchor is None or fake._drops_done >= len(fake._faults.drop_connection):
            return
        start, refuse = fake._faults.drop_connection[fake._drops_done]
        if fake._clock.now() >= anchor + start:
            if self.streaming:
                self._stream()  # what was due before the drop is sent
            fake._drops_done += 1
            fake.stats["drops"] += 1
            fake._refuse_until = anchor + start + refuse
            self.conn.shutdown(socket.SHUT_RDWR)
            raise _SessionClosed("drop_connection fault")

    # ------------------------------------------------------------------ commands
    def _commands(self) -> None:
        while len(self.rx) >= 8:
            size, ptype = _HDR.unpack_from(self.rx, 0)
            if ptype != _DT_COMMAND or size < 12 or size > _MAX_COMMAND_BYTES or size % 4:
                self.fake.stats["protocol_errors"].append(
                    f"client sent a header with length {size} and type {ptype}; closing the session")
                raise _SessionClosed("protocol error")
            if len(self.rx) < size:
                return
            command = struct.unpack_from("<i", self.rx, 8)[0]
            params = bytes(self.rx[12:size])
            del self.rx[:size]
            self.fake.stats["commands"] += 1
            # what is due goes out before the reply, also when the command came in while the loop waited (the
            # clock may have come to a stand meanwhile): the reply tells the client every sample due is ahead of it
            self._send_due()
            reply = self._command(command, params)
            lose = self.fake._faults.lose_reply
            if reply is not None and lose.get(command, 0) > 0:
                lose[command] -= 1
                self.fake.stats["lost_replies"] += 1
                reply = None
            if reply is not None:
                if self.fake._faults.slow_reply_s:
                    self.fake._clock.sleep(self.fake._faults.slow_reply_s)
                self._send(reply)

    def _command(self, command: int, params: bytes) -> bytes | None:
        fake = self.fake

        def ints(count: int):
            return struct.unpack(f"<{count}i", params) if len(params) == 4 * count else None

        if command == 1:  # GetSystemStatus
            not_ready = fake._not_ready()
            tps = 5 if fake._initialised else 4
            laser = 2 if not_ready else 3
            data = struct.pack("<10i", 0, tps, laser, 2, 3, 6, 0, 0, 0, _SERIAL)
            return _reply(command, _RS_OK, data)
        if command == 2:  # GetTrackerStatus
            ready = fake._initialised and not fake._not_ready()
            return _reply(command, _RS_OK, struct.pack("<i", 2 if ready else 0))
        if command == 5:  # SetUnits
            units = ints(5)
            if units is None:
                return _reply(command, _RS_WRONG_PARAMETER)
            if units[0] not in _MM_PER_UNIT:
                return _reply(command, _RS_WRONG_PARAMETER1)
            fake._length_unit = units[0]
            return _reply(command, _RS_OK)
        if command == 6:  # GetUnits
            return _reply(command, _RS_OK, struct.pack("<5i", fake._length_unit, 0, 0, 0, 0))
        if command == 7:  # Initialize
            if params:
                return _reply(command, _RS_WRONG_PARAMETER)
            if fake._not_ready():
                return _reply(command, _RS_NOT_WARMED_UP)
            self.init_done_at = fake._clock.now() + _INIT_DURATION_S
            fake._clock.schedule(self.init_done_at)
            return None  # replied when done
        if command == 24:  # SetMeasurementMode
            mode = ints(1)
            if mode is None:
                return _reply(command, _RS_WRONG_PARAMETER)
            if mode[0] not in (0, 1, _MM_6D_CONTINUOUS_TIME):
                return _reply(command, _RS_NOT_IMPLEMENTED)
            fake._meas_mode = mode[0]
            return _reply(command, _RS_OK)
        if command == 25:  # GetMeasurementMode
            return _reply(command, _RS_OK, struct.pack("<i", fake._meas_mode))
        if command == 26:  # SetCoordinateSystemType
            cs = ints(1)
            if cs is None:
                return _reply(command, _RS_WRONG_PARAMETER)
            return _reply(command, _RS_OK if cs[0] == 0 else (_RS_NOT_IMPLEMENTED if 0 < cs[0] <= 7
                                                             else _RS_WRONG_PARAMETER1))
        if command == 28:  # SetStationaryModeParams
            p = ints(2)
            if p is None:
                return _reply(command, _RS_WRONG_PARAMETER)
            if not 1 <= p[0] <= 100_000:
                return _reply(command, _RS_WRONG_PARAMETER1)
            fake._stationary_ms = p[0]
            return _reply(command, _RS_OK)
        if command == 30:  # SetContinuousTimeModeParams
            p = ints(4)
            if p is None:
                return _reply(command, _RS_WRONG_PARAMETER)
            if not 1 <= p[0] <= 1_000_000:
                return _reply(command, _RS_WRONG_PARAMETER1)
            if p[1] != 0 or p[2] != 0:
                return _reply(command, _RS_NOT_IMPLEMENTED)
            fake._separation_ms = p[0]
            return _reply(command, _RS_OK)
        if command == 47:  # SetSystemSettings
            return _reply(command, _RS_OK if ints(9) is not None else _RS_WRONG_PARAMETER)
        if command == 49:  # StartMeasurement
            if self.streaming or self.single_window is not None:
                return _reply(command, _RS_BUSY)
            if not fake._initialised:
                return _reply(command, _RS_NOT_INITIALIZED)
            now = fake._clock.now()
            if fake.stats["anchor_t"] is None:
                fake.stats["anchor_t"] = now
            if fake._meas_mode == 0:
                self.single_window = (now, now + fake._stationary_ms / 1000.0)
                fake._clock.schedule(self.single_window[1])
            else:
                sep_us = fake._separation_ms * 1000
                self.next_k = max(0, int(math.ceil((now + fake._offset) * 1e6 / sep_us)))
                self.streaming = True
                self.producer.hold_until(self._next_batch_due())
                if fake._drives_clock:
                    self.running = keep_running(fake._clock)
            return _reply(command, _RS_OK)
        if command == 52:  # StopMeasurement
            if self.streaming:
                self._stream(flush=True)
                self.streaming = False
                self.producer.release()
                stop_running(self.running)
                self.running = None
            return _reply(command, _RS_OK)
        return _reply(command, _RS_NOT_IMPLEMENTED)

    def _finish_pending(self) -> None:
        fake, now = self.fake, self.fake._clock.now()
        if self.init_done_at is not None and now >= self.init_done_at:
            self.init_done_at = None
            fake._initialised = True
            self._send(_reply(7, _RS_OK))
        if self.single_window is not None and now >= self.single_window[1]:
            t0, t1 = self.single_window
            self.single_window = None
            n = max(1, int(round((t1 - t0) * self.fake._source.rate_hz)))
            t = np.linspace(t0, t1, n)
            xyz, valid = fake._measure(t + fake._offset)
            if not valid.all():
                self._send(_error(49, _RS_MEAS_NOT_READY))
                return
            k = _MM_PER_UNIT[fake._length_unit]
            std = xyz.std(axis=0, ddof=1) if n > 1 else np.zeros(3)
            self._send(_single(xyz.mean(axis=0) / k, std / k))

    # ------------------------------------------------------------------ streaming
    def _per_packet(self) -> int:
        rate = 1000.0 / self.fake._separation_ms
        return max(1, int(round(rate / self.fake._faults.packet_rate_hz)))

    def _next_batch_due(self) -> float | None:
        if not self.streaming:
            return None
        sep_us = self.fake._separation_ms * 1000
        return (self.next_k + self._per_packet() - 1) * sep_us / 1e6 - self.fake._offset

    def _stream(self, flush: bool = False) -> None:
        fake = self.fake
        sep_us = fake._separation_ms * 1000
        per = self._per_packet()
        # the clock stops exactly on a packet's due time (the producer's cap): the tolerance keeps the
        # rounding of that time from postponing the packet
        k_now = int(math.floor((fake._clock.now() + fake._offset) * 1e6 / sep_us + 1e-6))
        backlog = k_now - self.next_k + 1
        limit = int(fake._faults.device_buffer_s * 1e6 / sep_us)
        if backlog > limit + per:  # the client did not keep up: the device buffer overflowed
            new_next = k_now + 1 - limit
            fake.stats["samples_dropped"] += new_next - self.next_k
            self.next_k = new_next
        while self.next_k + (1 if flush else per) - 1 <= k_now:
            n = min(per, k_now - self.next_k + 1)
            ks = np.arange(self.next_k, self.next_k + n, dtype=np.int64)
            self.next_k += n
            t_us = ks * sep_us
            xyz, valid = fake._measure(t_us / 1e6)
            xyz_unit = xyz / _MM_PER_UNIT[fake._length_unit]
            quat = fake._orientation(t_us / 1e6) if fake._meas_mode == _MM_6D_CONTINUOUS_TIME else None
            edges = np.flatnonzero(np.diff(valid.astype(np.int8))) + 1
            for lo, hi in zip(np.concatenate([[0], edges]), np.concatenate([edges, [n]])):
                if valid[lo]:
                    if not self.beam_ok:
                        self._send(_status_change(_SSC_READY))
                        self.beam_ok = True
                    packet = _multi(t_us[lo:hi], xyz_unit[lo:hi]) if quat is None else \
                        self._probe_packet(t_us[lo:hi], xyz_unit[lo:hi], quat[lo:hi])
                    self._data_packet(packet, hi - lo, (t_us[lo] / 1e6, t_us[hi - 1] / 1e6))
                elif self.beam_ok:
                    self._send(_status_change(_SSC_NOT_READY))
                    self.beam_ok = False
        if self.streaming:
            self.producer.hold_until(self._next_batch_due())

    def _probe_packet(self, t_us, xyz_unit, quat) -> bytes:
        """A 6-DoF packet; with the ``bad_quaternion`` fault every Nth one's first quaternion is not a unit one."""
        faults, stats = self.fake._faults, self.fake.stats
        stats["probe_packets"] = stats.get("probe_packets", 0) + 1
        if faults.bad_quaternion_every and stats["probe_packets"] % faults.bad_quaternion_every == 0:
            quat = quat.copy()
            quat[0] *= 0.9
            stats["bad_quaternions"] = stats.get("bad_quaternions", 0) + 1
        return _probe_multi(t_us, xyz_unit, quat)

    def _data_packet(self, packet: bytes, n_samples: int, span_s: tuple) -> None:
        fake, faults, stats = self.fake, self.fake._faults, self.fake.stats
        self.packets += 1
        stats["data_packets"] += 1
        count = stats["data_packets"]
        if faults.garbage_every and count % faults.garbage_every == 0:
            junk = fake._rng.integers(0, 256, int(fake._rng.integers(1, 65)), dtype=np.uint8).tobytes()
            stats["garbage_bytes"] += len(junk)
            self._send(junk)
        if faults.truncate_every and count % faults.truncate_every == 0:
            if faults.truncate_tail:
                cut = max(8, len(packet) - faults.truncate_tail)
            else:
                cut = int(fake._rng.integers(8, len(packet)))
            stats["truncated_packets"] += 1
            stats["truncated_samples"] += int(n_samples)
            stats["truncated_spans"].append((*span_s, int(n_samples)))
            self._send(packet[:cut])
        else:
            stats["samples_sent"] += int(n_samples)
            self._send(packet)
        if faults.huge_length_after and count == faults.huge_length_after:
            stats["huge_headers"] += 1
            self._send(_HDR.pack(2**31 - 1, _DT_MULTI))


def start_fake(world, *, host: str | None = None, port: int | None = None,
               faults: dict | None = None, drives_clock: bool = True) -> EmsconFake:
    """Start the emScon fake on loopback; see the module docstring for ``faults``.

    ``drives_clock=False`` in a cell where other fakes schedule simulated time (the controller's
    programs): the stream then follows the lockstep clock instead of running it.
    """
    return EmsconFake(world, host=host, port=port, faults=faults, drives_clock=drives_clock)


__all__ = ["start_fake", "EmsconFake", "TrackerFaults", "parse_tracker_faults", "check_loopback",
           "EMSCON_FAULTS"]
