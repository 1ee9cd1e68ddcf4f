"""Fixtures of the trailer tests: a live odometry fake and a driver on it."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.odometry import OdometryDriver
from fakes.odometry import OdometryFake
from fakes.sim.clock import SimClock
from fakes.sim.trailer import SimTrailer


@pytest.fixture
def odometry_fake(request):
    """A running odometry fake on a SimClock 200x faster than real time.

    Parametrise indirectly with a fault dict to inject faults (``"lockstep": True`` in it: the unit is
    stepped by its driver, as a dry run's cell is).
    """
    faults = dict(getattr(request, "param", None) or {})
    lockstep = bool(faults.pop("lockstep", False))  # stepped by its driver, as a dry run's (not a fault)
    clock = SimClock(time_scale=200.0, lockstep=lockstep)
    trailer = SimTrailer(clock, rng=np.random.default_rng(11))
    fake = OdometryFake(trailer, clock, faults=faults, rng=np.random.default_rng(12), lockstep=lockstep)
    yield fake
    fake.close()


@pytest.fixture
def odometry(odometry_fake):
    """``(driver, fake)`` connected over the fake's pty."""
    drv = OdometryDriver.open(odometry_fake.endpoint["device"], timeout_s=1.0, ack_timeout_s=0.2,
                              lockstep=odometry_fake.lockstep)
    yield drv, odometry_fake
    drv.close()
