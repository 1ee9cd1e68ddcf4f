"""Trailer odometry over NMEA 0183 on a serial line (pyserial).

Wire format: NMEA 0183 sentences ``$<body>*hh\\r\\n`` where ``hh`` is the XOR
of the body's bytes in two upper-case hex digits. The odometry unit speaks a
proprietary talker (``P`` + manufacturer ``ODO``); the first field's tail
names the sentence::

    device -> host
      $PODO,<t_s>,<v_m_s>,<kappa_1_m>,<psi_rad>*hh   odometry sample, device time
      $PODOA,<cmd>,<t_s>,<value>*hh                  command <cmd> applied at t_s
      $PODON,<cmd>,<reason>*hh                       command <cmd> refused
    host -> device (same line)
      $PODOC,<kappa_1_m>*hh                          hold this path curvature
      $PODOV,<v_m_s>*hh                              drive at this speed
      $PODOS,<token>,<t_s>*hh                        simulated unit only (``?lockstep=1``): step
                                                     one control cycle (below)

Units: s, m/s, 1/m, rad (seed 003).

Robustness: a sentence with a wrong checksum is counted and skipped; a
partial line (characters lost, a ``$`` before the end of the previous line,
no ``*hh``, overlong) is counted and skipped and the stream resynchronises on
the next ``$``; other talkers are counted as ignored. Nothing that parses is
ever dropped: samples read while waiting for a command's acknowledgement are
queued. Every blocking call has a timeout on the monotonic clock
(:class:`~station.errors.DeviceTimeout`); a refused command raises
:class:`~station.errors.DeviceFault`; a command whose acknowledgement is lost
is re-sent (set points are idempotent).

Lockstep (the simulated unit of a dry run only, ``nmea:///dev/ttyX?lockstep=1``):
a real unit runs in real time and the station keeps up with it; the
simulated one instead steps its control cycle only when the host asks, so
the same seed gives the same samples at any load (the way a
software-in-the-loop simulator waits for its flight stack's outputs). Before
it waits for a sample or an acknowledgement, the driver sends
``$PODOS,<token>,<t_s>``: "driver ``token`` has every sample up to ``t_s``
(empty: none yet) and has sent what the next cycle is to latch". The unit
then runs one cycle: it latches the commands it has read, sends the next
sample and waits again. A sync naming an older sample than the unit's newest
(that sample or the sync was lost, or the host was slow) makes the unit send
its newest sample again; the driver drops a sample that is not newer than
the newest it has, and returns from a blocking command only with the sample
of the cycle that applied it (so what is queued never depends on timing).
The sync is sent again after :data:`SYNC_RETRY_S` without the sample. Closing
sends ``$PODOS,<token>,END``: the unit then holds the clock for nobody.

The codec (:class:`NmeaDecoder`, :func:`encode_sentence`) is pure: bytes in,
messages out, no I/O; it lives in :mod:`drivers.nmea_codec`.
"""

from __future__ import annotations

import collections
import itertools
import math
import os
from dataclasses import dataclass

from drivers.nmea_codec import (
    MANUFACTURER, MAX_SENTENCE_BYTES, CommandAck, CommandNak, LineStats, NmeaDecoder, OdometrySample, checksum,
    encode_curvature_command, encode_sentence, encode_speed_command, encode_sync, parse_body,
)
from drivers.transport import Deadline, ListeningDeadline, SerialTransport, Transport
from station.device_urls import SCHEMES, parse_device_url
from station.errors import ConfigError, DeviceFault, DeviceTimeout, StationError

#: default line speed of the unit
DEFAULT_BAUD = int(SCHEMES["nmea"].options["baud"])

_TOKENS = itertools.count(1)
#: lockstep: the longest wait for a cycle's sample before the sync is sent again, s
SYNC_RETRY_S = 0.05

#: the most of one gap between two looks at the line that counts toward a sample's or a command's timeout,
#: s: the driver looks at least every ack timeout (0.5 s) while it runs, so a longer gap is a host that did
#: not run, whose unit was not heard (see :class:`drivers.transport.ListeningDeadline`)
LISTEN_SLICE_S = 1.0
#: lockstep: the host's own wait for a sample lasts at least this (s); the simulated unit's silence is
#: measured in its own time (the sample after it, :meth:`OdometryDriver.read_sample`), this only catches a
#: unit that never answers again (a loaded host had it time out while the unit was merely not scheduled)
LOCKSTEP_WAIT_S = 10.0


# ----------------------------------------------------------------------------- driver
@dataclass
class SentCommand:
    """A command on its way: ``status`` becomes ``"acked"``, ``"refused"`` or ``"lost"``."""

    cmd: str
    value: float
    status: str | None = None
    t_applied_s: float | None = None
    reason: str | None = None


@dataclass
class CommandStats:
    """Counters of the commands this driver sent."""

    sent: int = 0
    acked: int = 0
    refused: int = 0
    lost: int = 0
    garbled: int = 0
    #: lockstep: sync sentences sent, and samples dropped because they repeated one already received
    syncs: int = 0
    repeats: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def parse_odometry_url(url: str) -> tuple[str, int]:
    """``nmea:///dev/ttyS1?baud=57600`` (:mod:`station.device_urls`), or a plain device path /
    pyserial URL at the default baud -> (port, baud)."""
    if not isinstance(url, str) or not url:
        raise ConfigError(f"odometry device must be a path or URL, got {url!r}")
    if url.lower().startswith("nmea:"):
        u = parse_device_url(url, scheme="nmea")
        return u.path, u.int_option("baud")
    return url, DEFAULT_BAUD


class OdometryDriver:
    """Reads odometry samples and sends curvature/speed commands.

    Parameters
    ----------
    transport : Transport
        A byte pipe (e.g. :class:`drivers.transport.SerialTransport`).
    timeout_s : float
        Default timeout for a sample, s.
    ack_timeout_s : float
        Wait for a command's acknowledgement before re-sending it, s.
    command_retries : int
        Re-sends of a blocking command whose acknowledgement does not come, at
        least; a set point is idempotent (an absolute value), so it is re-sent
        every ``ack_timeout_s`` until acknowledged or until ``timeout_s`` has
        passed, whichever allows more copies (a line that loses one sentence in
        ten each way loses a copy or its acknowledgement one time in five).

    Commands come in two kinds: :meth:`command_curvature` /
    :meth:`command_speed` block until acknowledged (start, stop), and
    :meth:`send_curvature` streams set points without waiting — their
    acknowledgements are matched as samples are read, a refusal raises
    :class:`~station.errors.DeviceFault` from the next read, and a set point
    whose acknowledgement never comes is counted in
    :attr:`command_stats` (``lost``).
    """

    def __init__(self, transport: Transport, *, timeout_s: float = 2.0, ack_timeout_s: float = 0.5,
                 command_retries: int = 2, lockstep: bool = False) -> None:
        for name, value in (("timeout_s", timeout_s), ("ack_timeout_s", ack_timeout_s)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be > 0, got {value!r}")
        if not (isinstance(command_retries, int) and command_retries >= 0):
            raise ConfigError(f"command_retries must be an integer >= 0, got {command_retries!r}")
        self.transport = transport
        self.timeout_s = float(timeout_s)
        self.ack_timeout_s = float(ack_timeout_s)
        self.command_retries = command_retries
        self._decoder = NmeaDecoder()
        self._samples: collections.deque[OdometrySample] = collections.deque()
        self._unacked: collections.deque[SentCommand] = collections.deque()
        self._refusals: collections.deque[SentCommand] = collections.deque()
        self.command_stats = CommandStats()
        self.lockstep = bool(lockstep)
        # lockstep: ask again this soon for a cycle whose sample has not come (lost on the line, or the host
        # slow: the unit then sends it again, and the copy is dropped); the simulated unit is local
        self.sync_retry_s = min(self.ack_timeout_s, SYNC_RETRY_S)
        self._token = f"{os.getpid():x}x{next(_TOKENS)}"  # this driver, to the unit
        self._newest_t: float | None = None  # lockstep: the newest sample received
        self._returned_t: float | None = None  # lockstep: the device time of the newest sample handed out
        self._spacing: float | None = None  # lockstep: the shortest device time between two samples handed out

    @classmethod
    def from_url(cls, url, *, timeout_s: float | None = None, baudrate: int | None = None,
                 ack_timeout_s: float = 0.5, command_retries: int = 2) -> "OdometryDriver":
        """``nmea:///dev/ttyX[?baud=N][&lockstep=1]`` (57600 baud by default; :mod:`station.device_urls`;
        ``lockstep=1``: a simulated unit, stepped cycle by cycle); ``timeout_s``: how long to wait for a
        sample (2 s when None)."""
        u = parse_device_url(url, scheme="nmea")
        lockstep = u.flag_option("lockstep")
        return cls(SerialTransport(u.path, baudrate=baudrate or u.int_option("baud")),
                   timeout_s=2.0 if timeout_s is None else timeout_s,
                   ack_timeout_s=ack_timeout_s, command_retries=command_retries, lockstep=lockstep)

    @classmethod
    def open(cls, device: str, *, baudrate: int | None = None, timeout_s: float = 2.0,
             ack_timeout_s: float = 0.5, command_retries: int = 2, lockstep: bool = False) -> "OdometryDriver":
        """Open a plain serial device path or pyserial URL (an ``nmea://`` URL goes to :meth:`from_url`, its
        own ``lockstep`` option)."""
        if isinstance(device, str) and device.lower().startswith("nmea:"):
            return cls.from_url(device, timeout_s=timeout_s, baudrate=baudrate, ack_timeout_s=ack_timeout_s,
                                command_retries=command_retries)
        port, baud = parse_odometry_url(device)
        return cls(SerialTransport(port, baudrate=baudrate or baud), timeout_s=timeout_s,
                   ack_timeout_s=ack_timeout_s, command_retries=command_retries, lockstep=lockstep)

    # -- state ------------------------------------------------------------------------
    @property
    def stats(self) -> LineStats:
        """Counters of sentences, samples, checksum errors, partial lines..."""
        return self._decoder.stats

    @property
    def queued(self) -> int:
        """Samples received and not yet returned."""
        return len(self._samples)

    def close(self) -> None:
        if self.lockstep:  # the simulated unit need not wait for this driver any more
            try:
                self.transport.write(encode_sync(self._token, None, end=True), self.ack_timeout_s)
            except StationError:
                pass  # the line is gone already
        self.transport.close()

    def __enter__(self) -> "OdometryDriver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- reading ----------------------------------------------------------------------
    def _pump(self, deadline: Deadline | ListeningDeadline) -> bool:
        """Read once (up to the deadline); dispatch messages. True if bytes came."""
        data = self.transport.read(4096, min(deadline.time_left(), 0.25))
        if not data:
            return False
        for msg in self._decoder.feed(data):
            if isinstance(msg, OdometrySample):
                if self.lockstep:
                    if self._newest_t is not None and msg.t_s <= self._newest_t:
                        self.command_stats.repeats += 1  # sent again after a stale sync: have it already
                        continue
                    self._newest_t = msg.t_s
                self._samples.append(msg)
            elif isinstance(msg, CommandAck):
                self._settle(msg.cmd, msg.value, "acked", t_applied=msg.t_s)
            elif isinstance(msg, CommandNak):
                if msg.cmd in ("C", "V"):
                    self._settle(msg.cmd, None, "refused", reason=msg.reason)
                else:
                    self.command_stats.garbled += 1  # the unit could not read a command
        return True

    def _settle(self, cmd: str, value: float | None, status: str, *, t_applied=None, reason=None) -> None:
        """Match a reply to the oldest open command of its kind (older ones were lost)."""
        for i, sent in enumerate(self._unacked):
            if sent.cmd != cmd:
                continue
            if value is not None and abs(sent.value - value) > 1e-6 * max(1.0, abs(sent.value)):
                continue
            for older in list(self._unacked)[:i]:
                if older.cmd == cmd:
                    older.status = "lost"
                    self.command_stats.lost += 1
            self._unacked = collections.deque(c for j, c in enumerate(self._unacked)
                                              if j > i or (j < i and c.cmd != cmd))
            sent.status, sent.t_applied_s, sent.reason = status, t_applied, reason
            if status == "acked":
                self.command_stats.acked += 1
            else:
                self.command_stats.refused += 1
                self._refusals.append(sent)
            return
        # a reply to nothing open (e.g. the first ack of a re-sent command): ignore

    def _raise_refusal(self) -> None:
        if self._refusals:
            sent = self._refusals.popleft()
            raise DeviceFault(f"odometry unit refused command {sent.cmd}={sent.value:g}: {sent.reason}")

    def read_sample(self, timeout_s: float | None = None) -> OdometrySample:
        """The next sample (queued first); DeviceTimeout if none within the timeout.

        Raises DeviceFault first if the unit refused a streamed set point. In lockstep the timeout is
        the device's: the unit holds its clock for its host and only runs on unheld while its line is
        silent, so a sample more than the timeout of device time after the one before says the line was
        silent that long, however little of it this host saw; the host's own wait lasts at least
        :data:`LOCKSTEP_WAIT_S` (a unit that never answers again). The sample stays queued.
        """
        timeout = self.timeout_s if timeout_s is None else timeout_s
        sample = self._read_sample(max(timeout, LOCKSTEP_WAIT_S) if self.lockstep else timeout)
        if self.lockstep:
            last, self._returned_t = self._returned_t, sample.t_s
            gap = None if last is None else sample.t_s - last
            if gap is not None and self._spacing is not None and gap > timeout + self._spacing:
                self._samples.appendleft(sample)
                self._returned_t = last
                raise DeviceTimeout(
                    f"no odometry sample from {self.transport.description} within {timeout} s of device time "
                    f"(t = {last:.3f} s to {sample.t_s:.3f} s: the line was silent)")
            if gap is not None and gap > 0:
                self._spacing = gap if self._spacing is None else min(self._spacing, gap)
        return sample

    def _read_sample(self, timeout: float) -> OdometrySample:
        deadline = ListeningDeadline(timeout, LISTEN_SLICE_S)
        while not self._samples:
            self._raise_refusal()
            if deadline.expired():
                if self._last_look(lambda: bool(self._samples)):
                    break
                raise DeviceTimeout(
                    f"no odometry sample from {self.transport.description} within {timeout} s "
                    f"(line stats: {self.stats.as_dict()})")
            if self.lockstep:  # ask for the next cycle; again after every retry interval without a sample
                self._sync_once(lambda: bool(self._samples), deadline)
                continue
            self._pump(deadline)
        self._raise_refusal()
        return self._samples.popleft()

    def read_samples(self, n: int, timeout_s: float | None = None) -> list[OdometrySample]:
        """``n`` consecutive samples; each must come within the timeout."""
        if not isinstance(n, int) or n < 0:
            raise ConfigError(f"n must be an integer >= 0, got {n!r}")
        return [self.read_sample(timeout_s) for _ in range(n)]

    def drain(self) -> list[OdometrySample]:
        """Samples already received (reads what is waiting, without blocking)."""
        self._pump(Deadline(0.0))
        out = list(self._samples)
        self._samples.clear()
        if out and self.lockstep:
            self._returned_t = out[-1].t_s
        return out

    # -- commands ---------------------------------------------------------------------
    def send_curvature(self, kappa_1_m: float) -> SentCommand:
        """Stream a curvature set point without waiting for its acknowledgement."""
        self._raise_refusal()
        return self._send("C", float(kappa_1_m), encode_curvature_command(float(kappa_1_m)))

    def command_curvature(self, kappa_1_m: float, timeout_s: float | None = None) -> float:
        """Send a curvature set point and wait for it; return the device time it was applied."""
        return self._command("C", float(kappa_1_m), encode_curvature_command(float(kappa_1_m)), timeout_s)

    def command_speed(self, v_m_s: float, timeout_s: float | None = None) -> float:
        """Send a speed set point and wait for it; return the device time it was applied."""
        return self._command("V", float(v_m_s), encode_speed_command(float(v_m_s)), timeout_s)

    def _await_sample_at(self, t_s: float, patience: ListeningDeadline) -> None:
        """Lockstep: read (asking again every retry interval) until the sample of device time ``t_s`` is in.

        The unit sends it right after the acknowledgement, so it is first waited for without a sync (one
        sent before it arrives would have it sent twice)."""
        def have() -> bool:
            return self._newest_t is not None and self._newest_t >= t_s - 5e-4

        self._pump_until(have, Deadline(min(self.sync_retry_s, max(patience.time_left(), 0.0))))
        while not have():
            if patience.expired():
                if self._last_look(have):
                    break
                raise DeviceTimeout(f"no odometry sample of t = {t_s:.3f} s from {self.transport.description} "
                                    f"after its acknowledgement")
            self._sync_once(have, patience)

    def _last_look(self, done) -> bool:
        """At a deadline: read what is already waiting, without waiting; ``done()`` after it. The deadline
        is the host's clock: if this thread did not run for a while (a busy host), the reply may have come
        meanwhile, and a reply that came is no silence of the unit."""
        if not done():
            self._pump(Deadline(0.0))
        return done()

    def _sync_once(self, done, deadline: Deadline | ListeningDeadline) -> None:
        """Lockstep: one sync, then read until ``done()`` or the retry interval (or ``deadline``) has passed."""
        self._sync()
        self._pump_until(done, Deadline(min(self.sync_retry_s, max(deadline.time_left(), 0.0))))

    def _pump_until(self, done, deadline: Deadline | ListeningDeadline) -> None:
        """Read until ``done()`` or ``deadline``."""
        while not done() and not deadline.expired():
            self._pump(deadline)

    def _sync(self) -> None:
        self.transport.write(encode_sync(self._token, self._newest_t), self.ack_timeout_s)
        self.command_stats.syncs += 1

    def _send(self, cmd: str, value: float, frame: bytes) -> SentCommand:
        sent = SentCommand(cmd, value)
        self.transport.write(frame, self.ack_timeout_s)
        self._unacked.append(sent)
        self.command_stats.sent += 1
        return sent

    def _command(self, cmd: str, value: float, frame: bytes, timeout_s: float | None) -> float:
        timeout = self.ack_timeout_s if timeout_s is None else timeout_s
        self._raise_refusal()
        patience = ListeningDeadline(max(self.timeout_s, timeout), LISTEN_SLICE_S)  # re-sent until this, at least
        # retries + 1 times
        attempts = 0
        while attempts <= self.command_retries or not patience.expired():
            attempts += 1
            sent = self._send(cmd, value, frame)
            if self.lockstep:  # the unit latches it at its next cycle
                self._sync()
            deadline = Deadline(timeout)
            self._pump_until(lambda: sent.status is not None, deadline)
            self._last_look(lambda: sent.status is not None)
            if sent.status == "acked":
                if self.lockstep:  # the cycle that applied it also sent a sample: have it, whatever the timing
                    self._await_sample_at(sent.t_applied_s, patience)
                return sent.t_applied_s
            if sent.status == "refused":
                self._refusals = collections.deque(r for r in self._refusals if r is not sent)
                raise DeviceFault(f"odometry unit refused command {cmd}={value:g}: {sent.reason}")
            if sent.status is None:  # no reply in time: give up on this copy, re-send
                sent.status = "lost"
                self.command_stats.lost += 1
                self._unacked = collections.deque(c for c in self._unacked if c is not sent)
        raise DeviceTimeout(f"no acknowledgement of command {cmd}={value:g} from "
                            f"{self.transport.description} after {attempts} attempt(s) of {timeout} s")


__all__ = [
    "MANUFACTURER", "MAX_SENTENCE_BYTES", "DEFAULT_BAUD", "OdometrySample", "CommandAck", "CommandNak",
    "LineStats", "checksum", "encode_sentence", "encode_curvature_command", "encode_speed_command",
    "parse_body", "NmeaDecoder", "parse_odometry_url", "OdometryDriver", "SentCommand", "CommandStats",
]
