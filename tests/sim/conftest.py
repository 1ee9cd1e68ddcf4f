"""Fixtures of the simulation tests: robots, clocks, small worlds."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from station.models.robots import get_robot


@pytest.fixture(scope="session")
def robot():
    """The large industrial arm whose workspace holds the seed 000 cube."""
    return get_robot("industrial-3100")


@pytest.fixture()
def clock():
    return ManualClock()


@pytest.fixture(scope="session")
def iso_q(robot):
    """Nominal joint angles of seed 000 Table 2 (P1..P5) with P1's tool orientation."""
    from fakes.sim.iso_run import commanded_joints
    from station.analysis.iso9283.poses import TABLE2_POSES_MM

    _, q = commanded_joints(robot, np.array(TABLE2_POSES_MM))
    return q
