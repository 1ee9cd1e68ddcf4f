"""Both robot connections are one :class:`drivers.robot.Robot`: the same calls move the simulated arm through
the FTP+Modbus controller fake and through the UR fake (``ur_rtde``), and the gate refuses the same target."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.registry import device_for_url
from drivers.robot import Robot
from fakes.registry import start_named, url_of
from fakes.sim.world import make_world
from station.errors import SafetyError
from station.models import kinematics
from station.programs.program import CycleMark, Dwell, JointTarget, Loop, Move, Program
from station.safety import SafetyGate, default_limits


@pytest.fixture(params=["modbus+ftp", "ur"])
def robot(request, test_seed):
    seed = test_seed
    print(f"seed {seed}")
    world = make_world(robot="ur5e", seed=seed, time_scale=10.0, effects=None)
    fake = start_named("controller" if request.param == "modbus+ftp" else "ur", world)
    gate = SafetyGate(world.robot, default_limits(world.robot))
    drv = device_for_url(url_of(request.param, fake), timeout_s=5.0, gate=gate)
    try:
        drv.connect()
        yield drv, world, np.random.default_rng(seed)
    finally:
        drv.close()
        fake.close()
        world.close()


def test_the_same_calls_move_the_arm_through_either_connection(robot):
    drv, world, rng = robot
    assert isinstance(drv, Robot)
    state, took = drv.take_over()
    assert took == "" and state
    assert drv.fault_state() is None
    q0 = drv.joints_rad()
    np.testing.assert_allclose(q0, world.robot.home_q_rad, atol=1e-3)
    target = q0 + rng.uniform(-0.2, 0.2, 6)
    drv.move_to(target, speed_frac=0.1)
    drv.wait_settled(30.0)
    # the arm's own reading is where it went (the world's arm has no error effects here)
    t = world.clock.now()
    np.testing.assert_allclose(world.arm.actual_q_rad(np.array([t]))[0], target, atol=2e-3)
    np.testing.assert_allclose(drv.joints_rad(), target, atol=2e-3)
    np.testing.assert_allclose(drv.tcp_mm(), kinematics.tool_position(world.robot.dh_nominal, drv.joints_rad()),
                               atol=0.5)
    # a program run whole, progress reported, cycles counted
    a = JointTarget("A", tuple(np.degrees(target + 0.05)))
    b = JointTarget("B", tuple(np.degrees(target - 0.05)))
    prog = Program(name="ST_T", robot_name=world.robot.name, rated_tcp_speed_mm_s=1000.0, accel_frac=0.5,
                   statements=(Loop(2, (Move(a, "joint", 0.1), Dwell(0.1), Move(b, "joint", 0.1), CycleMark())),))
    seen = []
    final = drv.run(prog, timeout_s=60.0, on_status=lambda st: seen.append((st.moves_done, st.cycle_count)))
    assert final.moves_done == 4 and final.cycle_count == 2
    assert seen and all(m <= 4 for m, _ in seen) and seen == sorted(seen)
    np.testing.assert_allclose(drv.joints_rad(), np.radians(b.q_deg), atol=2e-3)
    # the gate refuses a target beyond the joint limits before anything moves
    q_before = drv.joints_rad()
    bad = q_before.copy()
    bad[1] = 7.0  # beyond +/- 360 deg
    with pytest.raises(SafetyError):
        drv.move_to(bad)
    np.testing.assert_allclose(drv.joints_rad(), q_before, atol=1e-4)  # (the Modbus report is in 0.001 deg)
    drv.stop()
    assert drv.fault_state() is None


def test_the_time_the_caller_spends_on_a_status_is_not_the_programs(robot):
    """The caller's journal write blocks (a disk stalled in a sync, seen in a soak: 30 s in one COMMIT) past the
    program's timeout while the program finishes: either connection reports it finished, not timed out."""
    drv, world, rng = robot
    drv.take_over()
    q0 = drv.joints_rad()
    a = JointTarget("A", tuple(np.degrees(q0 + rng.uniform(-0.1, 0.1, 6))))
    prog = Program(name="ST_SLOW_HOST", robot_name=world.robot.name, rated_tcp_speed_mm_s=1000.0, accel_frac=0.5,
                   statements=(Move(a, "joint", 0.2), Dwell(0.2)))
    timeout_s = float(rng.uniform(1.0, 2.0))
    blocked = []

    def on_status(st):
        if not blocked:
            t0 = time.monotonic()
            # held until the arm's last motion has ended on the world's clock and the timeout has passed (a
            # lockstep-capable clock stands still once the program is over: no margin past the queue's end)
            while (world.clock.now() < world.arm.queue_end_s or time.monotonic() - t0 < 1.5 * timeout_s) \
                    and time.monotonic() - t0 < 60.0:
                time.sleep(0.01)
            blocked.append(time.monotonic() - t0)

    final = drv.run(prog, timeout_s=timeout_s, on_status=on_status)
    assert blocked and timeout_s < blocked[0] < 60.0
    assert final.moves_done == 1
    np.testing.assert_allclose(drv.joints_rad(), np.radians(a.q_deg), atol=2e-3)
