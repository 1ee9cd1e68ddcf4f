"""Transports: timeouts on the monotonic clock, dropped links, bounded lines, URLs."""

from __future__ import annotations

import os
import pty
import socket
import time
import tty

import pytest

from drivers.transport import Deadline, LineReader, ListeningDeadline, SerialTransport, TcpTransport
from station.errors import ConfigError, ConnectionLost, DeviceTimeout, ProtocolError


@pytest.fixture
def server():
    lsock = socket.socket()
    lsock.bind(("127.0.0.1", 0))
    lsock.listen(1)
    yield lsock
    lsock.close()


def test_tcp_read_times_out_then_sees_the_peer_close(server):
    t = TcpTransport("127.0.0.1", server.getsockname()[1], connect_timeout_s=2.0)
    peer, _ = server.accept()
    start = time.monotonic()
    assert t.read(100, 0.05) == b""
    assert 0.04 <= time.monotonic() - start < 1.0
    peer.sendall(b"abc")
    assert t.read(100, 1.0) == b"abc"
    peer.close()
    with pytest.raises(ConnectionLost, match="closed by the peer"):
        t.read(100, 1.0)
    t.close()
    with pytest.raises(ConnectionLost, match="is closed"):
        t.write(b"x", 1.0)


def test_tcp_connect_refused_is_connection_lost(server):
    port = server.getsockname()[1]
    server.close()
    with pytest.raises(ConnectionLost, match="cannot connect"):
        TcpTransport("127.0.0.1", port, connect_timeout_s=1.0)


def test_line_reader_bounds_lines_and_times_out():
    master, slave = pty.openpty()
    tty.setraw(slave)
    port = SerialTransport(os.ttyname(slave))
    try:
        lines = LineReader(port, max_line_bytes=64)
        os.write(master, b"first\r\n" + b"y" * 200 + b"\r\nsecond\n")
        assert lines.read_line(1.0) == b"first"
        with pytest.raises(ProtocolError, match="longer than 64 bytes"):
            lines.read_line(1.0)
        assert lines.read_line(1.0) == b"second"
        assert lines.overflow_bytes >= 200
        with pytest.raises(DeviceTimeout, match="within 0.05 s"):
            lines.read_line(0.05)
        os.close(master)
        with pytest.raises(ConnectionLost):
            port.read(10, 0.5)
    finally:
        port.close()
        os.close(slave)


def test_a_line_that_came_while_the_reader_did_not_run_is_read_at_its_deadline():
    """A busy host may not run the reading thread until its deadline has passed; the reply that came
    meanwhile is read (once, without waiting) before a timeout is reported."""
    master, slave = pty.openpty()
    tty.setraw(slave)
    port = SerialTransport(os.ttyname(slave))
    try:
        lines = LineReader(port)
        os.write(master, b"%R1P,0,0:0\r\n")
        time.sleep(0.05)  # on the line before the reader looks
        assert lines.read_line(0.0) == b"%R1P,0,0:0"  # a deadline that has passed already
        with pytest.raises(DeviceTimeout):
            lines.read_line(0.0)  # nothing there: the timeout stands
    finally:
        port.close()
        os.close(master)
        os.close(slave)


def test_a_listening_deadline_counts_a_gap_between_looks_only_up_to_its_slice(rng):
    """Time counts as it passes while the caller looks often; of a gap longer than the slice (the process
    did not run) only the slice counts."""
    t = [float(rng.uniform(0, 1e4))]
    slice_s = float(rng.uniform(0.2, 0.5))
    steps = rng.uniform(0.0, slice_s, 5)
    timeout = float(steps.sum() + rng.uniform(1.0, 3.0))  # still time left after the looks below
    d = ListeningDeadline(timeout, slice_s, now=lambda: t[0])
    for k, dt in enumerate(steps):  # looked at often: every second counts
        t[0] += float(dt)
        assert d.time_left() == pytest.approx(timeout - steps[:k + 1].sum())
    left = d.time_left()
    t[0] += 10 * timeout  # the host did not run
    assert d.time_left() == pytest.approx(max(0.0, left - slice_s))
    while not d.expired():
        t[0] += slice_s / 2
    assert d.time_left() == 0.0
    with pytest.raises(ConfigError):
        ListeningDeadline(1.0, 0.0)


def test_tracker_urls_open_the_driver_their_scheme_names():
    from drivers.emscon import EmsconTracker
    from drivers.geocom import GeoComTracker
    from drivers.tracker_url import tracker_class

    assert tracker_class("emscon://10.0.0.5") is EmsconTracker
    assert tracker_class("geocom:///dev/ttyUSB0?baud=115200") is GeoComTracker
    assert tracker_class("geocom+socket://127.0.0.1:4001") is GeoComTracker
    for bad, why in [("ftp://x", "unknown scheme 'ftp'"), ("nothing", "scheme://"),
                     ("geocom:///dev/x?baud=fast", "baud"), ("geocom+socket://host", "needs a port"),
                     ("nmea:///dev/ttyS0", "expected a emscon or geocom or geocom\\+socket URL")]:
        with pytest.raises(ConfigError, match=why):
            tracker_class(bad)


def test_deadline():
    d = Deadline(0.0)
    assert d.expired() and d.time_left() == 0.0
    assert Deadline(None).time_left() == float("inf")
    with pytest.raises(ConfigError):
        Deadline(-1)


def test_serial_write_survives_signals_during_the_drain(rng):
    """``tcdrain`` is not restarted after a signal (termios raises EINTR); the transport waits again, and
    another failure of the line is still a lost connection."""
    import errno
    import termios

    import serial

    class Interrupted(serial.serial_for_url("loop://", timeout=0).__class__):
        interrupts = 0
        drains = 0

        def flush(self):
            self.drains += 1
            if self.interrupts:
                self.interrupts -= 1
                raise termios.error(errno.EINTR, "Interrupted system call")
            super().flush()

    port = Interrupted("loop://", timeout=0)
    n = port.interrupts = int(rng.integers(1, 6))
    link = SerialTransport(port)
    link.write(b"$PODOC,0.1*00\r\n", 1.0)
    assert port.drains == n + 1
    assert link.read(64, 0.5) == b"$PODOC,0.1*00\r\n"

    class Broken(Interrupted):
        def flush(self):
            raise termios.error(errno.EIO, "Input/output error")

    with pytest.raises(ConnectionLost, match="Input/output error"):
        SerialTransport(Broken("loop://", timeout=0)).write(b"x\r\n", 1.0)


def test_a_serial_write_whose_bytes_went_out_is_no_timeout_however_late_the_thread_ran(rng, monkeypatch):
    """The host's clock jumps by more than the write timeout between any two looks (a thread that did not
    run): a frame the terminal took is written, not a timeout (pyserial's write timeout fires then, after
    writing); a line that takes nothing more is still a timeout, after one more write past its deadline."""
    import serial.serialutil

    master, slave = pty.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    port = SerialTransport(os.ttyname(slave))
    timeout = float(rng.uniform(0.05, 0.5))
    t = [time.monotonic()]

    def away() -> float:
        t[0] += 3 * timeout
        return t[0]

    try:
        frame = b"$PODOS,1a2b," + b"%.3f" % rng.uniform(0, 100) + b"*00\r\n"
        monkeypatch.setattr(time, "monotonic", away)
        monkeypatch.setattr(serial.serialutil.Timeout, "TIME", staticmethod(away))  # pyserial's own look at the clock
        for _ in range(int(rng.integers(3, 8))):
            port.write(frame, timeout)
        monkeypatch.undo()
        got = b""
        while len(got) < 3 * len(frame):
            got += os.read(master, 4096)
        assert got.startswith(frame * 3)
        with pytest.raises(DeviceTimeout, match=rf"longer than {timeout} s \(\d+ not taken\)"):
            for _ in range(100_000):  # nobody reads: the terminal's buffer fills
                port.write(frame, timeout)
    finally:
        monkeypatch.undo()
        port.close()
        os.close(master)
        os.close(slave)


def test_a_helpers_wait_for_the_host_does_not_count_as_the_devices_silence(rng):
    """``host_delay``: time the process that talks to the device spent ready to run but not run (its run
    queue wait) is the host's, not the device's. Looks every 0.1 s over drawn waits: the deadline expires
    once the waits less the helper's queueing add up to the timeout, not before."""
    t, delay = [0.0], [0.0]
    d = ListeningDeadline(2.0, 0.1, now=lambda: t[0], host_delay=lambda: delay[0])
    counted = 0.0
    while True:
        step = float(rng.uniform(0.0, 0.1))
        queued = float(rng.uniform(0.0, step))
        t[0] += step
        delay[0] += queued
        counted += step - queued
        if d.expired():
            break
        assert counted < 2.0 + 1e-9
    assert counted >= 2.0 - 1e-9


def test_a_gap_counted_as_given_counts_that_and_the_looks_go_on_from_it(rng):
    """``count_gap``: the time since the last look counts as told (0 for the caller's own work, the whole of a
    call that timed out on its own clock), however long it was; later looks count from it as before."""
    t = [0.0]
    timeout = float(rng.uniform(1.0, 2.0))
    d = ListeningDeadline(timeout, 0.1, now=lambda: t[0])
    t[0] += 50.0
    d.count_gap(0.0)  # the caller's own work: nothing counted
    assert d.time_left() == pytest.approx(timeout)
    told = float(rng.uniform(0.2, 0.8)) * timeout
    t[0] += 0.01
    d.count_gap(told)  # a connect that timed out after `told`: all of it, not the slice
    assert d.time_left() == pytest.approx(timeout - told)
    t[0] += 0.05
    assert d.time_left() == pytest.approx(timeout - told - 0.05)
    t[0] += 10.0
    assert d.time_left() == pytest.approx(max(0.0, timeout - told - 0.15))
