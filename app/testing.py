"""pytest plugin of the station (registered as ``station`` in ``pytest11``).

Fixtures for acceptance scripts:

* ``fake_station`` — a :class:`station.acceptance.Station` whose devices are
  the fake cell (a fresh simulated world per run, seed from ``--station-seed``
  or random), with its store in the test's temporary directory. Its robot is
  one that passed its overhaul: drawn with realistic errors, but inside the
  configured limits by a clear margin (``condition="in-spec"``), so a script
  that checks the maker's limits passes on it whatever the seed.
* ``fake_station_out_of_spec`` — the same with a robot whose AP is over its
  limit by a clear margin: the acceptance script must refuse it.
"""

from __future__ import annotations

import random

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("station")
    group.addoption("--station-seed", type=int, default=None, help="seed of the fake cell (default: random)")
    group.addoption("--station-time-scale", type=float, default=20.0, help="fake cell speed-up (default 20)")


def _fake(tmp_path, request, condition: str):
    from app.acceptance import Station

    seed = request.config.getoption("--station-seed")
    if seed is None:
        seed = random.SystemRandom().randrange(2**31)
    station = Station.fake(tmp_path, seed=seed, time_scale=request.config.getoption("--station-time-scale"),
                           condition=condition)
    # printed with the test's output when it fails: the cell to rerun with --station-seed
    print(f"fake station: {condition} robot, cell seed {station.seed} (asked for {seed})")
    return station


@pytest.fixture
def fake_station(tmp_path, request):
    return _fake(tmp_path, request, "in-spec")


@pytest.fixture
def fake_station_out_of_spec(tmp_path, request):
    return _fake(tmp_path, request, "out-of-spec")
