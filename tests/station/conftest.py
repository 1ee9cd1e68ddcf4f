import numpy as np
import pytest

from fakes.station import FakeStation


@pytest.fixture
def world_seed():
    return int(np.random.default_rng().integers(0, 2**31))


@pytest.fixture
def fake_cell(world_seed):
    """A fake cell (simulated arm, emScon tracker, controller) on loopback, 20x real time."""
    with FakeStation.start(seed=world_seed, time_scale=20.0) as station:
        yield station
