"""End to end: generate -> gate -> FTP upload (read back) -> Modbus handshake -> the arm moves."""

from __future__ import annotations

import ftplib
import hashlib
import io
import time

import numpy as np
import pytest

from drivers.controller import CommandRefused, ControllerDriver
from fakes.sim.arm import IN_POSITION_RAD
from station.errors import ConfigError, ConnectionLost, SafetyError
from station.programs import iso_pose_program, render_krl, render_rapid, vap_program
from station.protocols.handshake import Result, State


def _dwell_positions(world, t0):
    """(times, positions) of the arm at the end of every dwell since t0."""
    dwells = [m for m in world.arm.moves if m.kind == "dwell" and m.t_start >= t0]
    t = np.array([m.t_end for m in dwells]) - 1e-3
    return t, world.arm.tool_position_mm(t)


def test_iso_cycle_end_to_end(rng, start_controller, make_driver, world, robot, iso_poses):
    fake = start_controller()
    drv = make_driver(fake)
    cycles = int(rng.integers(2, 5))
    speed = float(rng.uniform(0.3, 0.5))  # slow enough that no joint limit slows the P2 -> P3 line
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=cycles, speed_frac=speed))
    seen = []
    t0 = world.clock.now()
    final = drv.run(r, timeout_s=30.0, on_status=seen.append)
    assert final.state == State.FINISHED and final.cycle_count == cycles
    assert final.moves_done == 1 + 5 * cycles
    # progress was reported along the way, monotonically
    counts = [s.cycle_count for s in seen]
    assert counts == sorted(counts) and counts[-1] == cycles
    # what the controller holds is byte for byte what was generated
    assert (fake.program_dir / r.main_file).read_bytes() == r.text.encode()
    # the arm stood at each commanded target at the end of every dwell
    order = ["P1"] + ["P2", "P3", "P4", "P5", "P1"] * cycles
    t, got = _dwell_positions(world, t0)
    want = np.array([iso_poses[n] for n in order])
    assert got.shape == want.shape
    assert np.max(np.linalg.norm(got - want, axis=1)) < 0.05
    # linear moves at the commanded speed: the P2 -> P3 line cruises at the programmed v_tcp
    moves = [m for m in world.arm.moves if m.kind == "linear" and m.t_start >= t0]
    tt = np.linspace(moves[1].t_start, moves[1].t_end, 2001)
    p = world.arm.commanded_tool_pose(tt)[:, :3, 3]
    assert np.allclose(p[[0, -1]], [iso_poses["P2"], iso_poses["P3"]], atol=1e-3)
    v = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(tt)
    assert v.max() == pytest.approx(speed * robot.max_tcp_speed_mm_s, rel=0.01)
    # and the joints the controller reports are where the arm stands
    assert np.allclose(final.q_deg, np.degrees(world.arm.actual_q_rad(world.clock.now())), atol=2e-3)


def test_the_time_a_caller_spends_on_a_status_is_not_the_programs(rng, start_controller, make_driver, world, robot,
                                                                   iso_poses):
    """The caller's journal write blocks (a disk stalled in a sync, seen in a soak: 30 s in one COMMIT) past the
    program's timeout while the program finishes: the driver reports it finished, not "did not finish"."""
    fake = start_controller()
    drv = make_driver(fake)
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=1, speed_frac=0.5))
    timeout_s = float(rng.uniform(0.5, 1.5))
    blocked = []

    def on_status(st):
        if st.state == State.RUNNING and not blocked:
            t0 = time.monotonic()
            # held until the program has ended on the controller and the timeout has passed (at most 60 s)
            while (fake.core.state != State.FINISHED or time.monotonic() - t0 < 1.5 * timeout_s) \
                    and time.monotonic() - t0 < 60.0:
                time.sleep(0.01)
            blocked.append(time.monotonic() - t0)

    final = drv.run(r, timeout_s=timeout_s, on_status=on_status)
    assert blocked and blocked[0] > timeout_s
    assert final.state == State.FINISHED and final.cycle_count == 1


def test_a_program_ends_with_the_arm_in_position(rng, start_controller, make_driver, world):
    """A fine stop point (RAPID's ``fine`` zone): the controller reports the move done, and its program finished,
    once the arm is in position, not when the command arrived; the servo's lag then (~1e-3 rad after a move of
    a tenth of a radian) is gone. The move's size, direction and speed are drawn."""
    fake = start_controller()
    drv = make_driver(fake)
    q0 = drv.joints_rad()
    target = q0 + rng.choice([-1.0, 1.0], 6) * rng.uniform(0.03, 0.1, 6)
    final = drv.move_to(target, speed_frac=float(rng.uniform(0.05, 0.25)))  # under the gate's TCP speed cap
    assert final.state == State.FINISHED and final.moves_done == 1
    t_done = world.arm.queue_end_s  # where the controller's program ended
    q_done, q_rest = world.arm.actual_q_rad(np.array([t_done, t_done + 5.0]))
    assert np.max(np.abs(q_done - q_rest)) < 1.5 * IN_POSITION_RAD, np.abs(q_done - q_rest)
    np.testing.assert_allclose(q_rest, target, atol=1e-3)  # the arm's own stop scatter: none in this world


def test_the_tracker_sees_the_run(start_controller, make_driver, world, robot, iso_poses):
    """The world's tracker measures the stops of a vAP run at the commanded poses."""
    fake = start_controller()
    drv = make_driver(fake)
    sub = {n: iso_poses[n] for n in ("P1", "P2", "P4")}
    prog = vap_program(robot, sub, cycles=2, approach_mm=80.0, pre_dwell_s=0.0)
    t0 = world.clock.now()
    drv.run(render_rapid(prog), timeout_s=30.0)
    t, _ = _dwell_positions(world, t0)
    xyz_tracker, valid = world.tracker_source().measure(t)
    assert np.all(valid)
    T = world.base_T_tracker
    in_base = xyz_tracker @ T[:3, :3].T + T[:3, 3]
    want = np.array([iso_poses[n] for n in ("P1", "P2", "P4") for _ in range(3)] * 2)
    assert np.max(np.linalg.norm(in_base - want, axis=1)) < 0.2  # tracker MPE ~ 30 um


def test_unsafe_program_never_leaves_the_host(start_controller, make_driver, world, robot, iso_poses, gate):
    fake = start_controller()
    drv = make_driver(fake)
    poses = dict(iso_poses)
    poses["P5"] = (-500.0, 1200.0, gate.box_min[2] - 30.0)
    r = render_rapid(iso_pose_program(robot, poses, cycles=2))
    with pytest.raises(SafetyError, match="move to P5") as ei:
        drv.upload(r)
    line = int(str(ei.value).split(":")[0].split()[1])
    assert "p_P5," in r.text.splitlines()[line - 1]
    assert list(fake.program_dir.iterdir()) == []
    assert world.arm.moves == []
    with pytest.raises(SafetyError, match="RenderedProgram"):
        drv.upload(r.text)
    with pytest.raises(SafetyError, match="no verified upload"):
        drv.select()
    with pytest.raises(SafetyError, match="no gated"):
        drv.start()


def test_program_replaced_on_the_controller_is_not_started(start_controller, make_driver, world, robot, iso_poses):
    """Select checks the controller's CRC-32 against the verified upload."""
    fake = start_controller()
    drv = make_driver(fake)
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=2))
    receipt = drv.upload(r)
    assert receipt.files[r.main_file].sha256 == hashlib.sha256(r.text.encode()).hexdigest()
    other = render_rapid(iso_pose_program(robot, iso_poses, cycles=9))
    e = fake.endpoint
    ftp = ftplib.FTP(timeout=5)
    ftp.connect(e["host"], e["ftp_port"])
    ftp.login(e["ftp_user"], e["ftp_password"])
    ftp.storbinary(f"STOR {r.main_file}", io.BytesIO(other.text.encode()))
    ftp.quit()
    with pytest.raises(SafetyError, match="CRC-32"):
        drv.select()
    with pytest.raises(SafetyError):
        drv.start()
    assert world.arm.moves == []


def test_krl_upload_is_verified_but_this_controller_runs_rapid(start_controller, make_driver, robot, iso_poses):
    fake = start_controller()
    drv = make_driver(fake)
    k = render_krl(iso_pose_program(robot, iso_poses, cycles=2))
    receipt = drv.upload(k)
    assert set(receipt.files) == set(k.files)
    for name, text in k.files.items():
        assert (fake.program_dir / name).read_bytes() == text.encode()
        assert receipt.files[name].size == len(text.encode())
    with pytest.raises(CommandRefused, match="UNSUPPORTED_DIALECT") as ei:
        drv.select(receipt)
    assert ei.value.result == Result.UNSUPPORTED_DIALECT


def test_stop_in_the_middle_of_a_run(start_controller, make_driver, world, robot, iso_poses):
    fake = start_controller()
    drv = make_driver(fake)
    cycles = 6
    drv.upload(render_rapid(iso_pose_program(robot, iso_poses, cycles=cycles)))
    drv.select()
    drv.start()
    deadline = time.monotonic() + 20.0
    while drv.status().moves_done < 3:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    st = drv.stop()
    assert st.state == State.STOPPED
    assert 3 <= st.moves_done < 1 + 5 * cycles
    assert world.arm.state == "idle"
    q_stop = world.arm.commanded_q_rad(world.clock.now())
    # the servo lags a moving command: stopped at speed (where the host's polling happened to stop it), the
    # tool settles onto the frozen command within a few of the loop's time constants; then it stays
    world.clock.sleep(0.5)
    p_stop = world.arm.tool_position_mm(np.array([world.clock.now()]))[0]
    world.clock.sleep(1.0)
    assert np.array_equal(world.arm.commanded_q_rad(world.clock.now()), q_stop)  # nothing queued
    p_later = world.arm.tool_position_mm(np.array([world.clock.now()]))[0]
    assert np.linalg.norm(p_later - p_stop) < 0.01  # at rest
    # the program can be started again after a stop
    drv.start()
    final = drv.wait_done(60.0)
    assert final.state == State.FINISHED and final.cycle_count == cycles


def test_driver_configuration_errors(gate):
    with pytest.raises(ConfigError, match="modbus\\+ftp"):
        ControllerDriver.from_url("ftp://127.0.0.1", gate=gate)
    with pytest.raises(ConfigError, match="unknown option"):
        ControllerDriver.from_url("modbus+ftp://127.0.0.1?modbus=1", gate=gate)
    with pytest.raises(ConfigError, match="safety gate"):
        ControllerDriver("127.0.0.1", gate=None)
    with pytest.raises(ConfigError, match="timeout_s"):
        ControllerDriver("127.0.0.1", gate=gate, timeout_s=0)


def test_no_controller_is_a_clear_connection_error(gate):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    drv = ControllerDriver("127.0.0.1", gate=gate, modbus_port=port, timeout_s=1.0)
    with pytest.raises(ConnectionLost, match=f"127.0.0.1:{port}"):
        drv.connect()


def test_status_polls_start_quick_and_settle_at_the_poll_interval():
    from itertools import islice

    from drivers.controller import poll_pauses

    assert list(islice(poll_pauses(0.02), 7)) == pytest.approx([0.002, 0.004, 0.008, 0.016, 0.02, 0.02, 0.02])
    assert list(islice(poll_pauses(0.001), 3)) == [0.001] * 3  # never longer than the interval asked for
    # a long program is polled at the interval: after 5 ramp pauses (2 + 4 + 8 + 16 + 32 ms), 50 ms each
    assert sum(islice(poll_pauses(0.05), 1000)) == pytest.approx(0.062 + 995 * 0.05, rel=1e-12)
