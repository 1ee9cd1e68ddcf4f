"""Leica emScon TPI tracker driver (binary packets over TCP, port 700).

One reader thread owns the transport's receive side: it decodes packets
(:mod:`drivers.emscon_codec`), hands command replies to the waiting caller,
puts continuous samples into the stream's :class:`~drivers.tracker.StreamBuffer`
and turns system-status changes into events (MeasStatus_NotReady ->
``beam_broken``, MeasStatus_Ready -> ``target_reacquired``). Bytes that do
not frame are skipped and counted (``garbage_bytes``, ``rejected_frames``);
the stream resynchronises at the next plausible header.

When the link drops the reader emits ``connection_lost``, reconnects with
exponential backoff through the transport factory, restores units,
coordinate system and - if a stream was running - the continuous mode, and
emits ``reconnected``. The grid points missed meanwhile are counted as lost.

Errors: a reply with a non-zero status or an error packet raises
:class:`~station.errors.DeviceNotReady` (tracker not initialised, warming up,
busy), :class:`~drivers.tracker.BeamBroken` (no target for a measurement) or
:class:`~station.errors.DeviceError` naming the command and the TPI status;
no reply in time raises :class:`~station.errors.DeviceTimeout` (a late reply
is recognised and discarded); a dead link raises
:class:`~station.errors.ConnectionLost`.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import Counter, deque

import numpy as np

from drivers import emscon_codec as ec
from drivers.tracker import (BeamBroken, EventKind, StationaryMeasurement, StreamBuffer,
                             StreamRecord, TrackerBase, TrackerInfo)
from drivers.transport import ListeningDeadline, check_positive, tcp_factory, transport_or_factory
from station.device_urls import parse_device_url
from station.errors import (ConfigError, ConnectionLost, DeviceError, DeviceNotReady,
                            DeviceTimeout, ProtocolError, StationError)

#: no laser tracker measures farther (emScon trackers: up to 160 m with the longest-range targets)
MAX_RANGE_MM = 200_000.0

_COMMAND_NAMES = {int(c): c.name for c in ec.Command}

#: the longest a wait for the tracker blocks between two looks at its deadlines, s: a longer gap between two
#: looks is a host that did not run this process (nor its reader thread, which takes the tracker's packets
#: off the socket), and only this much of it counts as the tracker's silence
#: (:class:`drivers.transport.ListeningDeadline`)
LISTEN_SLICE_S = 0.05

#: commands that may be sent again after a lost reply: they read state, set it to a value, or stop (stopping
#: a stopped measurement is answered OK); Initialize and StartMeasurement are sent once
IDEMPOTENT = frozenset(int(c) for c in ec.Command) - {int(ec.Command.INITIALIZE), int(ec.Command.START_MEASUREMENT)}


def _cmd_name(command: int) -> str:
    return f"{_COMMAND_NAMES.get(command, 'command')} ({command})"


def _listening(timeout_s: float) -> ListeningDeadline:
    return ListeningDeadline(max(0.0, timeout_s), LISTEN_SLICE_S)


def _left(deadlines) -> float:
    """Seconds of listening left on the first of ``deadlines`` to expire (each one looked at)."""
    return min(d.time_left() for d in deadlines)


class EmsconTracker(TrackerBase):
    """emScon TPI client.

    Parameters
    ----------
    transport : Transport or callable returning a Transport
        A factory enables reconnection; a bare transport does not.
    reply_timeout_s : float
        Time allowed for each command reply (seconds of the tracker's silence: counted only while this
        process runs, see :data:`LISTEN_SLICE_S`; every timeout of this driver is counted so).
    reconnect_timeout_s : float
        How long to keep trying after the link drops before giving up.
    backoff_initial_s, backoff_max_s : float
        Reconnection delays double from the first to the second.
    max_packet_bytes : int
        Declared packet lengths above this are refused and skipped.
    """

    protocol = "emscon"
    measures_orientation = True

    def __init__(self, transport, *, reply_timeout_s: float = 5.0, reconnect_timeout_s: float = 10.0,
                 backoff_initial_s: float = 0.05, backoff_max_s: float = 1.0,
                 max_packet_bytes: int = ec.DEFAULT_MAX_PACKET_BYTES) -> None:
        super().__init__()
        check_positive(reply_timeout_s=reply_timeout_s, reconnect_timeout_s=reconnect_timeout_s,
                       backoff_initial_s=backoff_initial_s, backoff_max_s=backoff_max_s)
        self._factory, self._transport = transport_or_factory(transport)
        self.reply_timeout_s = float(reply_timeout_s)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self._backoff = (float(backoff_initial_s), float(backoff_max_s))
        self._max_packet = int(max_packet_bytes)
        self._rx = bytearray()
        self._stall: ListeningDeadline | None = None  # the rest of an incomplete packet, from its last bytes
        #: the last skipped byte runs as (bytes, reason), newest last: what a garbage count was made of
        self.rejections: deque = deque(maxlen=32)
        #: quiet time after which received packets are final (host s)
        self.quiet_s = 0.02
        #: time an incomplete packet may wait for its rest before it is skipped (s of the tracker's silence)
        self.stall_s = 0.5
        self._write_lock = threading.Lock()
        self._cmd_lock = threading.Lock()
        self._reply_lock = threading.Lock()
        self._replies: queue.Queue = queue.Queue()
        self._singles: queue.Queue = queue.Queue()
        self._pending: int | None = None
        self._awaiting_single = False
        self._abandoned: Counter = Counter()
        #: an idempotent command is sent again when its reply has not come within this (host s); it covers a
        #: reply swallowed by a truncated packet, which the reader finds after ``stall_s``
        self.retry_after_s = 1.5
        #: idempotent commands sent again after a lost reply
        self.retries = 0
        self._stop = threading.Event()
        self._link_up = threading.Event()
        self._failure: BaseException | None = None
        self._reader: threading.Thread | None = None
        self._length_unit = ec.LengthUnit.MILLIMETER
        self._mm_per_unit = 1.0
        self._separation_ms: int | None = None
        self._stream_mode = ec.MeasMode.CONTINUOUS_TIME
        self._beam_ok = True
        self._stream_active = False
        self.info: TrackerInfo | None = None

    @classmethod
    def from_url(cls, url, *, timeout_s: float | None = None, **options) -> "EmsconTracker":
        """``emscon://HOST[:PORT]`` (port 700 by default; :mod:`station.device_urls`);
        ``timeout_s`` is the reply timeout."""
        u = parse_device_url(url, scheme="emscon")
        if timeout_s is not None:
            options["reply_timeout_s"] = timeout_s
        return cls(tcp_factory(u.host, u.port), **options)

    # ------------------------------------------------------------------ public API
    def connect(self, timeout_s: float = 30.0) -> TrackerInfo:
        if self._reader is not None:
            if self._reader.is_alive():
                raise DeviceError("already connected")
            if self._factory is None:
                raise ConnectionLost("the driver was closed and a bare transport cannot be reopened")
            self._stop, self._failure, self._transport = threading.Event(), None, None
            self._rx.clear()
        deadline = _listening(timeout_s)
        if self._transport is None:
            self._transport = self._factory()
        self._link_up.set()
        self._reader = threading.Thread(target=self._reader_main, name="emscon-reader", daemon=True)
        self._reader.start()
        try:
            self._initialise(deadline, timeout_s)
            values = self._command(ec.CommandPacket(ec.Command.GET_SYSTEM_STATUS),
                                   timeout_s=min(self.reply_timeout_s, deadline.time_left() or 1e-3),
                                   within=(deadline,)).values
            self._configure(min(self.reply_timeout_s, max(deadline.time_left(), 1e-3)), within=(deadline,))
        except BaseException:
            self.close()
            raise
        major, minor, build, serial = values[4], values[5], values[6], values[9]
        self.info = TrackerInfo("emscon", "emScon server", str(serial), f"{major}.{minor}.{build}")
        return self.info

    def set_units(self, length_unit: str = "mm") -> None:
        unit = ec.LengthUnit(ec.length_unit_from_name(length_unit))
        self._command(self._units_packet(unit))
        self._length_unit = unit
        self._mm_per_unit = ec.MM_PER_LENGTH_UNIT[int(unit)]

    def measure_stationary(self, duration_s: float = 0.5, timeout_s: float = 10.0) -> StationaryMeasurement:
        if self._stream_active:
            raise DeviceError("a continuous stream is running; stop it before a stationary measurement")
        if not (isinstance(duration_s, (int, float)) and 0 < duration_s <= 3600):
            raise ConfigError(f"duration_s must be in (0, 3600], got {duration_s!r}")
        # the measurement's timeout counts from here, through its commands, as the tracker's silence
        deadline = _listening(timeout_s)
        self._command(ec.CommandPacket(ec.Command.SET_MEASUREMENT_MODE, (ec.MeasMode.STATIONARY,)),
                      timeout_s=min(self.reply_timeout_s, max(deadline.time_left(), 1e-3)), within=(deadline,))
        meas_ms = max(1, int(round(duration_s * 1000)))
        self._command(ec.CommandPacket(ec.Command.SET_STATIONARY_MODE_PARAMS, (meas_ms, 0)),
                      timeout_s=min(self.reply_timeout_s, max(deadline.time_left(), 1e-3)), within=(deadline,))
        while not self._singles.empty():  # stale results of an abandoned measurement
            self._singles.get_nowait()
        self._awaiting_single = True
        try:
            self._command(ec.CommandPacket(ec.Command.START_MEASUREMENT),
                          timeout_s=min(self.reply_timeout_s, max(deadline.time_left(), 1e-3)), within=(deadline,))
            result = self._await(self._singles, (deadline,))
            if result is None:
                raise DeviceTimeout(f"no stationary result within {timeout_s} s")
        finally:
            self._awaiting_single = False
        if isinstance(result, BaseException):
            raise result
        if isinstance(result, ec.ErrorPacket):
            if result.status == 10004:
                raise BeamBroken(f"stationary measurement failed: status {ec.status_name(result.status)} "
                                 f"(no target: beam broken)")
            raise self._status_error(result.command, result.status)
        if result.status != 0:
            raise self._status_error(ec.Command.START_MEASUREMENT, result.status)
        xyz = np.asarray(result.xyz, dtype=float)
        if not np.all(np.isfinite(xyz)) or np.any(np.abs(xyz) * self._mm_per_unit > MAX_RANGE_MM):
            raise ProtocolError(f"stationary result {xyz.tolist()} is not a measurable position "
                                f"(finite, within {MAX_RANGE_MM / 1000:g} m)")
        k = self._mm_per_unit
        return StationaryMeasurement(
            xyz_mm=xyz * k, std_mm=np.asarray(result.std_xyz, dtype=float) * k,
            t_device_s=None, host_time_s=time.monotonic(), temperature_c=result.temperature,
            pressure_mbar=result.pressure, humidity_pct=result.humidity)

    @staticmethod
    def rate_problem(rate_hz) -> str | None:
        """Why the tracker cannot stream at ``rate_hz`` (None if it can): continuous time
        mode spaces points by whole milliseconds, so only 1000/k Hz."""
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
            return f"rate_hz must be a finite number > 0, got {rate_hz!r}"
        sep = 1000.0 / rate_hz
        if sep < 1 - 1e-9 or abs(sep - round(sep)) > 1e-6:
            return (f"emScon continuous time mode spaces points by whole milliseconds: rate_hz "
                    f"must be 1000/k Hz (1000, 500, 250, ...), got {rate_hz!r}")
        return None

    def start_stream(self, rate_hz: float, *, six_dof: bool = False) -> None:
        """Stream on the time grid; ``six_dof``: a 6-DoF target (T-Mac, T-Probe) in the 6D continuous time
        mode, each sample with its orientation (``SampleBatch.quat_wxyz``)."""
        if self._stream_active:
            raise DeviceError("a continuous stream is already running")
        problem = self.rate_problem(rate_hz)
        if problem:
            raise ConfigError(problem)
        sep_ms = int(round(1000.0 / rate_hz))
        self._stream_mode = ec.MeasMode.SIX_DOF_CONTINUOUS_TIME if six_dof else ec.MeasMode.CONTINUOUS_TIME
        self._command(ec.CommandPacket(ec.Command.SET_MEASUREMENT_MODE, (self._stream_mode,)))
        self._command(ec.CommandPacket(ec.Command.SET_CONTINUOUS_TIME_MODE_PARAMS, (sep_ms, 0, 0, 0)))
        self._separation_ms = sep_ms
        self._stream = StreamBuffer(self.protocol, 1000.0 / sep_ms, grid=True)
        self._stream_active = True
        try:
            self._command(ec.CommandPacket(ec.Command.START_MEASUREMENT))
        except BaseException:
            self._stream_active = False
            raise

    def sync(self, timeout_s: float = 5.0) -> None:
        """A GetSystemStatus round trip: the reader decodes in order, so every data packet the server
        sent before its reply is in the stream buffer on return."""
        self._command(ec.CommandPacket(ec.Command.GET_SYSTEM_STATUS), timeout_s=timeout_s)

    def stop_stream(self, timeout_s: float = 5.0) -> StreamRecord:
        if self._stream is None:
            raise DeviceError("no stream was started")
        try:
            if self._stream_active:
                self._command(ec.CommandPacket(ec.Command.STOP_MEASUREMENT), timeout_s=timeout_s)
        finally:
            self._stream_active = False
        return self._stream.record()

    def close(self) -> None:
        if self._stream_active and self._link_up.is_set() and self._failure is None:
            try:
                self._command(ec.CommandPacket(ec.Command.STOP_MEASUREMENT), timeout_s=1.0)
            except StationError:
                pass
        self._stream_active = False
        self._stop.set()
        transport = self._transport
        if transport is not None:
            transport.close()
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=5.0)

    # ------------------------------------------------------------------ session
    def _units_packet(self, unit: int) -> ec.CommandPacket:
        return ec.CommandPacket(ec.Command.SET_UNITS, (int(unit), ec.AngleUnit.RADIAN, ec.TemperatureUnit.CELSIUS,
                                                       ec.PressureUnit.MBAR, 0))

    def _configure(self, timeout_s: float, within: tuple = ()) -> None:
        self._command(self._units_packet(self._length_unit), timeout_s=timeout_s, within=within)
        self._command(ec.CommandPacket(ec.Command.SET_COORDINATE_SYSTEM_TYPE, (ec.CoordinateSystemType.RHR,)),
                      timeout_s=timeout_s, within=within)

    def _initialise(self, deadline: ListeningDeadline, timeout_s: float, within: tuple = ()) -> None:
        """GetSystemStatus; Initialize until the tracker processor reports initialised (``deadline``, and
        ``within``: enclosing deadlines, looked at through every wait)."""
        delay, last, was_not_ready = self._backoff[0], None, False
        deadlines = (deadline, *within)
        while True:
            left = deadline.time_left()
            status = self._command(ec.CommandPacket(ec.Command.GET_SYSTEM_STATUS),
                                   timeout_s=min(self.reply_timeout_s, max(left, 1e-3)), within=deadlines).values
            if status[1] == ec.TrackerProcessorStatus.INITIALIZED:
                if was_not_ready:
                    self._event(EventKind.READY, "tracker initialised")
                return
            try:
                self._command(ec.CommandPacket(ec.Command.INITIALIZE), timeout_s=max(deadline.time_left(), 1e-3),
                              within=deadlines)
                continue
            except DeviceNotReady as exc:
                last = exc
                if not was_not_ready:
                    self._event(EventKind.NOT_READY, str(exc))
                was_not_ready = True
            if _left(deadlines) <= delay:
                raise DeviceNotReady(f"tracker not ready within {timeout_s:g} s: {last}")
            if self._back_off(delay, deadlines):
                raise ConnectionLost("driver closed while waiting for the tracker")
            delay = min(2 * delay, self._backoff[1])

    def _back_off(self, delay_s: float, deadlines: tuple) -> bool:
        """Wait ``delay_s`` (host s: a pause between attempts, not a timeout) looking at ``deadlines`` every
        :data:`LISTEN_SLICE_S`; True when the driver was closed meanwhile."""
        end = time.monotonic() + delay_s
        while (wait := end - time.monotonic()) > 0:
            if self._stop.wait(min(wait, LISTEN_SLICE_S)):
                return True
            _left(deadlines)
        return self._stop.is_set()

    def _restore(self, within: tuple = ()) -> None:
        """After a reconnection: same units, coordinates and, if running, the stream (``within``: the
        reconnection's deadline, looked at through every wait)."""
        self._initialise(_listening(self.reply_timeout_s * 4), self.reply_timeout_s * 4, within)
        self._configure(self.reply_timeout_s, within)
        if self._stream_active and self._separation_ms:
            self._command(ec.CommandPacket(ec.Command.SET_MEASUREMENT_MODE, (self._stream_mode,)), within=within)
            self._command(ec.CommandPacket(ec.Command.SET_CONTINUOUS_TIME_MODE_PARAMS,
                                           (self._separation_ms, 0, 0, 0)), within=within)
            self._command(ec.CommandPacket(ec.Command.START_MEASUREMENT), within=within)

    # ------------------------------------------------------------------ commands
    def _status_error(self, command: int, status: int) -> DeviceError:
        text = f"{_cmd_name(command)} failed with status {ec.status_name(status)}"
        if status in ec.NOT_READY_STATUSES:
            return DeviceNotReady(text)
        return DeviceError(text)

    def _command(self, packet: ec.CommandPacket, *, timeout_s: float | None = None,
                 within: tuple = ()) -> ec.CommandReply:
        """Send one command and wait for its reply (the reader thread pumps inline).

        An idempotent command (:data:`IDEMPOTENT`: asking again changes
        nothing) whose reply is lost, for example swallowed by a truncated
        data packet just before it, is sent again every ``retry_after_s``
        while ``timeout_s`` lasts; the surplus late reply is discarded. Other
        commands (start a measurement, initialise) are sent once and wait the
        whole ``timeout_s``. ``within``: enclosing deadlines (of a measurement, a connection), looked at
        through every wait and ending it too. Every wait looks every :data:`LISTEN_SLICE_S` at least.
        """
        timeout_s = self.reply_timeout_s if timeout_s is None else timeout_s
        deadline = _listening(timeout_s)
        deadlines = (deadline, *within)
        on_reader = threading.current_thread() is self._reader
        retry = packet.command in IDEMPOTENT
        if self._failure is not None:
            raise ConnectionLost(f"emScon link is down: {self._failure}")
        if not on_reader:
            if not self._wait_for(lambda t: self._link_up.wait(t), deadlines):
                raise DeviceTimeout(f"{_cmd_name(packet.command)}: link not restored within {timeout_s} s")
            if self._failure is not None:
                raise ConnectionLost(f"emScon link is down: {self._failure}")
        if not self._wait_for(lambda t: self._cmd_lock.acquire(timeout=t), deadlines):
            raise DeviceTimeout(f"{_cmd_name(packet.command)}: another command still waits for its reply")
        attempts = 0
        try:
            with self._reply_lock:
                while not self._replies.empty():
                    self._replies.get_nowait()
                self._pending = packet.command
            while True:
                self._write(packet.encode(), _left(deadlines))
                attempts += 1
                attempt = (_listening(min(self.retry_after_s, _left(deadlines))),) if retry else ()
                reply = self._await_reply((*attempt, *deadlines), on_reader)
                if reply is not None:
                    break
                with self._reply_lock:
                    self._abandoned[packet.command] += 1  # its reply, should it come after all, is surplus
                if not retry or _left(deadlines) <= 0.0:
                    more = f" ({attempts} attempts)" if attempts > 1 else ""
                    raise DeviceTimeout(f"no reply to {_cmd_name(packet.command)} within {timeout_s:g} s{more}")
                self.retries += 1
        finally:
            with self._reply_lock:
                self._pending = None
            self._cmd_lock.release()
        if isinstance(reply, BaseException):
            raise reply
        if isinstance(reply, ec.ErrorPacket) or reply.status != 0:
            raise self._status_error(reply.command, reply.status)
        return reply

    @staticmethod
    def _wait_for(wait, deadlines: tuple) -> bool:
        """``wait(t)`` (True when what it waits for came within ``t`` s) again every :data:`LISTEN_SLICE_S`
        until it comes (True) or one of ``deadlines`` expires (False)."""
        while True:
            left = _left(deadlines)
            if wait(min(left, LISTEN_SLICE_S)):
                return True
            if left <= 0.0:
                return False

    def _await(self, box: queue.Queue, deadlines: tuple):
        """The next item of ``box`` (filled by the reader thread), or None when one of ``deadlines``
        expired without one; looks every :data:`LISTEN_SLICE_S`."""
        while True:
            left = _left(deadlines)
            try:
                return box.get(timeout=min(left, LISTEN_SLICE_S))
            except queue.Empty:
                if left <= 0.0:
                    return None

    def _await_reply(self, deadlines: tuple, on_reader: bool):
        """The reply to the pending command, or None when one of ``deadlines`` passed without one."""
        if not on_reader:
            reply = self._await(self._replies, deadlines)
            if reply is not None:
                return reply
        else:
            while True:
                try:
                    return self._replies.get_nowait()
                except queue.Empty:
                    left = _left(deadlines)
                    if left <= 0.0:
                        break
                    self._pump(min(LISTEN_SLICE_S, left))
        with self._reply_lock:
            try:
                return self._replies.get_nowait()
            except queue.Empty:
                return None

    def _write(self, data: bytes, timeout_s: float) -> None:
        transport = self._transport
        if transport is None:
            raise ConnectionLost("not connected")
        with self._write_lock:
            transport.write(data, max(timeout_s, 1e-3))

    # ------------------------------------------------------------------ reader thread
    def _buffer(self) -> StreamBuffer:
        return self._stream if (self._stream is not None and self._stream_active) else self._idle

    def _reader_main(self) -> None:
        while not self._stop.is_set():
            try:
                self._pump(0.1)
            except ConnectionLost as exc:
                if self._stop.is_set():
                    break
                self._link_lost(exc)
                if not self._reconnect():
                    break
            except Exception as exc:  # a bug must not kill the stream silently
                err = DeviceError(f"emScon reader failed: {type(exc).__name__}: {exc}")
                if self._stream is not None:
                    self._stream.event(EventKind.DEVICE_ERROR, str(err))
                self._fail(err)
                break

    def _pump(self, timeout_s: float) -> None:
        """Read once and dispatch every complete packet.

        While bytes flow, a multi result waits for the start of what follows
        it (truncation check); when the link is quiet for ``quiet_s`` what is
        complete is final, and an incomplete packet still pending after
        ``stall_s`` is skipped as truncated.
        """
        data = self._transport.read(1 << 16, min(timeout_s, self.quiet_s) if self._rx else timeout_s)
        if data:
            self._rx += data
            self._stall = ListeningDeadline(self.stall_s, max(LISTEN_SLICE_S, self.quiet_s))  # looked at every quiet_s
            self._decode(flowing=True)
        elif self._rx:
            self._decode(flowing=False)
            if self._rx and (self._stall is None or self._stall.expired()):
                consumed, frame = ec.skip_stalled(bytes(self._rx), max_packet_bytes=self._max_packet)
                del self._rx[:consumed]
                self._handle(frame)
                self._decode(flowing=False)

    def _decode(self, flowing: bool) -> None:
        snapshot = bytes(self._rx)
        view = memoryview(snapshot)
        off = 0
        while True:
            consumed, frame = ec.decode(view[off:], from_server=True, max_packet_bytes=self._max_packet,
                                        require_successor=flowing)
            if consumed == 0:
                break
            off += consumed
            self._handle(frame)
        del self._rx[:off]

    def _handle(self, frame) -> None:
        if isinstance(frame, (ec.CommandReply, ec.ErrorPacket)):
            with self._reply_lock:
                if self._awaiting_single and isinstance(frame, ec.ErrorPacket) \
                        and frame.command == ec.Command.START_MEASUREMENT and self._pending is None:
                    self._singles.put(frame)
                elif self._pending == frame.command:
                    self._replies.put(frame)
                    # answered: a frame for the same command from now on is not this reply. A stationary
                    # measurement's error follows StartMeasurement's own reply; in one read with it, it came
                    # before the caller had cleared the pending command, was taken for a second reply and
                    # lost, and the measurement timed out (soak seed 2715888335)
                    self._pending = None
                elif self._abandoned[frame.command] > 0:
                    self._abandoned[frame.command] -= 1  # late reply to a timed-out command
                elif isinstance(frame, ec.ErrorPacket):
                    self._event(EventKind.DEVICE_ERROR,
                                f"unsolicited error for {_cmd_name(frame.command)}: {ec.status_name(frame.status)}")
            return
        if isinstance(frame, ec.MultiMeasResult):
            buf = self._stream
            if buf is None or self._stream_mode == ec.MeasMode.SIX_DOF_CONTINUOUS_TIME:
                self._idle.count_garbage(0)
                return
            k = self._mm_per_unit
            s = frame.samples
            xyz = np.column_stack([s["val1"], s["val2"], s["val3"]])
            buf.add(ec.join_time_s(s["time1"], s["time2"]), xyz * k if k != 1.0 else xyz, s["status"])
            return
        if isinstance(frame, ec.ProbeContinuousResult):
            buf = self._stream
            if buf is None or self._stream_mode != ec.MeasMode.SIX_DOF_CONTINUOUS_TIME:
                # 6-DoF samples where none were asked: not this stream's (counted, not taken)
                self._buffer().count_garbage(0)
                return
            s = frame.samples
            k = self._mm_per_unit
            ok6 = (s["rotation_status"] & 0b11) == 0b01  # Status6D set, Error6D clear
            if not ok6.all():
                buf.count_rejected(int((~ok6).sum()))
                s = s[ok6]
            buf.add(ec.join_time_s(s["time1"], s["time2"]), s["position"] * k, s["status"], s["quaternion"])
            return
        if isinstance(frame, ec.SingleMeasResult):
            self._singles.put(frame)
            return
        if isinstance(frame, ec.StatusChangePacket):
            if frame.event == ec.SystemStatusChange.MEAS_STATUS_NOT_READY:
                self._beam_ok = False
                self._event(EventKind.BEAM_BROKEN, "MeasStatus_NotReady")
            elif frame.event == ec.SystemStatusChange.MEAS_STATUS_READY:
                if not self._beam_ok:
                    self._event(EventKind.TARGET_REACQUIRED, "MeasStatus_Ready")
                self._beam_ok = True
            return
        if isinstance(frame, ec.Garbage):
            self.rejections.append((frame.nbytes, frame.reason))
            self._buffer().count_garbage(frame.nbytes)

    def _link_lost(self, exc: BaseException) -> None:
        self._link_up.clear()
        transport = self._transport
        if transport is not None:
            transport.close()
        self._rx.clear()
        with self._reply_lock:
            if self._pending is not None:
                self._replies.put(ConnectionLost(f"link dropped while waiting for "
                                                 f"{_cmd_name(self._pending)}: {exc}"))
            if self._awaiting_single:
                self._singles.put(ConnectionLost(f"link dropped during a stationary measurement: {exc}"))
        self._event(EventKind.CONNECTION_LOST, str(exc))

    def _reconnect(self) -> bool:
        if self._factory is None:
            self._fail(ConnectionLost("emScon link dropped and no transport factory was given to reconnect"))
            return False
        # the tracker's absence, counted only while this process runs: a host that did not run it meanwhile
        # (or did not run the tracker's simulation on this host) does not use up the attempts
        deadline = _listening(self.reconnect_timeout_s)
        delay, last, attempts = self._backoff[0], None, 0
        while not self._stop.is_set():
            attempts += 1
            try:
                deadline.time_left()
                t_connect = time.monotonic()
                try:
                    self._transport = self._factory()
                except DeviceTimeout:  # a connect that timed out on its own clock: that long unanswered
                    deadline.count_gap(time.monotonic() - t_connect)
                    raise
                self._rx.clear()
                self._restore((deadline,))
            except (ConnectionLost, DeviceTimeout, DeviceError) as exc:
                last = exc
                if self._transport is not None:
                    self._transport.close()
            else:
                self._link_up.set()
                self._event(EventKind.RECONNECTED, f"after {attempts} attempt(s)")
                return True
            if deadline.time_left() <= delay:
                break
            if self._back_off(delay, (deadline,)):
                return False
            delay = min(2 * delay, self._backoff[1])
        if not self._stop.is_set():
            self._fail(ConnectionLost(f"emScon link lost; {attempts} reconnection attempt(s) in "
                                      f"{self.reconnect_timeout_s:g} s failed: {last}"))
        return False

    def _fail(self, exc: BaseException) -> None:
        self._failure = exc
        self._link_up.set()  # wake waiting callers; they see _failure
        with self._reply_lock:
            if self._pending is not None:
                self._replies.put(exc)
        if self._awaiting_single:
            self._singles.put(exc)
        if self._stream is not None:
            self._stream.fail(exc)
        self._idle.fail(exc)


__all__ = ["EmsconTracker"]
