"""Fixtures of the controller tests: robot, gate, simulated world, fake, driver."""

from __future__ import annotations

import pytest

from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.models.robots import get_robot
from station.safety import SafetyGate, SafetyLimits

#: simulated seconds per real second: a 3-cycle ISO run (~35 s) takes under a second, and
#: the controller fake still plans each move (~15 ms host time) before the previous one ends
TIME_SCALE = 50.0

#: the seed 000 cube (Table 1) plus 100 mm: the cell's configured workspace box
CELL_BOX_MIN = (-700.0, 1000.0, 700.0)
CELL_BOX_MAX = (700.0, 2400.0, 2100.0)


@pytest.fixture(scope="session")
def robot():
    return get_robot("industrial-3100")


@pytest.fixture(scope="session")
def limits():
    return SafetyLimits(workspace_min_mm=CELL_BOX_MIN, workspace_max_mm=CELL_BOX_MAX, max_tcp_speed_mm_s=2000.0)


@pytest.fixture(scope="session")
def gate(robot, limits):
    return SafetyGate(robot, limits)


@pytest.fixture(scope="session")
def iso_poses():
    """Seed 000 Table 2, P1..P5 (mm)."""
    return {f"P{i + 1}": tuple(p) for i, p in enumerate(TABLE2_POSES_MM)}


@pytest.fixture
def world(test_seed):
    from fakes.sim.world import make_world

    w = make_world("industrial-3100", seed=test_seed, time_scale=TIME_SCALE, effects=None)
    yield w
    w.close()


@pytest.fixture
def start_controller(world):
    """``start_controller(faults=None) -> fake``; every fake is closed after the test."""
    from fakes.controller import start_fake

    fakes = []

    def start(faults=None, **kwargs):
        fake = start_fake(world, faults=faults, **kwargs)
        fakes.append(fake)
        return fake

    yield start
    for f in fakes:
        f.close()


@pytest.fixture
def make_driver(gate):
    """``make_driver(fake, **kwargs) -> connected ControllerDriver``; closed after the test."""
    from drivers.controller import ControllerDriver

    drivers = []

    def make(fake, **kwargs):
        kwargs.setdefault("timeout_s", 3.0)
        drv = ControllerDriver.from_url(fake.url, gate=kwargs.pop("gate", gate), **kwargs)
        drivers.append(drv)
        return drv.connect()

    yield make
    for d in drivers:
        d.close()


@pytest.fixture(autouse=True)
def no_leaked_threads():
    """Every fake joins its threads on close: none of ours outlive a test."""
    import threading

    before = set(threading.enumerate())
    yield
    left = [t for t in threading.enumerate() if t not in before and t.name.startswith("controller-fake")]
    assert not left, f"threads left running: {[t.name for t in left]}"
