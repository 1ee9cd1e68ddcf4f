"""Leica GeoCOM tracker / total-station driver (ASCII request/reply over serial).

Wire format (ASCII lines, CR LF terminated, CRC off)::

    request  %R1Q,<rpc>,<trid>:<p1>,<p2>,...
    reply    %R1P,<com_rc>,<trid>:<rc>[,<v1>,...]

The transaction id is echoed; a reply with another id is stale (it answers
a request that timed out) and is skipped. ``com_rc`` non-zero is a
communication-level error (ProtocolError); ``rc`` is the rpc's return code,
mapped to exceptions by :func:`geocom_error`. Coordinates come in metres,
angles in radians, times in milliseconds of the instrument clock; samples are
delivered in mm and seconds.

RPCs used: COM_NullProc 0, COM_GetDoublePrecision 108, CSV_GetInstrumentName
5004, CSV_GetInstrumentNo 5003, CSV_GetSWVersion 5034, TMC_DoMeasure 2008
(program, inclination mode), TMC_GetCoordinate 2082 (wait ms, inclination
mode) -> E, N, H, time, E_cont, N_cont, H_cont, time_cont.

GeoCOM has no pushed stream: :meth:`GeoComTracker.start_stream` starts the
tracking program (TMC_DoMeasure TRACK) and a poll thread that asks for the
coordinate at ``rate_hz`` (host time); every sample is stamped with the
instrument's coordinate time. A poll without an answer counts as lost, a
malformed answer as rejected, a repeated coordinate time as a duplicate, a
poll answered "no distance" (beam broken) as not measured.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from drivers.tracker import (BeamBroken, EventKind, guarded, StationaryMeasurement, StreamBuffer, StreamRecord,
                             TrackerBase, TrackerInfo)
from drivers.geocom_codec import (GeoComReply, INCLINATION_AUTO, MeasureProgram, RC_NAMES, RC_WARNINGS,
                                  REPLY_VALUES, Rpc, encode_request, geocom_error, idempotent, parse_float,
                                  parse_int, parse_reply, rc_name)
from drivers.transport import (LineReader, ListeningDeadline, check_positive, serial_factory,
                               transport_or_factory)
from station.device_urls import parse_device_url
from station.errors import (ConfigError, ConnectionLost, DeviceError, DeviceNotReady, DeviceTimeout, ProtocolError,
                            StationError)

#: the longest one wait for a reply blocks, s: a longer gap between two looks is a host that did not run, and
#: only this much of it counts toward a reply's timeout (:class:`drivers.transport.ListeningDeadline`)
LISTEN_SLICE_S = 0.01


class GeoComTracker(TrackerBase):
    """GeoCOM client over a serial line (pty in tests).

    Parameters
    ----------
    transport : Transport or callable returning a Transport
        A factory allows reopening the port after the line went dead.
    reply_timeout_s : float
        Time allowed for each reply (host seconds).
    reconnect_timeout_s : float
        How long a stream keeps trying to revive a dead line.
    dead_after : int
        Consecutive unanswered polls after which the line is reopened.
    """

    protocol = "geocom"

    def __init__(self, transport, *, reply_timeout_s: float = 3.0, reconnect_timeout_s: float = 10.0,
                 backoff_initial_s: float = 0.05, backoff_max_s: float = 1.0, dead_after: int = 2,
                 max_line_bytes: int = 1024) -> None:
        super().__init__()
        check_positive(reply_timeout_s=reply_timeout_s, reconnect_timeout_s=reconnect_timeout_s,
                       backoff_initial_s=backoff_initial_s, backoff_max_s=backoff_max_s)
        if not (isinstance(dead_after, int) and dead_after >= 1):
            raise ConfigError(f"dead_after must be an integer >= 1, got {dead_after!r}")
        self._factory, self._transport = transport_or_factory(transport)
        self.reply_timeout_s = float(reply_timeout_s)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self._backoff = (float(backoff_initial_s), float(backoff_max_s))
        self._dead_after = dead_after
        self._max_line = int(max_line_bytes)
        self._lines: LineReader | None = None
        self._lock = threading.Lock()
        self._trid = 0
        self._stop = threading.Event()
        self._poller: threading.Thread | None = None
        self._beam_ok = True
        self._ready = True
        self.info: TrackerInfo | None = None
        #: idempotent requests sent again after a lost or damaged reply
        self.retries = 0

    @classmethod
    def from_url(cls, url, *, timeout_s: float | None = None, **options) -> "GeoComTracker":
        """``geocom:///dev/ttyX[?baud=N]`` (115200 baud by default) or ``geocom+socket://HOST:PORT``
        (a TCP serial bridge), as :mod:`station.device_urls` defines them; ``timeout_s`` is the reply timeout."""
        u = parse_device_url(url, scheme=("geocom", "geocom+socket"))
        if timeout_s is not None:
            options["reply_timeout_s"] = timeout_s
        if u.scheme == "geocom":
            return cls(serial_factory(u.path, baudrate=u.int_option("baud")), **options)
        return cls(serial_factory(f"socket://{u.host}:{u.port}"), **options)

    # ------------------------------------------------------------------ public API
    def connect(self, timeout_s: float = 30.0) -> TrackerInfo:
        # the instrument's silence, counted only while this process runs: opening the line and clearing the
        # instrument's buffer block up to one reply's time when it runs; a longer gap is a host that did not
        deadline = ListeningDeadline(timeout_s, self.reply_timeout_s + LISTEN_SLICE_S)
        if self._transport is None or self._transport.closed:
            if self._factory is None:
                raise ConnectionLost("the driver was closed and a bare transport cannot be reopened")
            self._transport = self._factory()
        self._stop.clear()
        self._lines = LineReader(self._transport, max_line_bytes=self._max_line)
        self._transport.write(b"\n", self.reply_timeout_s)  # clear the instrument's receive buffer
        self.request(Rpc.NULL_PROC, timeout_s=min(self.reply_timeout_s, deadline.time_left()))
        name = self._optional(Rpc.GET_INSTRUMENT_NAME)
        number = self._optional(Rpc.GET_INSTRUMENT_NO)
        version = self._optional(Rpc.GET_SW_VERSION)
        self.info = TrackerInfo("geocom", name[0].strip('"') if name else "?", number[0] if number else "?",
                                ".".join(version) if version else "?")
        return self.info

    def set_units(self, length_unit: str = "mm") -> None:
        """GeoCOM always reports metres and radians; samples come out in mm either way."""
        if length_unit not in ("mm", "m"):
            raise ConfigError(f"GeoCOM length unit must be 'mm' or 'm' (the wire is always metres), "
                              f"got {length_unit!r}")

    def measure_stationary(self, duration_s: float = 0.5, timeout_s: float = 10.0) -> StationaryMeasurement:
        """One distance measurement (GeoCOM does not average; ``duration_s`` is unused)."""
        if self._stream_active:
            raise DeviceError("a stream is running; stop it before a stationary measurement")
        # each request waits at most reply_timeout_s between two looks: a longer gap is a host that did not run
        deadline = ListeningDeadline(timeout_s, self.reply_timeout_s + LISTEN_SLICE_S)
        self.request(Rpc.DO_MEASURE, (MeasureProgram.DISTANCE, INCLINATION_AUTO),
                     timeout_s=min(self.reply_timeout_s, max(deadline.time_left(), 1e-3)))
        wait_ms = int(max(0.0, min(deadline.time_left(), self.reply_timeout_s)) * 500)
        values = self.request(Rpc.GET_COORDINATE, (wait_ms, INCLINATION_AUTO),
                              timeout_s=min(self.reply_timeout_s, max(deadline.time_left(), 1e-3)))
        xyz, t_s = self._coordinate(values)
        return StationaryMeasurement(xyz_mm=xyz, std_mm=np.full(3, np.nan), t_device_s=t_s,
                                     host_time_s=time.monotonic())

    @staticmethod
    def rate_problem(rate_hz) -> str | None:
        """Why a polled GeoCOM stream cannot run at ``rate_hz`` (None if it can)."""
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
            return f"rate_hz must be in (0, 1000] for a polled GeoCOM stream, got {rate_hz!r}"
        return None

    def start_stream(self, rate_hz: float) -> None:
        if self._stream_active:
            raise DeviceError("a stream is already running")
        problem = self.rate_problem(rate_hz)
        if problem:
            raise ConfigError(problem)
        self.request(Rpc.DO_MEASURE, (MeasureProgram.TRACK, INCLINATION_AUTO))
        self._stream = StreamBuffer(self.protocol, rate_hz, grid=False)
        self._stream_active = True
        self._stop.clear()
        self._poller = threading.Thread(target=guarded(lambda: self._stream, "GeoCOM poller", self._poll_main),
                                        args=(1.0 / rate_hz,),
                                        name="geocom-poller", daemon=True)
        self._poller.start()

    def stop_stream(self, timeout_s: float = 5.0) -> StreamRecord:
        if self._stream is None:
            raise DeviceError("no stream was started")
        self._stop.set()
        if self._poller is not None:
            self._poller.join(timeout=timeout_s + self.reply_timeout_s)
            self._poller = None
        was_active, self._stream_active = self._stream_active, False
        if was_active:
            self.request(Rpc.DO_MEASURE, (MeasureProgram.STOP, INCLINATION_AUTO), timeout_s=timeout_s)
        return self._stream.record()

    def close(self) -> None:
        self._stop.set()
        if self._poller is not None and self._poller is not threading.current_thread():
            self._poller.join(timeout=self.reply_timeout_s * 2)
            self._poller = None
        if self._stream_active:
            self._stream_active = False
            try:
                self.request(Rpc.DO_MEASURE, (MeasureProgram.STOP, INCLINATION_AUTO), timeout_s=0.5)
            except StationError:
                pass
        if self._transport is not None:
            self._transport.close()

    # ------------------------------------------------------------------ requests
    def _sink(self) -> StreamBuffer:
        return self._stream if (self._stream is not None and self._stream_active) else self._idle

    def request(self, rpc: int, params=(), *, timeout_s: float | None = None, retry: bool | None = None) -> tuple:
        """Send one rpc and return its values (strings); raise on a non-OK rc.

        An idempotent request (:func:`idempotent`; ``retry`` overrides) whose
        reply is lost or arrives damaged is sent again, with a new
        transaction id, while ``timeout_s`` lasts: each attempt waits at most
        ``reply_timeout_s``, a damaged reply is answered at once. A request
        that is not idempotent is sent once and waits the whole ``timeout_s``.
        """
        timeout_s = self.reply_timeout_s if timeout_s is None else timeout_s
        if self._transport is None or self._lines is None:
            raise ConnectionLost("GeoCOM tracker is not connected")
        if retry is None:
            retry = idempotent(rpc, params)
        deadline = ListeningDeadline(timeout_s, LISTEN_SLICE_S)
        if not self._lock.acquire(timeout=max(deadline.time_left(), 0)):
            raise DeviceTimeout(f"rpc {rpc}: the line is busy with another request")
        attempts, damage = 0, None
        try:
            while True:
                trid = self._trid
                self._trid = (self._trid + 1) % 2**15
                self._transport.write(encode_request(rpc, trid, params), max(deadline.time_left(), 1e-3))
                attempts += 1
                attempt = ListeningDeadline(min(self.reply_timeout_s, deadline.time_left()), LISTEN_SLICE_S) \
                    if retry else deadline
                reply = self._await_reply(trid, (attempt, deadline), damaged_ends=retry)
                if reply is not None:
                    damage = self._shape_problem(rpc, reply) if retry else None
                    if damage is None:
                        break
                if not retry or deadline.expired():
                    if damage is not None:
                        raise damage
                    more = f" ({attempts} attempts)" if attempts > 1 else ""
                    raise DeviceTimeout(f"no reply to GeoCOM rpc {rpc} within {timeout_s:g} s{more}")
                self.retries += 1
        finally:
            self._lock.release()
        if reply.com_rc != 0:
            raise ProtocolError(f"GeoCOM rpc {rpc}: communication error {rc_name(reply.com_rc)}")
        if reply.rc != 0 and reply.rc not in RC_WARNINGS:
            raise geocom_error(rpc, reply.rc)
        problem = self._shape_problem(rpc, reply)
        if problem is not None:
            raise problem
        return reply.values

    @staticmethod
    def _shape_problem(rpc: int, reply: GeoComReply) -> ProtocolError | None:
        """A reply of ours whose value count is wrong (a damaged tail), as the error to raise."""
        want = REPLY_VALUES.get(rpc)
        if reply.com_rc == 0 and reply.rc in (0, *RC_WARNINGS) and want is not None and len(reply.values) != want:
            return ProtocolError(f"reply to GeoCOM rpc {rpc} carries {len(reply.values)} values, expected {want}")
        return None

    def _await_reply(self, trid: int, deadlines: tuple[ListeningDeadline, ...], *,
                     damaged_ends: bool) -> GeoComReply | None:
        """The reply with ``trid``; None when one of ``deadlines`` passes first or, with ``damaged_ends``,
        as soon as a damaged reply shows the answer was lost. Stale replies and garbage are skipped.
        The line and every deadline are looked at every :data:`LISTEN_SLICE_S` at least, so time this
        process did not run does not count as the instrument's silence."""
        while True:
            left = min(d.time_left() for d in deadlines)
            try:
                line = self._lines.read_line(min(left, LISTEN_SLICE_S))
            except DeviceTimeout:
                if left <= 0.0:
                    return None
                continue
            except ProtocolError:
                self._sink().count_garbage(0)
                continue
            start = line.rfind(b"%R1P,")
            if start < 0:
                if line:
                    self._sink().count_garbage(len(line))
                continue
            if start > 0:
                self._sink().count_garbage(start)
                line = line[start:]
            try:
                reply = parse_reply(line)
            except ProtocolError:
                self._sink().count_garbage(len(line))
                if damaged_ends:
                    return None
                continue
            if reply.trid != trid:
                continue  # stale reply to a request that timed out
            return reply

    def _optional(self, rpc: int):
        try:
            return self.request(rpc)
        except DeviceError:
            return None

    @staticmethod
    def _coordinate(values: tuple) -> tuple[np.ndarray, float]:
        e, n, h = (parse_float(Rpc.GET_COORDINATE, v) for v in values[0:3])
        t_ms = parse_int(Rpc.GET_COORDINATE, values[3])
        return np.array([e, n, h]) * 1000.0, t_ms / 1000.0

    # ------------------------------------------------------------------ polling
    def _poll_main(self, period_s: float) -> None:
        buf = self._stream
        silent = 0
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                # a poll is not retried: a lost answer is a lost sample, the next poll asks anew
                values = self.request(Rpc.GET_COORDINATE, (0, INCLINATION_AUTO), retry=False)
            except DeviceTimeout:
                buf.count_lost(1)
                silent += 1
                if silent >= self._dead_after and not self._revive(buf):
                    return
                continue
            except ConnectionLost as exc:
                buf.count_lost(1)
                if not self._revive(buf, exc):
                    return
                continue
            except BeamBroken as exc:
                silent = 0
                buf.count_not_measured(1)
                if self._beam_ok:
                    self._beam_ok = False
                    buf.event(EventKind.BEAM_BROKEN, str(exc))
            except DeviceNotReady as exc:
                silent = 0
                buf.count_not_measured(1)
                if self._ready:
                    self._ready = False
                    buf.event(EventKind.NOT_READY, str(exc))
            except ProtocolError:
                silent = 0
                buf.count_rejected(1)
            except DeviceError as exc:
                silent = 0
                buf.count_rejected(1)
                buf.event(EventKind.DEVICE_ERROR, str(exc))
            else:
                silent = 0
                try:
                    xyz, t_s = self._coordinate(values)
                except ProtocolError:
                    buf.count_rejected(1)
                else:
                    if not self._beam_ok:
                        self._beam_ok = True
                        buf.event(EventKind.TARGET_REACQUIRED, "coordinate available again")
                    if not self._ready:
                        self._ready = True
                        buf.event(EventKind.READY, "coordinate available again")
                    buf.add([t_s], xyz[None, :], [0])
            next_t += period_s
            delay = next_t - time.monotonic()
            if delay < 0:
                next_t = time.monotonic()
            elif self._stop.wait(delay):
                return

    def _revive(self, buf: StreamBuffer, cause: BaseException | None = None) -> bool:
        """Reopen a silent line with backoff and restart tracking; False when giving up."""
        buf.event(EventKind.CONNECTION_LOST, f"line silent: {cause or 'no replies'}")
        # the line's silence, counted only while this process runs: it is looked at after each request and
        # each pause, which block up to a reply's time or the longest pause when it runs; a longer gap is a
        # host that did not run (the instrument's replies were not read), and counts that much only
        deadline = ListeningDeadline(self.reconnect_timeout_s,
                                     max(self.reply_timeout_s, self._backoff[1]) + LISTEN_SLICE_S)
        delay, last = self._backoff[0], cause
        while not self._stop.is_set():
            if self._factory is not None:
                try:
                    self._transport.close()
                    self._transport = self._factory()
                    self._lines = LineReader(self._transport, max_line_bytes=self._max_line)
                except (ConnectionLost, DeviceTimeout) as exc:
                    last = exc
            try:
                deadline.time_left()
                self.request(Rpc.NULL_PROC)
                deadline.time_left()
                self.request(Rpc.DO_MEASURE, (MeasureProgram.TRACK, INCLINATION_AUTO))
            except (ConnectionLost, DeviceTimeout, DeviceError) as exc:
                last = exc
            else:
                buf.event(EventKind.RECONNECTED, "line answers again")
                return True
            if deadline.time_left() <= delay:
                break
            if self._stop.wait(delay):
                return False
            delay = min(2 * delay, self._backoff[1])
        if not self._stop.is_set():
            buf.fail(ConnectionLost(f"GeoCOM line dead for {self.reconnect_timeout_s:g} s: {last}"))
        return False


__all__ = ["GeoComTracker", "encode_request", "parse_reply", "GeoComReply", "geocom_error", "Rpc",
           "REPLY_VALUES", "RC_NAMES", "idempotent"]
