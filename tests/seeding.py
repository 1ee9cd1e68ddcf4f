"""One seed for every random draw of the suite (a pytest plugin, loaded with ``-p tests.seeding``).

The session seed comes from ``--seed N``, else from the environment variable
``TEST_SEED``, else it is drawn fresh: every run draws new data, and any run
can be replayed. Each test derives its own generator from the session seed and
its node id, so a test draws the same numbers whether it runs alone, in the
whole suite or on any xdist worker.

* ``rng`` — a ``numpy.random.Generator`` of the test;
* ``test_seed`` — an int in [0, 2**31) of the test (for worlds and fakes that
  take an int seed);
* hypothesis draws from the session seed too (its ``--hypothesis-seed``
  wins when given);
* ``--station-seed`` of the station plugin (the acceptance scripts' fake
  cells) defaults to the test's seed.

The header of a run prints the session seed; a failing test prints the seed
and the command that replays it, and the summary lists them all.
"""

from __future__ import annotations

import hashlib
import os
import random

import numpy as np
import pytest

ENV = "TEST_SEED"
_KEY = pytest.StashKey[int]()


def pytest_addoption(parser):
    group = parser.getgroup("seeding")
    group.addoption("--seed", type=int, default=None,
                    help=f"session seed of every random draw in the suite (default: ${ENV}, else drawn fresh)")


def session_seed(config) -> int:
    return config.stash[_KEY]


def _initial_seed(config) -> int:
    given = config.getoption("--seed")
    if given is not None:
        return int(given)
    worker = getattr(config, "workerinput", None)
    if worker is not None and "test_session_seed" in worker:
        return int(worker["test_session_seed"])
    env = os.environ.get(ENV, "").strip()
    if env:
        return int(env)
    return random.SystemRandom().randrange(2**32)


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config):
    seed = _initial_seed(config)
    config.stash[_KEY] = seed
    try:  # hypothesis: new examples every run, the same ones for the same seed
        from hypothesis import core
    except ImportError:  # pragma: no cover - hypothesis is in the test extra
        return
    if config.getoption("hypothesis_seed", None) is None:
        core.global_force_seed = seed


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """xdist: every worker uses the controller's session seed."""
    node.workerinput["test_session_seed"] = session_seed(node.config)


def pytest_report_header(config):
    return f"session seed {session_seed(config)} (replay with --seed {session_seed(config)} or {ENV}=...)"


def seed_of(seed: int, nodeid: str) -> int:
    """The test's own seed: a hash of the session seed and its node id, in [0, 2**31)."""
    digest = hashlib.sha256(f"{seed}\0{nodeid}".encode()).digest()
    return int.from_bytes(digest[:4], "little") & 0x7FFFFFFF


def _replay(config, nodeid: str) -> str:
    return f".venv/bin/python -m pytest '{nodeid}' --seed {session_seed(config)}"


def seed_for(request) -> int:
    """The seed of a fixture's node at any scope (a module-scoped fixture: the module's node id)."""
    return seed_of(session_seed(request.config), request.node.nodeid)


@pytest.fixture
def test_seed(request) -> int:
    """An int seed of this test (derived from the session seed and the node id)."""
    return seed_of(session_seed(request.config), request.node.nodeid)


@pytest.fixture
def rng(test_seed) -> np.random.Generator:
    """The test's random generator: new numbers each session, the same for the same ``--seed``."""
    return np.random.default_rng(test_seed)


def pytest_runtest_setup(item):
    # the acceptance scripts' fake cells (app/testing.py): the test's seed unless --station-seed is given
    opt = item.config.option
    if hasattr(opt, "station_seed"):
        if not hasattr(item.config, "_station_seed_given"):
            item.config._station_seed_given = opt.station_seed is not None
        if not item.config._station_seed_given:
            opt.station_seed = seed_of(session_seed(item.config), item.nodeid)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.failed:
        seed = session_seed(item.config)
        text = (f"session seed {seed}, test seed {seed_of(seed, item.nodeid)}\n"
                f"replay: {_replay(item.config, item.nodeid)}")
        report.sections.append(("seed", text))


def pytest_runtest_logreport(report):
    # on the controller (xdist) or the only process: collect the failures for the summary
    if report.failed:
        if report.nodeid not in _FAILED_IDS:
            _FAILED_IDS.append(report.nodeid)


_FAILED_IDS: list[str] = []


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    failed = _FAILED_IDS
    seed = session_seed(config)
    if not failed:
        terminalreporter.write_line(f"session seed {seed}")
        return
    terminalreporter.section("seed")
    terminalreporter.write_line(f"session seed {seed}; replay each failure with:")
    for nodeid in failed:
        terminalreporter.write_line(f"  {_replay(config, nodeid)}")
