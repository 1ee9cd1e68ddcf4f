"""The laser-tracker interface procedures use, whatever the wire protocol.

A procedure opens a tracker by URL (:func:`drivers.tracker_url.open_tracker`), connects, sets
units, takes stationary measurements, and runs continuous time-based
streams whose samples carry **device time**. Status changes (beam broken,
target reacquired, not ready, connection lost/restored) are
:class:`TrackerEvent` objects delivered in order with the samples, so a beam
break is something the procedure sees, not a hole it finds later.

Nothing delivered is silently dropped. Each stream keeps a
:class:`StreamRecord` whose counters satisfy, over the device-time grid
between the first and last sample::

    grid points = received + rejected + lost + not_measured

* ``received``: samples accepted and handed to the caller;
* ``rejected``: samples that arrived but failed validation (non-finite
  values, off the time grid) - not delivered;
* ``lost``: grid points the device measured that never arrived (dropped
  connection, device buffer overflow, corrupt packets);
* ``not_measured``: grid points inside a beam break (the device had no
  target, so there was nothing to measure).

Plus ``duplicates`` (a grid point that arrived again or out of order, not
delivered twice), ``rejected_frames`` and ``garbage_bytes`` from the framing
layer, and every gap with its cause in ``gaps``.

Errors come from :mod:`station.errors`; drivers add :class:`BeamBroken`.
"""

from __future__ import annotations

import abc
import enum
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from drivers.transport import ListeningDeadline
from station.errors import ConfigError, DeviceError


class BeamBroken(DeviceError):
    """The tracker has no target (beam interrupted) and cannot measure now."""


class EventKind(str, enum.Enum):
    BEAM_BROKEN = "beam_broken"
    TARGET_REACQUIRED = "target_reacquired"
    NOT_READY = "not_ready"
    READY = "ready"
    CONNECTION_LOST = "connection_lost"
    RECONNECTED = "reconnected"
    DEVICE_ERROR = "device_error"


@dataclass(frozen=True)
class TrackerEvent:
    """A status change, in arrival order.

    Attributes
    ----------
    kind : EventKind
    host_time_s : float
        Host monotonic time of arrival.
    t_device_s : float or None
        Device time of the last sample received before the event (the event
        happened after it), None before any sample.
    detail : str
    """

    kind: EventKind
    host_time_s: float
    t_device_s: float | None
    detail: str = ""


@dataclass(frozen=True)
class Gap:
    """Missing grid points between two received samples.

    ``cause`` is ``"beam_broken"``, ``"lost"`` or ``"rejected"`` (when every
    missing point was a rejected sample).
    """

    t_before_s: float
    t_after_s: float
    missing: int
    cause: str


@dataclass(frozen=True)
class SampleBatch:
    """Samples in device time, plus the events that arrived with them.

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Device time, s, strictly increasing.
    xyz_mm : ndarray, shape (N, 3)
        Target position in the tracker frame, mm.
    status : ndarray, shape (N,), int8
        Per-sample device status (0 = OK; emScon: 1 speed warning,
        2 speed exceeded, 3 prism error, 4 trigger time violation).
    events : tuple of TrackerEvent
    quat_wxyz : ndarray, shape (N, 4), or None
        A 6-DoF target's orientation per sample (unit quaternion, scalar
        first: the target's frame into the tracker's); None from a
        position-only stream.
    """

    t_s: np.ndarray
    xyz_mm: np.ndarray
    status: np.ndarray
    events: tuple = ()
    quat_wxyz: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass(frozen=True)
class StationaryMeasurement:
    """One stationary (averaged) point.

    ``xyz_mm`` (3,) tracker frame; ``std_mm`` (3,) per-axis standard deviation
    when the device reports it (NaN otherwise); ``t_device_s`` when the
    protocol carries a device time (GeoCOM), else None; ``host_time_s`` host
    monotonic time of arrival.
    """

    xyz_mm: np.ndarray
    std_mm: np.ndarray
    t_device_s: float | None
    host_time_s: float
    temperature_c: float | None = None
    pressure_mbar: float | None = None
    humidity_pct: float | None = None


@dataclass(frozen=True)
class StreamRecord:
    """Counters and gaps of one continuous stream (see module docstring)."""

    protocol: str
    rate_hz: float
    received: int
    rejected: int
    lost: int
    not_measured: int
    duplicates: int
    rejected_frames: int
    garbage_bytes: int
    reconnects: int
    t_first_s: float | None
    t_last_s: float | None
    gaps: tuple = ()
    events: tuple = ()
    #: why the stream stopped early (a dead link, a failure inside the driver's thread), or None
    error: str | None = None

    @property
    def grid_points(self) -> int:
        """Grid points from the first to the last received sample, inclusive."""
        if self.t_first_s is None:
            return 0
        return int(round((self.t_last_s - self.t_first_s) * self.rate_hz)) + 1


@dataclass(frozen=True)
class TrackerInfo:
    protocol: str
    name: str
    serial_number: str
    firmware: str


def _empty_batch(events=()) -> SampleBatch:
    return SampleBatch(np.empty(0), np.empty((0, 3)), np.empty(0, dtype=np.int8), tuple(events))


#: s: the longest :meth:`StreamBuffer.take` waits between two looks at its deadline
TAKE_LOOK_S = 0.05


class StreamBuffer:
    """Thread-safe accounting and buffering of one stream's samples.

    A reader thread calls :meth:`add` with decoded samples and :meth:`event`
    with status changes; the procedure's thread calls :meth:`take`. Samples
    on a device-time grid (``grid=True``) get gap accounting; polled streams
    (``grid=False``) count duplicates and leave ``lost`` to the driver
    (:meth:`count_lost`).

    Parameters
    ----------
    protocol : str
    rate_hz : float
        Grid rate, Hz (> 0).
    grid : bool
    grid_tolerance : float
        Largest distance from a grid point, in periods, for a sample to count
        as on the grid.
    """

    def __init__(self, protocol: str, rate_hz: float, *, grid: bool = True,
                 grid_tolerance: float = 0.25) -> None:
        if not (isinstance(rate_hz, (int, float)) and np.isfinite(rate_hz) and rate_hz > 0):
            raise ConfigError(f"rate_hz must be a finite number > 0, got {rate_hz!r}")
        self.protocol = protocol
        self.rate_hz = float(rate_hz)
        self.grid = grid
        self._tol = grid_tolerance
        self._cond = threading.Condition()
        self._chunks: deque = deque()
        self._pending_events: list[TrackerEvent] = []
        self._all_events: list[TrackerEvent] = []
        self._gaps: list[Gap] = []
        self._last_k: int | None = None
        self._last_t: float | None = None
        self._first_t: float | None = None
        self._beam_broken_since_last = False
        self._rejected_since_last = 0
        self.received = 0
        self.rejected = 0
        self.lost = 0
        self.not_measured = 0
        self.duplicates = 0
        self.rejected_frames = 0
        self.garbage_bytes = 0
        self.reconnects = 0
        self._failure: BaseException | None = None

    # -- writer side (reader thread) --------------------------------------------------
    def event(self, kind: EventKind, detail: str = "") -> TrackerEvent:
        with self._cond:
            ev = TrackerEvent(EventKind(kind), time.monotonic(), self._last_t, detail)
            if ev.kind is EventKind.BEAM_BROKEN:
                self._beam_broken_since_last = True
            if ev.kind is EventKind.RECONNECTED:
                self.reconnects += 1
            self._pending_events.append(ev)
            self._all_events.append(ev)
            self._cond.notify_all()
            return ev

    def count_garbage(self, nbytes: int) -> None:
        with self._cond:
            self.garbage_bytes += int(nbytes)
            self.rejected_frames += 1

    def count_rejected(self, n: int) -> None:
        with self._cond:
            self.rejected += int(n)
            self._rejected_since_last += int(n)

    def count_lost(self, n: int) -> None:
        with self._cond:
            self.lost += int(n)

    def count_not_measured(self, n: int) -> None:
        with self._cond:
            self.not_measured += int(n)

    def fail(self, exc: BaseException) -> None:
        """The stream cannot continue; :meth:`take` raises ``exc`` once drained, the record keeps why."""
        with self._cond:
            self._failure = exc
            self._cond.notify_all()

    def add(self, t_s, xyz, status, quat_wxyz=None) -> int:
        """Validate, account and buffer samples (with a 6-DoF target's quaternions, (N, 4)); returns how many
        were accepted."""
        t_s = np.asarray(t_s, dtype=np.float64).ravel()
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        status = np.asarray(status).astype(np.int8, copy=False).ravel()
        quat = None if quat_wxyz is None else np.asarray(quat_wxyz, dtype=np.float64).reshape(-1, 4)
        if not (len(t_s) == len(xyz) == len(status)) or (quat is not None and len(quat) != len(t_s)):
            raise ValueError("t_s, xyz, status (and quat_wxyz) must have the same length")
        with self._cond:
            keep = np.isfinite(t_s) & np.isfinite(xyz).all(axis=1)
            if quat is not None:
                keep &= np.isfinite(quat).all(axis=1)
            if self.grid:
                kf = t_s * self.rate_hz
                k = np.rint(np.where(keep, kf, 0.0)).astype(np.int64)
                keep &= np.abs(kf - k) <= self._tol
                # strictly increasing grid index against everything accepted before
                prev = -(2**62) if self._last_k is None else self._last_k
                run = np.maximum.accumulate(np.concatenate([[prev], np.where(keep, k, prev)]))[:-1]
                repeat = keep & (k <= run)  # a grid point already delivered (or out of order)
                self.duplicates += int(repeat.sum())
                keep &= ~repeat
            else:
                finite = keep
                prev = -np.inf if self._last_t is None else self._last_t
                run = np.maximum.accumulate(np.concatenate([[prev], np.where(finite, t_s, prev)]))[:-1]
                self.duplicates += int((finite & (t_s == run)).sum())
                self.rejected += int((~finite).sum()) + int((finite & (t_s < run)).sum())
                keep = finite & (t_s > run)
            if self.grid:
                rej = ~keep & ~repeat
                self.rejected += int(rej.sum())
                idx = np.flatnonzero(keep)
                if idx.size:
                    k_kept = k[idx]
                    prev_k = np.concatenate([[self._last_k if self._last_k is not None else k_kept[0] - 1],
                                             k_kept[:-1]])
                    missing = k_kept - prev_k - 1
                    # rejected samples between consecutive kept samples
                    crej = np.concatenate([[0], np.cumsum(rej)])
                    rej_before = crej[idx] - np.concatenate([[0], crej[idx[:-1] + 1]])
                    rej_before[0] += self._rejected_since_last
                    t_prev = np.concatenate([[self._last_t if self._last_t is not None else np.nan],
                                             t_s[idx[:-1]]])
                    for j in np.flatnonzero(missing > 0):  # loops over gaps, not samples
                        m = int(missing[j])
                        if j == 0 and self._beam_broken_since_last:
                            self.not_measured += m
                            cause = "beam_broken"
                        else:
                            unexplained = max(0, m - int(rej_before[j]))
                            self.lost += unexplained
                            cause = "lost" if unexplained else "rejected"
                        self._gaps.append(Gap(float(t_prev[j]), float(t_s[idx[j]]), m, cause))
                    self._last_k = int(k_kept[-1])
                    self._rejected_since_last = int(crej[-1] - crej[idx[-1] + 1])
                else:
                    self._rejected_since_last += int(rej.sum())
            else:
                idx = np.flatnonzero(keep)
            if idx.size:
                self._beam_broken_since_last = False
                if self._first_t is None:
                    self._first_t = float(t_s[idx[0]])
                self._last_t = float(t_s[idx[-1]])
                self.received += int(idx.size)
                self._chunks.append((t_s[idx], xyz[idx], status[idx], None if quat is None else quat[idx]))
                self._cond.notify_all()
            return int(idx.size)

    # -- reader side (procedure) -------------------------------------------------------
    def take(self, timeout_s: float, max_samples: int | None = None) -> SampleBatch:
        """Samples and events buffered so far; waits up to ``timeout_s`` for any, counted only while this
        process runs (:class:`drivers.transport.ListeningDeadline`: a longer gap than :data:`TAKE_LOOK_S`
        between two looks is a host that did not run the driver's reader either)."""
        deadline = ListeningDeadline(max(0.0, timeout_s), TAKE_LOOK_S)
        with self._cond:
            while not self._chunks and not self._pending_events and self._failure is None:
                left = deadline.time_left()
                if left <= 0:
                    break
                self._cond.wait(min(left, TAKE_LOOK_S))
            events = tuple(self._pending_events)
            self._pending_events.clear()
            if not self._chunks:
                if self._failure is not None and not events:
                    raise self._failure
                return _empty_batch(events)
            parts, n = [], 0
            while self._chunks and (max_samples is None or n < max_samples):
                t, x, s, q = self._chunks.popleft()
                if max_samples is not None and n + len(t) > max_samples:
                    cut = max_samples - n
                    self._chunks.appendleft((t[cut:], x[cut:], s[cut:], None if q is None else q[cut:]))
                    t, x, s, q = t[:cut], x[:cut], s[:cut], None if q is None else q[:cut]
                parts.append((t, x, s, q))
                n += len(t)
        # orientation only when every sample of the batch has one (a stream is 6-DoF or not as a whole)
        quats = [p[3] for p in parts]
        quat = None if any(q is None for q in quats) else np.concatenate(quats)
        return SampleBatch(np.concatenate([p[0] for p in parts]),
                           np.concatenate([p[1] for p in parts]),
                           np.concatenate([p[2] for p in parts]), events, quat)

    def take_events(self) -> list[TrackerEvent]:
        with self._cond:
            events = list(self._pending_events)
            self._pending_events.clear()
            return events

    def record(self) -> StreamRecord:
        with self._cond:
            return StreamRecord(
                protocol=self.protocol, rate_hz=self.rate_hz, received=self.received,
                rejected=self.rejected, lost=self.lost, not_measured=self.not_measured,
                duplicates=self.duplicates, rejected_frames=self.rejected_frames,
                garbage_bytes=self.garbage_bytes, reconnects=self.reconnects,
                t_first_s=self._first_t, t_last_s=self._last_t, gaps=tuple(self._gaps),
                events=tuple(self._all_events), error=None if self._failure is None else str(self._failure))


def guarded(buf_of, name: str, target):
    """``target`` wrapped for a device thread: an exception it raises fails the stream (an event and an
    error the procedure sees when it reads or stops the stream) instead of ending the thread silently.
    ``buf_of()`` gives the stream buffer at the time of the failure."""
    def run(*args, **kwargs):
        try:
            target(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001 - whatever it is, the reader of the stream must learn of it
            buf = buf_of()
            if buf is not None:
                err = DeviceError(f"{name} failed: {type(exc).__name__}: {exc}")
                buf.event(EventKind.DEVICE_ERROR, str(err))
                buf.fail(err)
    return run


@runtime_checkable
class Tracker(Protocol):
    """What the procedures call on a tracker (implemented by the emScon and GeoCom drivers, on
    :class:`TrackerBase`). Devices are described the same way throughout: a ``Protocol`` the callers
    see (:class:`drivers.robot.Robot` for a robot), and the code a family of drivers shares in a
    base class of its own. Use as a context manager."""

    protocol: str

    def connect(self, timeout_s: float = 30.0) -> TrackerInfo:
        """Open the link, check the tracker and initialise it if needed."""

    def set_units(self, length_unit: str = "mm") -> None:
        """Units the device reports in; samples are always delivered in mm."""

    def measure_stationary(self, duration_s: float = 0.5, timeout_s: float = 10.0) -> StationaryMeasurement:
        """One stationary point averaged over ``duration_s`` of device time.

        Raises BeamBroken, DeviceNotReady, DeviceTimeout, ConnectionLost.
        """

    def start_stream(self, rate_hz: float) -> None:
        """Start a continuous time-based stream at ``rate_hz`` (device time)."""

    def stop_stream(self, timeout_s: float = 5.0) -> StreamRecord:
        """Stop the stream; samples already received stay readable."""

    def read_samples(self, timeout_s: float = 1.0, max_samples: int | None = None) -> SampleBatch:
        """Samples (device time, mm) and events since the last call (empty after ``timeout_s``)."""

    def sync(self, timeout_s: float = 5.0) -> None:
        """Return once every sample the device sent before this call is readable."""

    def poll_events(self) -> list[TrackerEvent]:
        """Events not yet handed out (with or without a stream)."""

    def stream_record(self) -> StreamRecord | None:
        """Counters of the current (or last) stream."""

    def link_record(self) -> StreamRecord:
        """Counters of the traffic outside streams."""

    def close(self) -> None:
        """Stop everything and release the transport; idempotent."""

    def __enter__(self): ...

    def __exit__(self, *exc) -> None: ...


class TrackerBase(abc.ABC):
    """The code every tracker driver shares (event and stream buffers, reads, context manager); a driver
    implements the abstract methods and so offers :class:`Tracker`."""

    protocol: str = "?"
    #: streams a 6-DoF target's orientation too (``start_stream(rate_hz, six_dof=True)``)
    measures_orientation: bool = False

    def __init__(self) -> None:
        # events outside a stream land here; a stream uses its own buffer
        self._idle = StreamBuffer(self.protocol, 1.0, grid=False)
        self._stream: StreamBuffer | None = None

    # -- to implement ------------------------------------------------------------------
    @abc.abstractmethod
    def connect(self, timeout_s: float = 30.0) -> TrackerInfo:
        """Open the link, check the tracker and initialise it if needed."""

    @abc.abstractmethod
    def set_units(self, length_unit: str = "mm") -> None:
        """Units the device reports in; samples are always delivered in mm."""

    @abc.abstractmethod
    def measure_stationary(self, duration_s: float = 0.5, timeout_s: float = 10.0) -> StationaryMeasurement:
        """One stationary point averaged over ``duration_s`` of device time.

        Raises BeamBroken, DeviceNotReady, DeviceTimeout, ConnectionLost.
        """

    @abc.abstractmethod
    def start_stream(self, rate_hz: float) -> None:
        """Start a continuous time-based stream at ``rate_hz`` (device time)."""

    @abc.abstractmethod
    def stop_stream(self, timeout_s: float = 5.0) -> StreamRecord:
        """Stop the stream; samples already received stay readable."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop everything and release the transport; idempotent."""

    # -- shared ------------------------------------------------------------------------
    @property
    def streaming(self) -> bool:
        return self._stream is not None and self._stream_active

    _stream_active = False

    def read_samples(self, timeout_s: float = 1.0, max_samples: int | None = None) -> SampleBatch:
        """Samples (device time, mm) and events since the last call.

        Waits up to ``timeout_s`` for at least one sample or event; returns an
        empty batch when none came. Raises ConnectionLost once the link is
        gone for good and every buffered sample has been handed out.
        """
        buf = self._stream
        if buf is None:
            return self._idle.take(timeout_s)  # events only
        idle = self._idle.take_events()
        batch = buf.take(timeout_s, max_samples)
        if idle:
            batch = SampleBatch(batch.t_s, batch.xyz_mm, batch.status, tuple(idle) + batch.events)
        return batch

    def sync(self, timeout_s: float = 5.0) -> None:
        """Return once every sample the device sent before this call is readable.

        A driver whose samples share one ordered link with its command replies
        makes a round trip (a reply comes after everything sent before it);
        a driver that asks for each sample itself has nothing in flight.
        """

    def poll_events(self) -> list[TrackerEvent]:
        """Events not yet handed out (with or without a stream)."""
        events = self._idle.take_events()
        if self._stream is not None:
            events += self._stream.take_events()
        return events

    def stream_record(self) -> StreamRecord | None:
        """Counters of the current (or last) stream."""
        return None if self._stream is None else self._stream.record()

    def link_record(self) -> StreamRecord:
        """Counters of the traffic outside streams (garbage bytes, rejected
        frames) and every event that arrived while no stream ran."""
        return self._idle.record()

    def _event(self, kind: EventKind, detail: str = "") -> None:
        (self._stream if self._stream is not None and self._stream_active else self._idle).event(kind, detail)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = [
    "BeamBroken", "EventKind", "TrackerEvent", "Gap", "SampleBatch", "StationaryMeasurement",
    "StreamRecord", "TrackerInfo", "StreamBuffer", "Tracker", "TrackerBase",
]
