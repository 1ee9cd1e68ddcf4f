"""pytest plugin of the station (registered as ``station`` in ``pytest11``).

Fixtures for acceptance scripts:

* ``fake_station`` — a :class:`station.acceptance.Station` whose devices are
  the fake cell (a fresh simulated world per run, seed from ``--station-seed``
  or random), with its store in the test's temporary directory.
"""

from __future__ import annotations

import random

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("station")
    group.addoption("--station-seed", type=int, default=None, help="seed of the fake cell (default: random)")
    group.addoption("--station-time-scale", type=float, default=20.0, help="fake cell speed-up (default 20)")


@pytest.fixture
def fake_station(tmp_path, request):
    from station.acceptance import Station

    seed = request.config.getoption("--station-seed")
    if seed is None:
        seed = random.SystemRandom().randrange(2**31)
    return Station.fake(tmp_path, seed=seed, time_scale=request.config.getoption("--station-time-scale"))
