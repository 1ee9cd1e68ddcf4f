"""GeoCOM: codec, the driver against the pty fake with every fault, and geocompy as judge."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.geocom import GeoComTracker
from drivers.geocom_codec import GeoComReply, MeasureProgram, encode_request, geocom_error, parse_reply, split_values
from drivers.tracker import BeamBroken, EventKind
from drivers.tracker_url import open_tracker
from drivers.transport import LineReader, SerialTransport, serial_factory
from fakes.geocom import start_fake
from station.errors import (ConfigError, DeviceError, DeviceFault, DeviceNotReady, DeviceTimeout,
                            ProtocolError)

from tests.host_pause import pause_host

from .conftest import CircleWorld


# -- codec ------------------------------------------------------------------------------

def test_request_bytes():
    assert encode_request(0, 0) == b"%R1Q,0,0:\r\n"
    assert encode_request(2008, 7, (1, 1)) == b"%R1Q,2008,7:1,1\r\n"
    assert encode_request(2082, 12, (5000, 1)) == b"%R1Q,2082,12:5000,1\r\n"
    assert encode_request(9, 1, (0.25, "AT", True)) == b'%R1Q,9,1:0.25,"AT",1\r\n'
    with pytest.raises(ConfigError):
        encode_request(1, 2**15)
    with pytest.raises(ConfigError):
        encode_request(1, 1, (float("nan"),))


def test_reply_parsing():
    assert parse_reply(b"%R1P,0,7:0") == GeoComReply(0, 7, 0, ())
    assert parse_reply(b"%R1P,0,3:0,1.5,-2,100") == GeoComReply(0, 3, 0, ("1.5", "-2", "100"))
    assert parse_reply(b'%R1P,0,4:0,"TS,16"') == GeoComReply(0, 4, 0, ('"TS,16"',))
    assert parse_reply(b"%R1P,0,5,1234:1292,0.0") == GeoComReply(0, 5, 1292, ("0.0",))  # with CRC field
    for bad in (b"", b"%R1Q,0,0:", b"%R1P,0:0", b"R1P,0,1:0", b"%R1P,x,1:0"):
        with pytest.raises(ProtocolError, match="not a GeoCOM reply"):
            parse_reply(bad)
    with pytest.raises(ProtocolError, match="unterminated string"):
        split_values('"abc,1')


@pytest.mark.parametrize("rc, cls, text", [
    (1292, BeamBroken, "TMC_DIST_ERROR"), (1285, BeamBroken, "TMC_ANGLE_OK"),
    (1293, DeviceNotReady, "TMC_BUSY"), (13, DeviceNotReady, "SYSBUSY"),
    (4, DeviceFault, "FATAL"), (6, DeviceTimeout, "TIME_OUT"), (5, DeviceError, "does not implement"),
    (2, DeviceError, "invalid parameter"), (4242, DeviceError, "rc 4242"),
])
def test_return_codes_map_to_clear_errors(rc, cls, text):
    err = geocom_error(2082, rc)
    assert isinstance(err, cls) and text in str(err) and "rpc 2082" in str(err)


# -- driver against the fake on a pty ------------------------------------------------------

@pytest.fixture
def rig():
    made = []

    def make(faults=None, world=None, connect=True, **options):
        world = world or CircleWorld()
        fake = start_fake(world, faults=faults)
        options.setdefault("reply_timeout_s", 0.5)
        tracker = GeoComTracker(serial_factory(fake.endpoint["device"]), **options)
        made.append((world, fake, tracker))
        if connect:
            tracker.connect(timeout_s=5)
        return world, fake, tracker

    yield make
    for world, fake, tracker in made:
        tracker.close()
        fake.close()


def _stream(tracker, real_s: float, rate_hz: float = 200.0, min_samples: int = 0):
    """Stream for ``real_s`` s, and on until ``min_samples`` samples came (a loaded machine polls fewer a second;
    at most 60 s more)."""
    tracker.start_stream(rate_hz)
    ts, xs, events = [], [], []
    end = time.monotonic() + real_s
    late = end + 60.0
    got = 0
    while time.monotonic() < end or (got < min_samples and time.monotonic() < late):
        b = tracker.read_samples(0.05)
        ts.append(b.t_s), xs.append(b.xyz_mm), events.extend(b.events)
        got += len(b.t_s)
    record = tracker.stop_stream()
    b = tracker.read_samples(0.0)
    ts.append(b.t_s), xs.append(b.xyz_mm), events.extend(b.events)
    return np.concatenate(ts), np.concatenate(xs), events, record


def test_connect_and_stationary_point_equal_the_truth(rig):
    world, fake, tracker = rig(connect=False)
    info = tracker.connect(timeout_s=5)
    assert (info.name, info.serial_number, info.firmware) == ("AT960", "424242", "7.0.0")
    m = tracker.measure_stationary()
    np.testing.assert_allclose(m.xyz_mm, world.source.truth([m.t_device_s])[0], rtol=0, atol=1e-9)
    assert m.t_device_s * 1000 == pytest.approx(round(m.t_device_s * 1000))


def test_polled_stream_is_exact(rig):
    world, fake, tracker = rig()
    t, xyz, events, record = _stream(tracker, 0.4, min_samples=20)
    assert record.received >= 20 and record.received == len(t)
    assert record.lost == record.rejected == record.not_measured == 0
    assert np.all(np.diff(t) > 0) and events == []
    np.testing.assert_allclose(xyz, world.source.truth(t), rtol=0, atol=1e-9)


def test_beam_break_raises_and_is_an_event_in_a_stream(rig):
    world, fake, tracker = rig(faults={"beam_break": "0:8"})
    with pytest.raises(BeamBroken, match="1292"):
        tracker.measure_stationary()
    t, xyz, events, record = _stream(tracker, 0.8)  # world runs 20x: the break ends after 0.4 s
    kinds = [e.kind for e in events]
    assert kinds[:2] == [EventKind.BEAM_BROKEN, EventKind.TARGET_REACQUIRED]
    assert record.not_measured >= 1 and record.received >= 1
    assert t[0] >= fake.stats["anchor_t"] + 8.0 - 1e-3
    np.testing.assert_allclose(xyz, world.source.truth(t), rtol=0, atol=1e-9)


def test_garbage_is_skipped_and_counted(rig):
    world, fake, tracker = rig(faults={"garbage": "2", "seed": "3"})
    t, xyz, events, record = _stream(tracker, 0.4, min_samples=20)
    assert record.received >= 20
    counted = record.garbage_bytes + tracker.link_record().garbage_bytes
    assert 0 < counted <= fake.stats["garbage_bytes"]
    np.testing.assert_allclose(xyz, world.source.truth(t), rtol=0, atol=1e-9)


def test_truncated_replies_are_rejected_or_lost_never_wrong(rig):
    world, fake, tracker = rig(faults={"truncate": "3", "seed": "5"}, reply_timeout_s=0.1)
    t, xyz, events, record = _stream(tracker, 0.6, min_samples=10)
    assert record.received >= 10
    assert record.rejected + record.lost >= 1
    assert record.rejected + record.lost <= fake.stats["truncated"]
    np.testing.assert_allclose(xyz, world.source.truth(t), rtol=0, atol=1e-9)


@pytest.mark.parametrize("silent", [False, True])
def test_a_host_that_did_not_run_during_connect_is_no_silence_of_the_instrument(monkeypatch, rng, silent):
    """This host is stopped for 1.5-2.5 times the connect's timeout while the line opens: an instrument that
    answers is connected (counting the host's wall time, connect gave its first request 0 s and failed);
    a silent one still times out naming the request, after the pause and a reply's time of listening."""
    from fakes import geocom as fake_geocom

    if silent:
        monkeypatch.setattr(fake_geocom.GeoComFake, "_line", lambda fake, line: None)
    reply_timeout_s = float(rng.uniform(0.2, 0.4))
    timeout_s = float(rng.uniform(2.0, 3.0)) * reply_timeout_s
    pause_s = float(rng.uniform(1.5, 2.5)) * timeout_s
    world = CircleWorld()
    paused = []
    with start_fake(world) as fake:
        opener = serial_factory(fake.endpoint["device"])

        def factory():
            if not paused:
                paused.append(pause_s)
                pause_host(pause_s)
            return opener()

        tracker = GeoComTracker(factory, reply_timeout_s=reply_timeout_s)
        try:
            started = time.monotonic()
            if silent:
                # the wait named is the reply timeout or, when less is left of connect's budget, what was left
                # (CI seed 2373777377: 0.324476 of 0.324531 s)
                with pytest.raises(DeviceTimeout, match=r"no reply to GeoCOM rpc 0 within [0-9.]+ s"):
                    tracker.connect(timeout_s=timeout_s)
                assert time.monotonic() - started >= pause_s + reply_timeout_s
            else:
                assert tracker.connect(timeout_s=timeout_s).name == "AT960"
                m = tracker.measure_stationary()
                np.testing.assert_allclose(m.xyz_mm, world.source.truth([m.t_device_s])[0], rtol=0, atol=1e-9)
            assert paused == [pause_s]
        finally:
            tracker.close()


def test_an_idempotent_request_whose_reply_is_lost_is_sent_again_within_its_deadline(rig):
    """Every 2nd reply loses its tail: queries and the state-setting measure programs still get their answer."""
    world, fake, tracker = rig(faults={"truncate": "2", "seed": "7"}, reply_timeout_s=0.2)
    before, replies, retries = fake.stats["truncated"], fake.stats["replies"], tracker.retries
    for _ in range(6):
        assert tracker.request(5004) == ('"AT960"',)
        assert tracker.request(2008, (MeasureProgram.TRACK, 1), timeout_s=2.0) == ()
        assert tracker.request(2008, (MeasureProgram.STOP, 1), timeout_s=2.0) == ()
    lost = fake.stats["truncated"] - before
    # each cut reply cost one more request (a reply later than 0.2 s on a loaded machine costs one too)
    assert lost >= 6 and tracker.retries - retries >= lost
    assert fake.stats["replies"] - replies == 18 + tracker.retries - retries


def test_a_request_that_is_not_idempotent_is_sent_once(rig):
    world, fake, tracker = rig(faults={"truncate": "2", "seed": "7"}, reply_timeout_s=0.05)
    if fake.stats["replies"] % 2 == 0:  # the next reply is whole: use it up
        tracker.request(0, retry=False)
    replies, retries = fake.stats["replies"], tracker.retries
    with pytest.raises(DeviceTimeout, match=r"rpc 2008 within 0.3 s$"):
        tracker.request(2008, (MeasureProgram.DISTANCE, 1), timeout_s=0.3)  # its reply is cut: not asked again
    assert fake.stats["replies"] - replies == 1 and fake.stats["truncated"] >= 1 and tracker.retries == retries


def test_slow_reply_times_out_then_stale_reply_is_skipped(rig):
    world, fake, tracker = rig(faults={"slow_reply_s": "2.0"}, reply_timeout_s=1.0)  # 0.1 s real
    with pytest.raises(DeviceTimeout, match="rpc 0 within 0.02"):
        tracker.request(0, timeout_s=0.02)
    values = tracker.request(5004)  # the late NullProc reply arrives first and is skipped by trid
    assert values == ('"AT960"',)


def test_not_ready_instrument(rig):
    world, fake, tracker = rig(faults={"not_ready": "always"})
    with pytest.raises(DeviceNotReady, match="TMC_BUSY"):
        tracker.measure_stationary()


def test_dead_line_is_revived_with_backoff(rig):
    world, fake, tracker = rig(faults={"drop_connection": "0.5:4"}, reply_timeout_s=0.05,
                               backoff_initial_s=0.02)
    t, xyz, events, record = _stream(tracker, 0.8)
    kinds = [e.kind for e in events]
    assert kinds == [EventKind.CONNECTION_LOST, EventKind.RECONNECTED]
    assert record.lost >= 2 and fake.stats["dropped_requests"] >= 2
    assert t[-1] > fake.stats["anchor_t"] + 4.5
    np.testing.assert_allclose(xyz, world.source.truth(t), rtol=0, atol=1e-9)


def test_bad_requests_get_clear_errors(rig):
    world, fake, tracker = rig()
    with pytest.raises(DeviceError, match="rpc 9999 failed with rc 5 .*does not implement"):
        tracker.request(9999)
    with pytest.raises(DeviceError, match="rpc 2082 failed with rc 2 .*invalid parameter"):
        tracker.request(2082, (1,))
    with pytest.raises(ConfigError):
        tracker.set_units("ft")


def test_fake_answers_a_malformed_request_with_a_com_error(world):
    with start_fake(world) as fake:
        port = SerialTransport(fake.endpoint["device"])
        lines = LineReader(port)
        port.write(b"%R1Q,12,3:\r\n", 1.0)
        assert parse_reply(lines.read_line(1.0)) == GeoComReply(0, 3, 5, ())
        port.write(b"%R1Q,2008,4;1,1\r\n", 1.0)  # ';' instead of ':'
        assert parse_reply(lines.read_line(1.0)).com_rc == 3078
        port.write(b"x" * 5000 + b"\r\n%R1Q,0,5:\r\n", 1.0)  # an overlong line is dropped
        assert parse_reply(lines.read_line(1.0)) == GeoComReply(0, 5, 0, ())
        port.close()
        assert fake.stats["malformed"] == 2
    with pytest.raises(ConfigError, match="pty"):
        start_fake(world, host="127.0.0.1")


def test_open_tracker_by_url(world):
    with start_fake(world) as fake, open_tracker(f"geocom://{fake.endpoint['device']}?baud=115200") as tracker:
        assert isinstance(tracker, GeoComTracker)
        tracker.connect(timeout_s=5)
        m = tracker.measure_stationary()
        np.testing.assert_allclose(m.xyz_mm, world.source.truth([m.t_device_s])[0], rtol=0, atol=1e-9)


# -- the third-party client judges the fake --------------------------------------------------

def test_geocompy_measures_through_the_fake(world):
    from geocompy.communication import open_serial
    from geocompy.geo import GeoCom
    from geocompy.geo.gctypes import GeoComCode

    with start_fake(world) as fake:
        with open_serial(fake.endpoint["device"], timeout=5) as line:
            tps = GeoCom(line)  # NullProc, precision, name, serial, versions
            assert tps.precision == 15
            assert tps.csv.get_instrument_name().params == "AT960"
            assert tps.tmc.do_measurement().error == GeoComCode.OK
            resp = tps.tmc.get_coordinate()
            assert resp.error == GeoComCode.OK
            coord, t_ms, cont, t_cont_ms = resp.params
            truth_m = world.source.truth([t_ms / 1000.0])[0] / 1000.0
            np.testing.assert_allclose([coord.x, coord.y, coord.z], truth_m, rtol=0, atol=1e-12)
            assert t_cont_ms >= t_ms
            hz, v, dist = tps.tmc.get_simple_measurement().params
            assert dist == pytest.approx(np.linalg.norm(truth_m), abs=1e-12)
            assert float(v) == pytest.approx(np.arctan2(np.hypot(*truth_m[:2]), truth_m[2]), abs=1e-12)
            assert float(hz) == pytest.approx(np.arctan2(truth_m[0], truth_m[1]) % (2 * np.pi), abs=1e-12)
            assert tps.request(9999).error == GeoComCode.NOT_IMPL
        assert fake.stats["malformed"] == 0


def test_a_time_field_of_hundreds_of_digits_is_a_protocol_error():
    """Issue reproducer: a 309-digit time raised OverflowError, which killed the polling thread."""
    with pytest.raises(ProtocolError, match="32-bit"):
        GeoComTracker._coordinate(("0.1", "0.2", "0.3", "9" * 309, "0", "0", "0", "0"))
    with pytest.raises(ProtocolError, match="32-bit"):
        GeoComTracker._coordinate(("0.1", "0.2", "0.3", str(2**40)))


def test_an_exception_in_the_polling_thread_is_an_event_and_an_error(rig):
    world, fake, tracker = rig()
    calls = [0]
    real = GeoComTracker._coordinate

    def broken(values):
        calls[0] += 1
        if calls[0] > 3:
            raise RuntimeError("injected fault in the poller")
        return real(values)

    tracker._coordinate = broken
    tracker.start_stream(100.0)
    with pytest.raises(DeviceError, match="injected fault"):
        for _ in range(100):
            tracker.read_samples(0.1)
    record = tracker.stop_stream()
    assert record.received >= 3 and record.error is not None and "RuntimeError" in record.error
    assert any(e.kind is EventKind.DEVICE_ERROR for e in record.events)


class _AwayAfterRequest(SerialTransport):
    """A busy host: once armed (``away_s``), right after a request has gone out the driver's thread does not
    run for ``away_s``."""

    away_s = 0.0

    def write(self, data: bytes, timeout_s: float) -> None:
        super().write(data, timeout_s)
        time.sleep(self.away_s)


def test_time_the_host_did_not_run_is_no_silence_of_the_instrument(rng):
    """The instrument (a script on the pty's other end) answers a little after the driver's host runs again,
    which took longer than the whole reply timeout: the driver still takes that reply. Counting every host
    second as the instrument's silence, it timed out (a stream's poll twice in a row on a busy machine, and
    the line was wrongly called dead and reopened)."""
    import os
    import pty
    import select
    import threading
    import tty

    master, slave = pty.openpty()
    tty.setraw(slave)
    tty.setraw(master)
    reply_timeout = float(rng.uniform(0.2, 0.4))
    late = {"s": 0.0}
    asked = []

    done = threading.Event()  # set before the pty is closed: the script stops looking at it first

    def lines():
        buf = b""
        while not done.is_set():
            if b"\n" not in buf:
                if select.select([master], [], [], 0.05)[0]:
                    buf += os.read(master, 4096)
                continue
            line, buf = buf.split(b"\n", 1)
            yield line.strip()

    def instrument() -> None:  # NullProc answered (late once armed), anything else "not implemented"
        for line in lines():
            if not line:
                continue
            rpc, trid = (int(x) for x in line[len(b"%R1Q,"):].split(b":")[0].split(b","))
            asked.append(rpc)
            time.sleep(late["s"] if rpc == 0 else 0.0)
            os.write(master, b"%%R1P,0,%d:%d\r\n" % (trid, 0 if rpc == 0 else 5))

    answering = threading.Thread(target=instrument)
    answering.start()
    link = _AwayAfterRequest(os.ttyname(slave), baudrate=115200)
    tracker = GeoComTracker(link, reply_timeout_s=reply_timeout)
    try:
        tracker.connect(timeout_s=5.0)
        link.away_s = 2 * reply_timeout
        late["s"] = link.away_s + float(rng.uniform(0.2, 0.4)) * reply_timeout  # the host runs again first
        n = len(asked)
        assert tracker.request(0, retry=False) == ()
        assert asked[n:] == [0]
    finally:
        tracker.close()
        done.set()
        answering.join(5.0)
        os.close(master)
        os.close(slave)
