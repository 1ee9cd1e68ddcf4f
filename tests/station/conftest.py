import pytest

from fakes.station import FakeStation
from tests.pace import LOCKSTEP


@pytest.fixture
def world_seed(test_seed):
    """The test's seed (tests/seeding.py): a fresh world every run, replayed with --seed."""
    return test_seed


@pytest.fixture
def fake_cell(world_seed):
    """A fake cell (simulated arm, emScon tracker, controller) on loopback, lockstep as fast as it goes."""
    with FakeStation.start(seed=world_seed, time_scale=LOCKSTEP) as station:
        yield station
