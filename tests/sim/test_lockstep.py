"""The world's clock runs in lockstep with the fakes: one seed, the same samples at any pace and any load.

Unit properties of :class:`fakes.sim.clock.SimClock` (a lockstep clock stands
still with nothing scheduled, lands exactly on what is scheduled, never passes
a producer's cap, never runs faster than its pace), then the whole tracker +
controller path: the same programs run through the real drivers at two time
scales, once with a reader that keeps up and once with one that stalls for
long stretches of wall time, give the same samples bit for bit.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from fakes.sim.clock import SimClock

#: how long a test waits on the wall for a clock that should (or should not) move, s
WALL_S = 0.2


def test_a_lockstep_clock_stands_still_with_nothing_scheduled():
    clock = SimClock(time_scale=1000.0, start=5.0, lockstep=True)
    time.sleep(WALL_S)
    assert clock.now() == 5.0 and clock.idle()
    free = SimClock(time_scale=1000.0, start=5.0)  # a free-running clock moves on its own
    time.sleep(WALL_S)
    assert free.now() > 5.0 + 0.5 * WALL_S * 1000.0


def test_sleep_until_lands_exactly_and_a_schedule_runs_the_clock_without_a_waiter():
    clock = SimClock(time_scale=500.0, lockstep=True)
    target = 1.2345678901
    assert clock.sleep_until(target) is True
    assert clock.now() == target  # exactly: an event happens at its simulated instant, not after it
    clock.schedule(target + 0.5)
    deadline = time.monotonic() + 5.0
    while clock.now() < target + 0.5 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert clock.now() == target + 0.5
    time.sleep(WALL_S)
    assert clock.now() == target + 0.5  # and stops there


def test_a_producer_cap_stalls_time_until_it_moves():
    clock = SimClock(time_scale=1000.0, lockstep=True)
    prod = clock.producer("test")
    prod.hold_until(0.3)
    done = threading.Event()
    threading.Thread(target=lambda: (clock.sleep_until(2.0), done.set()), daemon=True).start()
    time.sleep(WALL_S)  # 200 simulated seconds of pace: the cap holds the clock at 0.3
    assert clock.now() == 0.3 and not done.is_set()
    prod.hold_until(1.0)
    time.sleep(WALL_S)
    assert clock.now() == 1.0 and not done.is_set()
    prod.release()
    assert done.wait(5.0) and clock.now() == 2.0


def test_the_pace_is_a_maximum_rate():
    clock = SimClock(time_scale=10.0, lockstep=True)
    t0 = time.monotonic()
    clock.sleep_until(1.0)  # 1 simulated second at 10x: at least 0.1 s of wall time
    assert time.monotonic() - t0 >= 0.1 - 0.01  # tolerance: 10 ms for the host's timer granularity
    assert clock.now() == 1.0


def _run_cell(seed: int, time_scale: float, stall_s: float):
    """Home, then one ISO pose cycle while the emScon fake streams, through the real drivers; every
    ``stall_s`` of wall time between reads the reader sleeps (a stalled consumer)."""
    from drivers.controller import ControllerDriver
    from drivers.emscon import EmsconTracker
    from fakes.station import FakeStation
    from procedures.iso9283 import cycle_program, plan_from_config, programs
    from station.config import config_from_dict

    with FakeStation.start(seed=seed, time_scale=time_scale) as cell:
        cfg = config_from_dict(cell.config_dict(iso9283={"cycles": 2, "vap_cycles": 2}))
        plan = plan_from_config(cfg)
        ctl = ControllerDriver.from_url(cell.controller_url, gate=plan.gate())
        trk = EmsconTracker.from_url(cell.tracker_url)
        ctl.connect()
        trk.connect()
        trk.set_units("mm")
        try:
            ctl.run(programs(plan)["home"], timeout_s=60.0)
            trk.start_stream(plan.tracker_rate_hz)
            parts = []

            def on_status(_st):
                if stall_s:
                    time.sleep(stall_s)  # the reader does not read: the fake's sends block, time stalls
                parts.append(trk.read_samples(0.0))

            ctl.run(cycle_program(plan, "pose cycle", 1), timeout_s=120.0, on_status=on_status)
            trk.sync()
            parts.append(trk.read_samples(0.0))
            trk.stop_stream()
            parts.append(trk.read_samples(0.0))
        finally:
            trk.close()
            ctl.close()
    t = np.concatenate([p.t_s for p in parts])
    xyz = np.concatenate([p.xyz_mm for p in parts])
    return t, xyz


def test_one_seed_gives_the_same_samples_at_any_pace_and_any_consumer_speed(world_seed):
    fast_t, fast_xyz = _run_cell(world_seed, 200.0, 0.0)
    slow_t, slow_xyz = _run_cell(world_seed, 5.0, 0.05)
    assert fast_t.size > 100
    np.testing.assert_array_equal(fast_t, slow_t)
    np.testing.assert_array_equal(fast_xyz, slow_xyz)  # bit for bit
    assert np.all(np.diff(fast_t) > 0)
    # a tracker stream with holes would lose the point: every grid sample arrived
    assert np.allclose(np.diff(fast_t), np.diff(fast_t)[0])


@pytest.fixture
def world_seed(test_seed):
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    print(f"world seed {seed}")
    return seed
