"""``ur_rtde``'s DashboardClient judges the fake's dashboard server; the driver's
program and power control through it."""

from __future__ import annotations

import time

import numpy as np
import pytest

import dashboard_client
from station.errors import ConnectionLost, DeviceError, DeviceNotReady, SafetyError


def _wait(pred, timeout_s=10.0, what="condition"):
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.002)


@pytest.fixture
def dash(fake):
    d = dashboard_client.DashboardClient(fake.endpoint["host"])
    d.connect()
    yield d
    d.disconnect()


def test_play_pause_stop_load_running(fake, dash):
    assert dash.isConnected()
    assert dash.polyscopeVersion().startswith("5.11")
    assert dash.isInRemoteControl() is True
    assert dash.getSerialNumber().isdigit()
    assert dash.robotmode() == "Robotmode: RUNNING"
    assert dash.getLoadedProgram() == "No program loaded"
    with pytest.raises(RuntimeError, match="Failed to execute: play"):
        dash.play()  # nothing loaded
    with pytest.raises(RuntimeError, match="File not found: nope.urp"):
        dash.loadURP("nope.urp")
    dash.loadURP("station_idle.urp")
    assert dash.getLoadedProgram() == "Loaded program: /programs/station_idle.urp"
    assert dash.running() is False and dash.programState() == "STOPPED station_idle.urp"
    dash.play()
    assert dash.running() is True and dash.programState() == "PLAYING station_idle.urp"
    dash.pause()
    assert dash.running() is False and dash.programState() == "PAUSED station_idle.urp"
    with pytest.raises(RuntimeError, match="Failed to execute: pause"):
        dash.pause()
    dash.play()  # resume
    assert dash.programState() == "PLAYING station_idle.urp"
    dash.stop()
    assert dash.running() is False and dash.programState() == "STOPPED station_idle.urp"
    with pytest.raises(RuntimeError, match="Failed to execute: stop"):
        dash.stop()
    dash.send("no such command\n")
    assert dash.receive() == "could not understand: 'no such command'"


def test_pause_halts_a_moving_program_and_play_finishes_the_move(world, fake, dash, rng):
    arm = world.arm
    q_goal = world.robot.home_q_rad + rng.choice([-1, 1], 6) * rng.uniform(0.3, 0.5, 6)
    fake.sim_add_program("sweep.urp", f"def sweep():\n  movej({q_goal.tolist()}, a=0.5, v=0.3)\nend\n")
    dash.loadURP("sweep.urp")
    dash.play()
    _wait(lambda: arm.state == "moving", what="motion start")
    t_mid = arm.moves[-1].t_start + 0.4 * (arm.moves[-1].t_end - arm.moves[-1].t_start)
    _wait(lambda: world.clock.now() > t_mid, what="mid-move")
    dash.pause()
    assert dash.programState().startswith("PAUSED")
    _wait(lambda: arm.state == "idle", what="halt after pause")
    t = world.clock.now()
    q_paused = arm.commanded_q_rad(t)
    assert np.max(np.abs(q_paused - q_goal)) > 0.05  # halted on the way, not at the goal
    _wait(lambda: world.clock.now() > t + 0.5, what="time to pass")
    np.testing.assert_allclose(arm.commanded_q_rad(world.clock.now()), q_paused, atol=1e-12)  # and stays there
    dash.play()
    _wait(lambda: dash.programState().startswith("STOPPED"), what="program end")
    np.testing.assert_allclose(arm.commanded_q_rad(world.clock.now()), q_goal, atol=1e-9)


def test_driver_power_cycle_and_trusted_play(world, fake, make_driver, rng):
    d = make_driver(fake, trusted_programs={"station_idle.urp"})
    st = d.power_off()
    assert st.robot_mode == 3 and not st.ready_to_move
    n_scripts = len(fake.scripts_received)
    with pytest.raises(DeviceNotReady, match="robot_mode 3"):
        d.move_joint(world.robot.home_q_rad + 0.1)
    assert len(fake.scripts_received) == n_scripts  # nothing sent to a powered-off robot
    st = d.power_on()
    assert st.robot_mode == 7 and st.ready_to_move
    fake.sim_add_program("unknown.urp", "def unknown():\n  sleep(1)\nend\n")
    d.load_program("unknown.urp")
    with pytest.raises(SafetyError, match="not in the driver's trusted_programs"):
        d.play()
    assert d.is_running() is False
    d.load_program("station_idle.urp")
    d.play()
    assert d.is_running() is True
    _wait(lambda: d.state().program_running, what="RTDE runtime_state PLAYING")
    d.pause()
    assert d.program_state().startswith("PAUSED")
    d.play()
    d.stop_program()
    assert d.is_running() is False
    with pytest.raises(DeviceError, match="refused: controller replied 'File not found: nope.urp'"):
        d.load_program("nope.urp")
    with pytest.raises(Exception, match="program name"):
        d.load_program("x.urp\nplay")  # nothing from a caller reaches the wire unchecked


def test_dashboard_refusal_and_refused_connection(world, make_fake, make_driver):
    fake = make_fake({"dashboard_refuse": "play,power"})
    d = make_driver(fake, trusted_programs={"station_idle.urp"})
    d.load_program("station_idle.urp")
    with pytest.raises(DeviceError, match="dashboard 'play' refused.*Failed to execute: play"):
        d.play()
    assert d.is_running() is False and d.state().robot_mode == 7
    with pytest.raises(DeviceError, match="'power off' refused.*Failed to execute: power off"):
        d.power_off()
    assert d.state().robot_mode == 7
    from drivers.ur import URDriver
    from station.safety import SafetyGate, default_limits

    closed = make_fake({"dashboard_refuse": "connect"})
    drv = URDriver(closed.endpoint["host"], world.robot, SafetyGate(world.robot, default_limits(world.robot)))
    with pytest.raises(ConnectionLost, match="dashboard"):
        drv.connect()
