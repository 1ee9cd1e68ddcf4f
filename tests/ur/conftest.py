"""Fixtures of the UR tests: a simulated UR5e world, the UR fake on a loopback
address of its own, the safety gate, the driver, and the ``ur_rtde`` probe
that runs in a child process (see ``rtde_probe.py``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from fakes.sim.world import make_world
from fakes.ur import start_fake
from station.safety import SafetyGate, SafetyLimits, default_limits

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PROBE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "rtde_probe.py")

#: simulated seconds per real second in these tests
TIME_SCALE = 8.0


@pytest.fixture
def world():
    w = make_world(robot="ur5e", seed=3, time_scale=TIME_SCALE)
    yield w
    w.close()


@pytest.fixture
def make_fake(world):
    """``make_fake(faults=None)`` -> running fake; all closed (threads joined) at teardown."""
    fakes = []

    def make(faults=None):
        fake = start_fake(world, faults=faults)
        fakes.append(fake)
        return fake

    yield make
    for f in fakes:
        f.close()


@pytest.fixture
def fake(make_fake):
    return make_fake()


@pytest.fixture
def gate(world):
    return SafetyGate(world.robot, default_limits(world.robot))


def box_gate(world, half_mm: float = 250.0) -> SafetyGate:
    """Gate whose workspace is a box of +/- ``half_mm`` around the home TCP."""
    from station.models import kinematics

    c = kinematics.tool_position(world.robot.dh_nominal, world.robot.home_q_rad)
    return SafetyGate(
        world.robot,
        SafetyLimits(
            workspace_min_mm=tuple(c - half_mm),
            workspace_max_mm=tuple(c + half_mm),
            max_tcp_speed_mm_s=500.0,
            max_speed_frac=0.6,
            max_accel_frac=0.6,
        ),
    )


@pytest.fixture
def make_driver(world):
    """``make_driver(fake, gate=None, **kw)`` -> connected URDriver; closed at teardown."""
    from drivers.ur import URDriver

    drivers = []

    def make(fake, gate=None, **kw):
        g = gate if gate is not None else SafetyGate(world.robot, default_limits(world.robot))
        d = URDriver(fake.endpoint["host"], world.robot, g, **kw)
        drivers.append(d)
        return d.connect()

    yield make
    for d in drivers:
        d.close()


def run_probe(host: str, frequency_hz: float, duration_s: float, variables=(), timeout_s: float = 30.0,
              min_rows: int = 0) -> dict:
    """Run ``ur_rtde``'s RTDEReceiveInterface in a child process; its JSON report (``min_rows``: as
    :func:`start_probe`)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
    p = subprocess.run(
        [sys.executable, PROBE, host, repr(float(frequency_hz)), repr(float(duration_s)), ",".join(variables),
         str(int(min_rows))],
        capture_output=True, text=True, timeout=timeout_s, env=env,
    )
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"probe printed no report (rc {p.returncode}): {p.stdout[-500:]} {p.stderr[-500:]}"
    return json.loads(lines[-1])


def start_probe(host: str, frequency_hz: float, duration_s: float, variables=(), min_rows: int = 0) -> subprocess.Popen:
    """The probe in a child process; ``min_rows``: sample on (up to 10 s) until that many rows and a consecutive
    pair were seen."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([ROOT, env.get("PYTHONPATH", "")])
    return subprocess.Popen(
        [sys.executable, PROBE, host, repr(float(frequency_hz)), repr(float(duration_s)), ",".join(variables),
         str(int(min_rows))],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )


def finish_probe(p: subprocess.Popen, timeout_s: float = 30.0) -> dict:
    out, err = p.communicate(timeout=timeout_s)
    lines = [ln for ln in out.splitlines() if ln.startswith("{")]
    assert lines, f"probe printed no report (rc {p.returncode}): {out[-500:]} {err[-500:]}"
    return json.loads(lines[-1])


@pytest.fixture(autouse=True)
def no_leaked_threads():
    """Every fake, driver and world of a test is closed and its threads joined."""
    import threading

    before = set(threading.enumerate())
    yield
    leaked = [t.name for t in threading.enumerate() if t not in before and t.is_alive()]
    assert not leaked, f"threads left running: {leaked}"
