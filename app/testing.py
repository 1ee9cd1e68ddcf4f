"""pytest plugin of the station (registered as ``station`` in ``pytest11``).

Fixtures for acceptance scripts:

* ``fake_station`` — a :class:`app.acceptance.Station` whose devices are
  the fake cell (a fresh simulated world per run, seed from ``--station-seed``
  or random), with its store in the test's temporary directory. Its robot is
  one that passed its overhaul: drawn with realistic errors, but inside the
  configured limits by a clear margin (``condition="in-spec"``), so a script
  that checks the maker's limits passes on it whatever the seed. A test
  shapes it with the marker ``@pytest.mark.station(...)``, whose keywords are
  :meth:`Station.fake`'s (``condition``, ``serial``, ``model``, ``limits``
  merged into the fake robot's, ``payload_kg``, ``cycles``, ``vap_cycles``,
  ``measurements``, ``record``).
* ``fake_station_out_of_spec`` — the same with a robot whose AP is over its
  limit by a clear margin: the acceptance script must refuse it.
* ``make_fake_station`` — a factory: ``make_fake_station(condition="rp-out",
  serial="NA8608-0042", limits={"rp_limit_mm": 0.3}, cycles=5)``, as many
  stations as a test needs, each printed with its seed.

Conditions (:data:`app.acceptance.CONDITIONS`): ``as-drawn``,
``in-spec``, ``out-of-spec`` (AP out), ``marginal`` (AP in the guard band below its limit),
``rp-out``, ``one-pose-out`` (one pose's AP out, the rest in). The cell's seed is printed (shown with a failing test's output):
rerun with ``--station-seed N``. ``--station-store PATH`` points every
fixture's store at one persistent SQLite store so history spans sessions
(a plant's central PostgreSQL store is reached by forwarding: ``store_url``
in a config, :meth:`Station.from_config`).
"""

from __future__ import annotations

import random

import pytest


def pytest_addoption(parser):
    group = parser.getgroup("station")
    group.addoption("--station-seed", type=int, default=None, help="seed of the fake cell (default: random)")
    group.addoption("--station-time-scale", type=float, default=20.0, help="fake cell speed-up (default 20)")
    group.addoption("--station-store", default=None,
                    help="SQLite store of every fake station (default: the test's temporary directory)")


def pytest_configure(config):
    config.addinivalue_line("markers", "station(**kw): shape the fake_station fixture (Station.fake's keywords)")


def _fake(tmp_path, request, **kw):
    from app.acceptance import Station

    seed = request.config.getoption("--station-seed")
    if seed is None:
        seed = random.SystemRandom().randrange(2**31)
    kw.setdefault("store", request.config.getoption("--station-store"))
    kw.setdefault("condition", "in-spec")
    kw.setdefault("time_scale", request.config.getoption("--station-time-scale"))
    station = Station.fake(tmp_path, seed=seed, **kw)
    # printed with the test's output when it fails: the cell to rerun with --station-seed
    print(f"fake station: {station.condition} robot {station.config.robots['r1'].serial}, cell seed "
          f"{station.seed} (asked for {seed}; rerun with --station-seed {seed})")
    return station


def _marker_kw(request) -> dict:
    m = request.node.get_closest_marker("station")
    return dict(m.kwargs) if m else {}


@pytest.fixture
def fake_station(tmp_path, request):
    return _fake(tmp_path, request, **_marker_kw(request))


@pytest.fixture
def fake_station_out_of_spec(tmp_path, request):
    return _fake(tmp_path, request, **{**_marker_kw(request), "condition": "out-of-spec"})


@pytest.fixture
def make_fake_station(tmp_path, request):
    made = []

    def make(**kw):
        workdir = tmp_path / f"station-{len(made) + 1}"
        workdir.mkdir()
        made.append(_fake(workdir, request, **kw))
        return made[-1]

    return make
