"""Shared helpers of the tracker tests (no fixtures here: see conftest.py)."""

from __future__ import annotations

import threading
import time

import numpy as np

from station.errors import ConnectionLost


def collect(tracker, sim_seconds: float, clock, *, timeout_s: float = 20.0):
    """Read samples and events until ``sim_seconds`` of device time have streamed.

    Returns (t_s (N,), xyz_mm (N,3), status (N,), events list).
    """
    ts, xs, ss, events = [], [], [], []
    t_end = clock.now() + sim_seconds
    deadline = time.monotonic() + timeout_s
    while clock.now() < t_end:
        assert time.monotonic() < deadline, "stream did not advance in time"
        batch = tracker.read_samples(0.05)
        ts.append(batch.t_s), xs.append(batch.xyz_mm), ss.append(batch.status)
        events.extend(batch.events)
    return ts, xs, ss, events


def finish(tracker, parts):
    """Stop the stream, drain what is left; returns (t, xyz, status, events, record)."""
    ts, xs, ss, events = parts
    record = tracker.stop_stream()
    batch = tracker.read_samples(0.0)
    ts.append(batch.t_s), xs.append(batch.xyz_mm), ss.append(batch.status)
    events.extend(batch.events)
    return np.concatenate(ts), np.concatenate(xs), np.concatenate(ss), events, record


def check_stream_invariants(t, xyz, record, truth, rate_hz):
    """Samples on the grid, increasing, equal to the truth; counters add up."""
    assert len(t) == record.received
    k = t * rate_hz
    np.testing.assert_allclose(k, np.rint(k), rtol=0, atol=1e-6)
    assert np.all(np.diff(t) > 0)
    np.testing.assert_allclose(xyz, truth(t), rtol=0, atol=1e-9)
    assert record.grid_points == record.received + record.rejected + record.lost + record.not_measured
    missing_in_gaps = sum(g.missing for g in record.gaps)
    assert missing_in_gaps == record.grid_points - record.received


class ScriptedTransport:
    """A transport that expects exact request bytes and answers with scripted bytes.

    ``pairs`` is a list of ``(request_bytes, reply_bytes)``; ``push(bytes)``
    queues unsolicited bytes. A write that differs from the next expected
    request, or pairs left over at :meth:`assert_done`, fail the test.
    """

    description = "scripted"

    def __init__(self, pairs) -> None:
        self._pairs = list(pairs)
        self._rx = bytearray()
        self._cond = threading.Condition()
        self._closed = False
        self.mismatch: str | None = None

    @property
    def closed(self) -> bool:
        return self._closed

    def push(self, data: bytes) -> None:
        with self._cond:
            self._rx += data
            self._cond.notify_all()

    def write(self, data: bytes, timeout_s: float) -> None:
        with self._cond:
            if self._closed:
                raise ConnectionLost("scripted transport closed")
            if not self._pairs:
                self.mismatch = f"unexpected request {data.hex()}"
                raise AssertionError(self.mismatch)
            want, reply = self._pairs.pop(0)
            if data != want:
                self.mismatch = f"request {data.hex()} != expected {want.hex()}"
                raise AssertionError(self.mismatch)
            self._rx += reply
            self._cond.notify_all()

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        with self._cond:
            end = time.monotonic() + timeout_s
            while not self._rx:
                if self._closed:
                    raise ConnectionLost("scripted transport closed")
                left = end - time.monotonic()
                if left <= 0:
                    return b""
                self._cond.wait(left)
            data = bytes(self._rx[:max_bytes])
            del self._rx[:max_bytes]
            return data

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def assert_done(self) -> None:
        assert self.mismatch is None, self.mismatch
        assert not self._pairs, f"{len(self._pairs)} scripted pair(s) left over: " + \
            ", ".join(p[0].hex() for p in self._pairs)
