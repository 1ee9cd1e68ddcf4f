"""The emScon driver byte for byte: scripted request/reply pairs, left-over pairs fail."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from drivers import emscon_codec as ec
from drivers.emscon import EmsconTracker
from drivers.tracker import EventKind
from station.errors import ConfigError, ConnectionLost, DeviceError, DeviceNotReady

from .helpers import ScriptedTransport


def hx(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


GET_STATUS = hx("0c000000 00000000 01000000")
STATUS_INITIALISED = hx("38000000 00000000 01000000 00000000 00000000 05000000 03000000 02000000"
                        "03000000 06000000 00000000 00000000 00000000 2a000000")
STATUS_NOT_INITIALISED = STATUS_INITIALISED.replace(hx("00000000 05000000 03000000"),
                                                    hx("00000000 04000000 03000000"))
SET_UNITS_MM = hx("20000000 00000000 05000000 01000000 00000000 00000000 00000000 00000000")
SET_UNITS_OK = hx("10000000 00000000 05000000 00000000")
SET_RHR = hx("10000000 00000000 1a000000 00000000")
SET_RHR_OK = hx("10000000 00000000 1a000000 00000000")
CONNECT = [(GET_STATUS, STATUS_INITIALISED), (GET_STATUS, STATUS_INITIALISED),
           (SET_UNITS_MM, SET_UNITS_OK), (SET_RHR, SET_RHR_OK)]


def _connected(pairs):
    transport = ScriptedTransport(CONNECT + pairs)
    tracker = EmsconTracker(transport, reply_timeout_s=1.0)
    info = tracker.connect(timeout_s=5)
    assert info.serial_number == "42" and info.firmware == "3.6.0"
    return transport, tracker


def test_connect_of_an_initialised_tracker():
    transport, tracker = _connected([])
    tracker.close()
    transport.assert_done()


def test_connect_initialises_when_needed():
    init = hx("0c000000 00000000 07000000")
    pairs = [(GET_STATUS, STATUS_NOT_INITIALISED), (init, hx("10000000 00000000 07000000 00000000")),
             (GET_STATUS, STATUS_INITIALISED), (GET_STATUS, STATUS_INITIALISED),
             (SET_UNITS_MM, SET_UNITS_OK), (SET_RHR, SET_RHR_OK)]
    transport = ScriptedTransport(pairs)
    tracker = EmsconTracker(transport, reply_timeout_s=1.0)
    tracker.connect(timeout_s=5)
    tracker.close()
    transport.assert_done()


def test_left_over_pairs_fail():
    transport, tracker = _connected([(GET_STATUS, STATUS_INITIALISED)])
    tracker.close()
    with pytest.raises(AssertionError, match="1 scripted pair"):
        transport.assert_done()


def test_stationary_measurement_exchange():
    single = struct.pack("<ii", 156, 2) + struct.pack("<iii", 0, 0, 0) + struct.pack(
        "<17d", 1.5, -2.25, 3.0, 0.01, 0.02, 0.03, 0.04, 0, 0, 0, 0, 0, 0, 0, 21.5, 1001.0, 40.0)
    pairs = [
        (hx("10000000 00000000 18000000 00000000"), hx("10000000 00000000 18000000 00000000")),
        (hx("14000000 00000000 1c000000 fa000000 00000000"), hx("10000000 00000000 1c000000 00000000")),
        (hx("0c000000 00000000 31000000"), hx("10000000 00000000 31000000 00000000") + single),
    ]
    transport, tracker = _connected(pairs)
    m = tracker.measure_stationary(duration_s=0.25)
    np.testing.assert_array_equal(m.xyz_mm, [1.5, -2.25, 3.0])
    np.testing.assert_array_equal(m.std_mm, [0.01, 0.02, 0.03])
    assert (m.temperature_c, m.pressure_mbar, m.humidity_pct) == (21.5, 1001.0, 40.0)
    tracker.close()
    transport.assert_done()


def test_stream_exchange_with_events_and_resync():
    samples = ec.MultiMeasResult.from_arrays(np.array([10_000, 11_000, 12_000]),
                                             [[1.0, 2.0, 3.0], [1.1, 2.1, 3.1], [1.2, 2.2, 3.2]])
    later = ec.MultiMeasResult.from_arrays(np.array([20_000]), [[9.0, 8.0, 7.0]])
    pairs = [
        (hx("10000000 00000000 18000000 01000000"), hx("10000000 00000000 18000000 00000000")),
        (hx("1c000000 00000000 1e000000 01000000 00000000 00000000 00000000"),
         hx("10000000 00000000 1e000000 00000000")),
        (hx("0c000000 00000000 31000000"),
         hx("10000000 00000000 31000000 00000000") + samples.encode() + b"\xde\xad\xbe"
         + hx("0c000000 08000000 19000000") + hx("0c000000 08000000 1b000000") + later.encode()),
        (hx("0c000000 00000000 34000000"), hx("10000000 00000000 34000000 00000000")),
    ]
    transport, tracker = _connected(pairs)
    tracker.start_stream(1000.0)
    got, events = [], []
    while sum(len(b) for b in got) < 4:
        batch = tracker.read_samples(1.0)
        got.append(batch)
        events.extend(batch.events)
    record = tracker.stop_stream()
    np.testing.assert_allclose(np.concatenate([b.t_s for b in got]), [0.010, 0.011, 0.012, 0.020])
    assert [e.kind for e in events] == [EventKind.BEAM_BROKEN, EventKind.TARGET_REACQUIRED]
    assert record.garbage_bytes == 3 and record.not_measured == 7 and record.lost == 0
    tracker.close()
    transport.assert_done()


def test_error_packet_and_status_map_to_clear_errors():
    pairs = [
        (hx("10000000 00000000 18000000 00000000"), hx("10000000 01000000 18000000 27000000")),
        (hx("10000000 00000000 18000000 00000000"), hx("10000000 00000000 18000000 03000000")),
    ]
    transport, tracker = _connected(pairs)
    with pytest.raises(DeviceNotReady, match=r"SET_MEASUREMENT_MODE \(24\) failed with status 39 "
                                             r"\(TrackerNotInitialized\)"):
        tracker.measure_stationary()
    with pytest.raises(DeviceError, match=r"status 3 \(WrongParameter\)"):
        tracker.measure_stationary()
    tracker.close()
    transport.assert_done()


def test_huge_length_before_a_reply_is_refused_and_the_reply_still_arrives():
    pairs = [(SET_UNITS_MM, struct.pack("<ii", 2**31 - 4, 3) + SET_UNITS_OK)]
    transport, tracker = _connected(pairs)
    tracker.set_units("mm")
    assert tracker.link_record().garbage_bytes == 8
    tracker.close()
    transport.assert_done()


def test_unsolicited_error_becomes_an_event():
    transport, tracker = _connected([])
    transport.push(hx("10000000 01000000 31000000 14270000"))
    (event,) = tracker.read_samples(2.0).events
    assert event.kind is EventKind.DEVICE_ERROR and "10004 (MeasurementStatusNotReady)" in event.detail
    tracker.close()


def test_link_drop_without_factory_fails_clearly():
    transport, tracker = _connected([])
    transport.close()
    (event,) = tracker.read_samples(2.0).events
    assert event.kind is EventKind.CONNECTION_LOST
    with pytest.raises(ConnectionLost, match="no transport factory"):
        tracker.set_units("mm")
    with pytest.raises(ConnectionLost, match="no transport factory"):
        tracker.read_samples(0.1)
    tracker.close()


def test_bad_unit_name():
    transport, tracker = _connected([])
    with pytest.raises(ConfigError, match="length unit"):
        tracker.set_units("furlong")
    tracker.close()
    transport.assert_done()


def _single(status: int, xyz) -> bytes:
    return struct.pack("<ii", 156, 2) + struct.pack("<iii", status, 0, 0) + struct.pack(
        "<17d", *xyz, 0.01, 0.02, 0.03, 0.04, 0, 0, 0, 0, 0, 0, 0, 21.5, 1001.0, 40.0)


@pytest.mark.parametrize("status, xyz, match", [
    (0, (float("nan"), 1.0, 2.0), "not a measurable position"),
    (0, (1.0, float("inf"), 2.0), "not a measurable position"),
    (0, (1e12, 1.0, 2.0), "not a measurable position"),
    (10004, (1.0, 2.0, 3.0), "status"),
])
def test_stationary_result_that_is_no_measurement_is_refused(status, xyz, match):
    pairs = [
        (hx("10000000 00000000 18000000 00000000"), hx("10000000 00000000 18000000 00000000")),
        (hx("14000000 00000000 1c000000 fa000000 00000000"), hx("10000000 00000000 1c000000 00000000")),
        (hx("0c000000 00000000 31000000"), hx("10000000 00000000 31000000 00000000") + _single(status, xyz)),
    ]
    transport, tracker = _connected(pairs)
    try:
        with pytest.raises(DeviceError, match=match):
            tracker.measure_stationary(duration_s=0.25)
    finally:
        tracker.close()


def test_an_exception_in_the_reader_thread_is_an_event_and_an_error_never_a_silent_death():
    samples = ec.MultiMeasResult.from_arrays(np.array([10_000, 11_000]), [[1.0, 2.0, 3.0], [1.1, 2.1, 3.1]])
    pairs = [
        (hx("10000000 00000000 18000000 01000000"), hx("10000000 00000000 18000000 00000000")),
        (hx("1c000000 00000000 1e000000 01000000 00000000 00000000 00000000"),
         hx("10000000 00000000 1e000000 00000000")),
        (hx("0c000000 00000000 31000000"), hx("10000000 00000000 31000000 00000000") + samples.encode()),
    ]
    transport, tracker = _connected(pairs)
    real = tracker._handle

    def broken(frame):
        if isinstance(frame, ec.MultiMeasResult):
            raise RuntimeError("injected fault in the reader")
        return real(frame)

    tracker._handle = broken
    tracker.start_stream(1000.0)
    with pytest.raises(DeviceError, match="injected fault"):
        for _ in range(50):
            tracker.read_samples(0.1)
    record = tracker._stream.record()
    assert record.error is not None and "RuntimeError" in record.error
    assert any(e.kind is EventKind.DEVICE_ERROR and "injected" in e.detail for e in record.events)
    tracker.close()
