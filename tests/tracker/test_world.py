"""Both tracker fakes measuring the simulated world (``fakes.sim.world.make_world``).

The world's tracker has its own clock (offset from the world's), noise tied
to its grid index and scheduled beam breaks; what the drivers deliver must be
exactly what that model reports at the delivered device times.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.emscon import EmsconTracker
from drivers.geocom import GeoComTracker
from drivers.tracker import EventKind
import fakes.sim.world as world_mod
from drivers.transport import serial_factory, tcp_factory

from .helpers import collect, finish


@pytest.fixture
def sim_world(rng):
    offset = float(rng.uniform(-0.4, 0.4))
    world = world_mod.make_world(seed=int(rng.integers(1 << 20)), time_scale=20.0,
                                 tracker_clock_offset_s=offset)
    yield world, offset
    world.close()


def test_emscon_streams_the_world_model_on_its_device_clock(sim_world):
    from fakes.emscon import start_fake

    world, offset = sim_world
    source = world.tracker_source()
    t0 = world.clock.now() + 3.0
    world.tracker.add_beam_break(t0, t0 + 0.25)
    with start_fake(world) as fake:
        tracker = EmsconTracker(tcp_factory(fake.endpoint["host"], fake.endpoint["port"]))
        try:
            tracker.connect(timeout_s=10)
            tracker.start_stream(1000.0)
            assert world.clock.now() < t0
            t, xyz, status, events, record = finish(tracker, collect(tracker, 4.0, world.clock))
        finally:
            tracker.close()
    k = t * 1000.0
    np.testing.assert_allclose(k, np.rint(k), atol=1e-6)
    expected, valid = source.measure(t - offset)
    assert valid.all()
    np.testing.assert_allclose(xyz, expected, rtol=0, atol=1e-9)
    assert [e.kind for e in events] == [EventKind.BEAM_BROKEN, EventKind.TARGET_REACQUIRED]
    in_break = np.ceil((t0 + 0.25 + offset) * 1000 - 1e-9) - np.ceil((t0 + offset) * 1000 - 1e-9)
    assert record.not_measured == in_break and record.lost == 0
    assert record.grid_points == record.received + record.not_measured


def test_geocom_measures_the_world_model(sim_world):
    from fakes.geocom import start_fake

    world, offset = sim_world
    source = world.tracker_source()
    with start_fake(world) as fake:
        tracker = GeoComTracker(serial_factory(fake.endpoint["device"]))
        try:
            tracker.connect(timeout_s=5)
            m = tracker.measure_stationary()
        finally:
            tracker.close()
    expected, valid = source.measure([m.t_device_s - offset])
    assert valid.all()
    np.testing.assert_allclose(m.xyz_mm, expected[0], rtol=0, atol=1e-9)
