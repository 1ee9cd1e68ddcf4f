"""Stream accounting: every grid point is received, rejected, lost or not measured."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.tracker import EventKind, StreamBuffer
from station.errors import ConfigError, ConnectionLost


def _feed(buf, k, rate=1000.0, status=0):
    k = np.asarray(k, dtype=float)
    buf.add(k / rate, np.column_stack([k, -k, 2 * k]), np.full(len(k), status))


def test_random_holes_are_lost_and_add_up(rng):
    buf = StreamBuffer("x", 1000.0)
    k = np.arange(5000, 25000)
    keep = rng.random(k.size) > rng.uniform(0.01, 0.2)
    keep[0] = keep[-1] = True
    for chunk in np.array_split(k[keep], int(rng.integers(1, 50))):
        _feed(buf, chunk)
    rec = buf.record()
    assert rec.received == keep.sum() and rec.lost == (~keep).sum()
    assert rec.grid_points == k.size == rec.received + rec.lost
    assert sum(g.missing for g in rec.gaps) == rec.lost and all(g.cause == "lost" for g in rec.gaps)
    batch = buf.take(0.0)
    np.testing.assert_array_equal(batch.t_s, k[keep] / 1000.0)
    np.testing.assert_array_equal(batch.xyz_mm[:, 1], -k[keep])


def test_rejected_samples_are_not_counted_lost():
    buf = StreamBuffer("x", 1000.0)
    t = np.arange(100, 110) / 1000.0
    xyz = np.ones((10, 3))
    xyz[3] = np.nan  # non-finite
    t[6] += 0.0004  # off the grid
    buf.add(t, xyz, np.zeros(10))
    _feed(buf, [108, 109])  # grid points delivered already
    rec = buf.record()
    assert (rec.received, rec.rejected, rec.lost, rec.duplicates) == (8, 2, 0, 2)
    assert [g.cause for g in rec.gaps] == ["rejected", "rejected"]
    assert rec.grid_points == 10 == rec.received + rec.rejected


def test_beam_break_gap_is_not_measured_and_events_come_in_order():
    buf = StreamBuffer("x", 500.0)
    _feed(buf, range(0, 50), rate=500.0)
    buf.event(EventKind.BEAM_BROKEN, "no target")
    buf.event(EventKind.TARGET_REACQUIRED)
    _feed(buf, range(80, 100), rate=500.0)
    _feed(buf, range(103, 110), rate=500.0)  # a plain hole after the break
    rec = buf.record()
    assert (rec.not_measured, rec.lost) == (30, 3)
    assert [g.cause for g in rec.gaps] == ["beam_broken", "lost"]
    batch = buf.take(0.0)
    assert [e.kind for e in batch.events] == [EventKind.BEAM_BROKEN, EventKind.TARGET_REACQUIRED]
    assert batch.events[0].t_device_s == pytest.approx(49 / 500.0)


def test_take_waits_limits_and_raises_after_draining_a_failure():
    buf = StreamBuffer("x", 1000.0)
    assert len(buf.take(0.01)) == 0
    timer = threading.Timer(0.05, _feed, (buf, range(10)))
    timer.start()
    assert len(buf.take(2.0)) == 10
    timer.join()
    _feed(buf, range(10, 30))
    buf.fail(ConnectionLost("gone"))
    assert len(buf.take(0.0, max_samples=15)) == 15
    assert len(buf.take(0.0)) == 5
    with pytest.raises(ConnectionLost, match="gone"):
        buf.take(0.0)


def test_polled_stream_counts_duplicates():
    buf = StreamBuffer("x", 50.0, grid=False)
    buf.add([0.1, 0.1, 0.2, 0.15, 0.3], np.zeros((5, 3)), np.zeros(5))
    rec = buf.record()
    assert (rec.received, rec.duplicates, rec.rejected) == (3, 1, 1)


def test_rate_validated():
    with pytest.raises(ConfigError, match="rate_hz"):
        StreamBuffer("x", 0.0)


@pytest.mark.parametrize("silent", [False, True])
def test_a_host_that_did_not_run_is_no_silence_of_the_stream(rng, silent):
    """The driver's reader has samples ready, and this host is stopped for a drawn 1.5-2.5 times ``take``'s
    timeout before it adds them: ``take`` returns them (counting the host's wall time, it returned nothing
    when the reader ran again). ``silent``: nothing comes, and ``take`` returns empty after the pause and the
    timeout less one look."""
    import time

    from drivers.tracker import TAKE_LOOK_S
    from tests.host_pause import pause_host

    buf = StreamBuffer("x", 1000.0)
    timeout_s = float(rng.uniform(0.3, 0.6))
    pause_s = float(rng.uniform(1.5, 2.5)) * timeout_s
    n = int(rng.integers(3, 20))

    def reader():
        pause_host(pause_s)
        if not silent:
            buf.add(np.arange(n) * 1e-3, np.zeros((n, 3)), np.zeros(n, dtype=int))

    started = time.monotonic()
    thread = threading.Thread(target=reader)
    thread.start()
    try:
        batch = buf.take(timeout_s)
    finally:
        thread.join()
    if silent:
        assert len(batch) == 0 and time.monotonic() - started >= pause_s + timeout_s - TAKE_LOOK_S
    else:
        assert len(batch) == n
