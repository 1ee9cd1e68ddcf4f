"""Byte transports that drivers get injected: TCP socket, serial port, serial URL.

Every driver in ``drivers/`` talks to its device through a :class:`Transport`,
so the same codec runs over a real port, a pty in tests, or a loopback socket.
All reads and writes take a timeout measured on the monotonic clock; nothing
here blocks without one.

Errors (from :mod:`station.errors`)::

    read/write on a dropped link      -> ConnectionLost
    write that cannot finish in time  -> DeviceTimeout
    line longer than its limit        -> ProtocolError (never buffered unbounded)
    bad URL                           -> ConfigError

A read that times out is not an error: :meth:`Transport.read` returns ``b""``
and the caller decides (see :class:`LineReader` for a line protocol that turns
it into :class:`~station.errors.DeviceTimeout`).
"""

from __future__ import annotations

import errno
import math
import os
import select
import socket
import time
from typing import Callable, Protocol, runtime_checkable

from station.errors import ConfigError, ConnectionLost, DeviceTimeout, ProtocolError


class Deadline:
    """A point in monotonic time: ``time_left()`` and ``expired()``.

    Parameters
    ----------
    timeout_s : float or None
        Seconds from now; ``None`` means never.
    """

    __slots__ = ("_end",)

    def __init__(self, timeout_s: float | None) -> None:
        if timeout_s is not None and not (isinstance(timeout_s, (int, float)) and timeout_s >= 0):
            raise ConfigError(f"timeout_s must be >= 0 or None, got {timeout_s!r}")
        self._end = math.inf if timeout_s is None else time.monotonic() + float(timeout_s)

    def time_left(self) -> float:
        """Seconds left (0.0 once expired, ``inf`` for no deadline)."""
        return max(0.0, self._end - time.monotonic())

    def expired(self) -> bool:
        return time.monotonic() >= self._end


class ListeningDeadline:
    """A timeout on a device's silence, counted only while the caller could listen.

    Time passes for it between two looks (:meth:`time_left`, :meth:`expired`) up to ``slice_s`` each: a
    caller that looks at least every ``slice_s`` while it waits counts every second, but a longer gap means
    the process did not run (a busy or paused host; the device's replies are then not read, and a simulated
    device in the same process does not run either), and only ``slice_s`` of it counts.

    Parameters
    ----------
    timeout_s : float
        Seconds of silence allowed.
    slice_s : float
        The longest the caller blocks between two looks when it runs (> 0).
    now : callable, optional
        The clock (default ``time.monotonic``).
    host_delay : callable, optional
        Seconds (cumulative, non-decreasing) that the party who talks to the device on the caller's behalf
        (a helper process) spent ready to run but not run by this host: between two looks, that much does
        not count either (:func:`run_queue_delay_s`).
    """

    __slots__ = ("_left", "_slice", "_now", "_last", "_host_delay", "_last_delay")

    def __init__(self, timeout_s: float, slice_s: float, *, now=time.monotonic, host_delay=None) -> None:
        if not (isinstance(timeout_s, (int, float)) and timeout_s >= 0):
            raise ConfigError(f"timeout_s must be >= 0, got {timeout_s!r}")
        if not (isinstance(slice_s, (int, float)) and slice_s > 0):
            raise ConfigError(f"slice_s must be > 0, got {slice_s!r}")
        self._left, self._slice, self._now = float(timeout_s), float(slice_s), now
        self._host_delay = host_delay
        self._last_delay = host_delay() if host_delay is not None else 0.0
        self._last = now()

    def time_left(self) -> float:
        """Seconds of listening left (0.0 once expired)."""
        t = self._now()
        counted = min(t - self._last, self._slice)
        if self._host_delay is not None:
            delay = self._host_delay()
            counted = max(0.0, counted - max(0.0, delay - self._last_delay))
            self._last_delay = max(delay, self._last_delay)
        self._left -= counted
        self._last = t
        return max(0.0, self._left)

    def expired(self) -> bool:
        return self.time_left() <= 0.0

    def count_gap(self, seconds: float) -> None:
        """A look at which the time since the previous look counts as ``seconds``, however long it was: 0.0
        for the caller's own work (not listening), or the whole of a call that timed out on its own clock
        (the device was silent for it, e.g. a TCP connect)."""
        self._left -= max(0.0, float(seconds))
        self._last = self._now()
        if self._host_delay is not None:
            self._last_delay = max(self._host_delay(), self._last_delay)


def run_queue_delay_s(pid: int) -> float:
    """Seconds process ``pid``'s main thread has spent ready to run while this host ran others (Linux
    ``/proc/PID/schedstat``, its second field); 0.0 where the kernel does not say (the time then counts)."""
    try:
        with open(f"/proc/{int(pid)}/schedstat", "rb") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return 0.0


@runtime_checkable
class Transport(Protocol):
    """A bidirectional byte pipe with timeouts on every call."""

    description: str

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        """Return 1..max_bytes bytes, or ``b""`` if none arrived within ``timeout_s``.

        Raises ConnectionLost when the link is down.
        """

    def write(self, data: bytes, timeout_s: float) -> None:
        """Write all of ``data`` within ``timeout_s`` (DeviceTimeout otherwise)."""

    def close(self) -> None:
        """Release the link; idempotent."""

    @property
    def closed(self) -> bool: ...


TransportFactory = Callable[[], Transport]


def check_positive(**values: float) -> None:
    """ConfigError naming the first value that is not a finite number > 0."""
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ConfigError(f"{name} must be a finite number > 0, got {value!r}")


def transport_or_factory(transport) -> tuple[TransportFactory | None, Transport | None]:
    """``(factory, None)`` for a factory (the driver can reconnect), ``(None, transport)`` for an open one."""
    if isinstance(transport, Transport):
        return None, transport
    if callable(transport):
        return transport, None
    raise ConfigError(f"transport must be a Transport or a factory, got {type(transport).__name__}")


class TcpTransport:
    """A TCP client socket.

    Parameters
    ----------
    host, port : str, int
        Peer address.
    connect_timeout_s : float
        Time allowed for the TCP handshake.
    sock : socket.socket, optional
        An already connected socket to wrap instead (``host``/``port`` then
        only describe it).
    """

    def __init__(self, host: str, port: int, *, connect_timeout_s: float = 5.0,
                 sock: socket.socket | None = None) -> None:
        if not isinstance(port, int) or not 0 < port < 65536:
            raise ConfigError(f"port must be an integer in 1..65535, got {port!r}")
        self.description = f"tcp://{host}:{port}"
        if sock is None:
            try:
                sock = socket.create_connection((host, port), timeout=connect_timeout_s)
            except socket.timeout as exc:
                raise DeviceTimeout(f"connecting to {self.description} took longer than "
                                    f"{connect_timeout_s} s") from exc
            except OSError as exc:
                raise ConnectionLost(f"cannot connect to {self.description}: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        if self._closed:
            raise ConnectionLost(f"{self.description} is closed")
        try:
            ready, _, _ = select.select([self._sock], [], [], max(0.0, timeout_s))
            if not ready:
                return b""
            data = self._sock.recv(max_bytes)
        except (OSError, ValueError) as exc:
            raise ConnectionLost(f"reading from {self.description} failed: {exc}") from exc
        if not data:
            raise ConnectionLost(f"{self.description} closed by the peer")
        return data

    def write(self, data: bytes, timeout_s: float) -> None:
        if self._closed:
            raise ConnectionLost(f"{self.description} is closed")
        view = memoryview(data)
        deadline = Deadline(timeout_s)
        try:
            while view:
                left = deadline.time_left()
                _, ready, _ = select.select([], [self._sock], [], left)
                if not ready:
                    raise DeviceTimeout(f"writing {len(data)} bytes to {self.description} "
                                        f"took longer than {timeout_s} s")
                sent = self._sock.send(view)
                view = view[sent:]
        except DeviceTimeout:
            raise
        except (OSError, ValueError) as exc:
            raise ConnectionLost(f"writing to {self.description} failed: {exc}") from exc

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()


class SerialTransport:
    """A pyserial port: a device path (``/dev/ttyUSB0``, a pty slave) or a
    pyserial URL (``socket://127.0.0.1:4001``, ``loop://``).

    Parameters
    ----------
    port : str or serial.SerialBase
        Path, URL, or an already opened pyserial object.
    baudrate : int
        Line speed (ignored by ptys and sockets).
    """

    def __init__(self, port, *, baudrate: int = 9600) -> None:
        import serial  # local: only serial users pay for the import

        self._serial_exc = serial.SerialException
        try:  # a terminal, written through its descriptor (not a pyserial URL's socket or loop)
            from serial.serialposix import Serial as posix_serial
        except ImportError:
            posix_serial = ()
        self._posix_serial = posix_serial
        #: the line speed asked for, baud
        self.baudrate = baudrate
        if isinstance(port, str):
            if not isinstance(baudrate, int) or baudrate <= 0:
                raise ConfigError(f"baudrate must be a positive integer, got {baudrate!r}")
            try:
                if "://" in port:
                    self._port = serial.serial_for_url(port, baudrate=baudrate, timeout=0)
                else:
                    self._port = serial.Serial(port, baudrate=baudrate, timeout=0)
            except (serial.SerialException, OSError, ValueError) as exc:
                raise ConnectionLost(f"cannot open serial port {port!r}: {exc}") from exc
            self.description = port
        else:
            self._port = port
            self.description = str(getattr(port, "port", port))
        self._timeout: float | None = None
        self._write_timeout: float | None = None
        self._closed = False

    @property
    def closed(self) -> bool:
        return self._closed

    def _set_timeout(self, timeout_s: float) -> None:
        if self._timeout != timeout_s:  # pyserial reconfigures the port on every set
            self._port.timeout = timeout_s
            self._timeout = timeout_s

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        if self._closed:
            raise ConnectionLost(f"{self.description} is closed")
        try:
            waiting = self._port.in_waiting
            if waiting:
                self._set_timeout(0)
                return self._port.read(min(waiting, max_bytes))
            self._set_timeout(max(0.0, timeout_s))
            first = self._port.read(1)
            if not first:
                return b""
            more = self._port.in_waiting
            if more and max_bytes > 1:
                self._set_timeout(0)
                first += self._port.read(min(more, max_bytes - 1))
            return first
        except (self._serial_exc, OSError, TypeError, AttributeError) as exc:
            raise ConnectionLost(f"reading from {self.description} failed: {exc}") from exc

    def write(self, data: bytes, timeout_s: float) -> None:
        if self._closed:
            raise ConnectionLost(f"{self.description} is closed")
        if isinstance(self._port, self._posix_serial):
            self._write_fd(data, max(0.001, timeout_s))
            return
        try:
            wt = max(0.001, timeout_s)
            if self._write_timeout != wt:  # pyserial reconfigures the port on every set
                self._port.write_timeout = wt
                self._write_timeout = wt
            self._port.write(data)
            self._drain(time.monotonic() + wt)
        except Exception as exc:  # pyserial raises SerialTimeoutException or OSError
            if type(exc).__name__ == "SerialTimeoutException":
                raise DeviceTimeout(f"writing {len(data)} bytes to {self.description} took "
                                    f"longer than {timeout_s} s") from exc
            raise ConnectionLost(f"writing to {self.description} failed: {exc}") from exc

    def _write_fd(self, data: bytes, timeout_s: float) -> None:
        """Write to a terminal (a device or a pty; pyserial opens it non-blocking): a timeout only when the
        line has not taken every byte by the deadline, after one more write past it. pyserial's own write
        timeout also fires when the bytes went out but this thread did not run for the timeout meanwhile (a
        busy host), which is no fault of the line."""
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        try:
            fd = self._port.fileno()
            while True:
                try:
                    view = view[os.write(fd, view):]
                except (BlockingIOError, InterruptedError):
                    pass
                if not view:
                    break
                left = deadline - time.monotonic()
                if left <= 0:  # a last write came after the deadline and the line still took nothing more
                    raise DeviceTimeout(f"writing {len(data)} bytes to {self.description} took "
                                        f"longer than {timeout_s} s ({len(view)} not taken)")
                select.select([], [fd], [], left)
            self._drain(deadline)
        except DeviceTimeout:
            raise
        except Exception as exc:  # OSError, termios.error, a port pyserial closed (fileno raises)
            raise ConnectionLost(f"writing to {self.description} failed: {exc}") from exc

    def _drain(self, deadline: float) -> None:
        """Wait until the written bytes have left (``tcdrain``), again when a signal interrupts the wait:
        the terminal call is not restarted by Python (a Ctrl-Z, a window resize or a child's exit would
        otherwise end the link)."""
        while True:
            try:
                self._port.flush()
                return
            except Exception as exc:  # termios.error (errno, text), or OSError
                code = getattr(exc, "errno", None) or (exc.args[0] if exc.args else None)
                if code != errno.EINTR or time.monotonic() > deadline:
                    raise

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._port.close()
        except Exception:
            pass


class LineReader:
    """Reads terminated lines from a transport, never buffering more than
    ``max_line_bytes`` of one line.

    Parameters
    ----------
    transport : Transport
    terminator : bytes
        Line end (``b"\\n"``; a preceding ``\\r`` is stripped too).
    max_line_bytes : int
        A line longer than this raises ProtocolError and its bytes are dropped
        up to the next terminator.
    """

    def __init__(self, transport: Transport, *, terminator: bytes = b"\n",
                 max_line_bytes: int = 4096) -> None:
        self.transport = transport
        self._term = terminator
        self._max = int(max_line_bytes)
        self._buf = bytearray()
        self._discarding = False
        #: bytes dropped because a line overflowed
        self.overflow_bytes = 0

    def clear(self) -> None:
        self._buf.clear()
        self._discarding = False

    def read_line(self, timeout_s: float, slice_s: float | None = None) -> bytes:
        """Next line without its terminator; DeviceTimeout if none in time. With ``slice_s`` the time is the
        device's silence (:class:`ListeningDeadline`, looking at least every ``slice_s``): a host that did not
        run is not a device that did not answer."""
        deadline = Deadline(timeout_s) if slice_s is None else ListeningDeadline(timeout_s, slice_s)
        looked = False
        while True:
            idx = self._buf.find(self._term)
            if idx >= 0:
                line = bytes(self._buf[:idx])
                del self._buf[: idx + len(self._term)]
                if self._discarding or len(line) > self._max:
                    self._discarding = False
                    self.overflow_bytes += len(line)
                    raise ProtocolError(f"line longer than {self._max} bytes on "
                                        f"{self.transport.description}; dropped")
                return line[:-1] if line.endswith(b"\r") else line
            if len(self._buf) > self._max:
                self.overflow_bytes += len(self._buf)
                self._buf.clear()
                self._discarding = True
            left = deadline.time_left()
            if left <= 0:
                if not looked:
                    # once more, without waiting: what came while this thread did not run (a busy host) is
                    # no silence of the device
                    looked = True
                    self._buf += self.transport.read(4096, 0.0)
                    continue
                raise DeviceTimeout(f"no complete line from {self.transport.description} "
                                    f"within {timeout_s} s")
            self._buf += self.transport.read(4096, left if slice_s is None else min(left, slice_s))


def tcp_factory(host: str, port: int, *, connect_timeout_s: float = 5.0) -> TransportFactory:
    """A factory that opens a new :class:`TcpTransport` on each call (reconnection)."""
    return lambda: TcpTransport(host, port, connect_timeout_s=connect_timeout_s)


def serial_factory(port: str, *, baudrate: int = 9600) -> TransportFactory:
    """A factory that (re)opens a :class:`SerialTransport` on each call."""
    return lambda: SerialTransport(port, baudrate=baudrate)


__all__ = [
    "Deadline", "ListeningDeadline", "run_queue_delay_s", "Transport", "TransportFactory", "TcpTransport",
    "SerialTransport", "LineReader", "tcp_factory", "serial_factory",
]
