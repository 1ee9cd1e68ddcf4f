"""Fixtures for the tracker drivers and fakes.

``CircleWorld`` is a minimal stand-in for ``fakes.sim.world`` with the three
members a tracker fake uses (``clock``, ``rate_hz``, ``measure``): a target
running a circle, noise-free, so a sample can be compared bit-for-bit with the
truth at its device time.
"""

from __future__ import annotations

import numpy as np
import pytest

from fakes.sim.clock import SimClock

#: simulated seconds per real second in these tests
TIME_SCALE = 20.0


class CircleSource:
    """Target on a horizontal circle; ``measure(t) -> (xyz_mm, valid)``."""

    def __init__(self, clock, rate_hz: float = 1000.0, *, center_mm=(1800.0, -250.0, 420.0),
                 radius_mm: float = 300.0, period_s: float = 4.0, blocked=()) -> None:
        self.clock = clock
        self.rate_hz = rate_hz
        self.center = np.asarray(center_mm, dtype=float)
        self.radius = radius_mm
        self.period = period_s
        self.blocked = list(blocked)  # absolute (t0, t1) windows without target

    def truth(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        a = 2 * np.pi * t / self.period
        return self.center + self.radius * np.column_stack([np.cos(a), np.sin(a), 0.1 * np.sin(2 * a)])

    def measure(self, t):
        t = np.asarray(t, dtype=float)
        valid = np.ones(t.shape, dtype=bool)
        for t0, t1 in self.blocked:
            valid &= ~((t >= t0) & (t < t1))
        return self.truth(t), valid


class CircleWorld:
    def __init__(self, time_scale: float = TIME_SCALE, rate_hz: float = 1000.0, **kw) -> None:
        self.clock = SimClock(time_scale=time_scale, start=0.0)
        self.source = CircleSource(self.clock, rate_hz, **kw)

    def tracker_source(self) -> CircleSource:
        return self.source

    def close(self) -> None:
        pass


@pytest.fixture
def world():
    w = CircleWorld()
    yield w
    w.close()


@pytest.fixture
def make_world():
    return CircleWorld


@pytest.fixture(autouse=True)
def no_leaked_threads():
    """Every driver and fake thread is joined by the end of its test."""
    import threading
    import time

    yield
    ours = ("emscon-", "geocom-")
    deadline = time.monotonic() + 2.0
    for thread in [t for t in threading.enumerate() if t.name.startswith(ours)]:
        thread.join(timeout=max(0.0, deadline - time.monotonic()))
    alive = [t.name for t in threading.enumerate() if t.name.startswith(ours)]
    assert not alive, f"threads left running: {alive}"
