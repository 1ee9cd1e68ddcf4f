"""UR driver -> UR fake -> simulated arm, seen by the emScon tracker fake through
its own driver: the tracker measures the displacement the robot really made."""

from __future__ import annotations

import numpy as np

import drivers.emscon as emscon_driver
import fakes.emscon as emscon_fake


def test_tracker_sees_the_move_the_ur_driver_commanded(world, fake, make_driver, rng):
    tracker_fake = emscon_fake.start_fake(world)
    try:
        ep = tracker_fake.endpoint
        tracker = emscon_driver.EmsconTracker.from_url(f"emscon://{ep['host']}:{ep['port']}")
        tracker.connect(timeout_s=30.0)
        try:
            d = make_driver(fake)
            arm = world.arm
            before = tracker.measure_stationary(duration_s=0.2)
            t_before = world.clock.now()
            home = world.robot.home_q_rad
            q_goal = home + rng.uniform(-0.3, 0.3, 6)
            while np.linalg.norm(kin_tcp(world, q_goal) - kin_tcp(world, home)) < 50.0:  # a move worth seeing
                q_goal = home + rng.uniform(-0.3, 0.3, 6)
            st = d.move_joint(q_goal, speed_frac=0.2)
            after = tracker.measure_stationary(duration_s=0.2)
            t_after = world.clock.now()
        finally:
            tracker.close()
    finally:
        tracker_fake.close()
    measured = np.linalg.norm(after.xyz_mm - before.xyz_mm)
    true = np.linalg.norm(arm.tool_position_mm(t_after) - arm.tool_position_mm(t_before))
    reported = np.linalg.norm(st.tcp_xyz_mm - kin_tcp(world, world.robot.home_q_rad))
    commanded = np.linalg.norm(kin_tcp(world, q_goal) - kin_tcp(world, world.robot.home_q_rad))
    assert measured > 0.5 * commanded  # the arm really moved (commanded >= 50 mm, arm errors are mm)
    # the tracker frame is a rigid transform of the base frame: distances agree to the
    # tracker's error (MPE 15 um + 6 um/m at a few metres -> well under 0.1 mm)
    assert abs(measured - true) < 0.1, (measured, true)
    # the controller's own report (nominal model) describes the same move to within the arm's errors
    assert abs(measured - reported) < 2.0, (measured, reported)


def kin_tcp(world, q):
    from station.models import kinematics

    return kinematics.tool_position(world.robot.dh_nominal, q)
