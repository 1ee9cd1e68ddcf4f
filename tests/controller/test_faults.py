"""Every injected fault ends in a clear error and a safe state (program stopped, arm at rest)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from drivers.controller import ControllerFault, ModbusExceptionError, UploadVerificationError
from station.device_urls import parse_device_url
from station.errors import ConnectionLost, DeviceError, DeviceTimeout
from station.programs import expected_stops, iso_pose_program, render_rapid
from station.protocols.handshake import Fault, State
from tests.host_pause import pause_host


@pytest.fixture
def program(robot, iso_poses):
    return render_rapid(iso_pose_program(robot, iso_poses, cycles=4))


def assert_safe(fake, world, *, allowed=(State.STOPPED, State.READY, State.FAULT, State.NO_PROGRAM)):
    """Controller not running, arm at rest with nothing queued."""
    assert fake.core.state in allowed, fake.core.state
    world.arm.wait_idle(timeout_s=5.0)
    assert world.arm.state in ("idle", "protective_stop")
    t = world.clock.now()
    q0 = world.arm.commanded_q_rad(t)
    world.clock.sleep(2.0)  # two simulated seconds later it has not moved
    assert np.allclose(world.arm.commanded_q_rad(world.clock.now()), q0, atol=1e-12)


def wait_moves(drv, n, timeout_s=20.0):
    end = time.monotonic() + timeout_s
    while True:
        st = drv.status()
        if st.moves_done >= n:
            return st
        assert time.monotonic() < end, "the program did not progress"
        time.sleep(0.01)


@pytest.mark.parametrize("what, reply", [("login", "530"), ("stor", "550"), ("retr", "550"), ("size", "550")])
def test_ftp_refusals(start_controller, make_driver, world, program, what, reply):
    fake = start_controller({"ftp_refuse": what})
    drv = make_driver(fake)
    with pytest.raises(DeviceError, match=reply) as ei:
        drv.upload(program)
    assert "FTP" in str(ei.value) and not isinstance(ei.value, UploadVerificationError)
    assert world.arm.moves == []
    assert fake.core.state == State.NO_PROGRAM


@pytest.mark.parametrize("kind, match", [("flip", "sha256"), ("truncate", "bytes")])
def test_corrupted_upload_is_caught_by_read_back(start_controller, make_driver, world, program, kind, match):
    fake = start_controller({"ftp_corrupt": kind})
    drv = make_driver(fake)
    with pytest.raises(UploadVerificationError, match=match):
        drv.upload(program)
    with pytest.raises(Exception, match="no verified upload"):
        drv.select()
    assert world.arm.moves == []


@pytest.mark.parametrize("code", [4, 6])
def test_modbus_exception_on_start(start_controller, make_driver, world, program, code):
    fake = start_controller({"modbus_exception": str(code), "modbus_exception_on": "start"})
    drv = make_driver(fake)
    drv.upload(program)
    drv.select()
    with pytest.raises(ModbusExceptionError, match=f"exception code {code}") as ei:
        drv.start()
    assert ei.value.exception_code == code
    assert "STOP acknowledged" in str(ei.value) or "not running" in str(ei.value)
    assert_safe(fake, world)
    assert drv.status().moves_done == 0


def test_modbus_exception_while_running_stops_the_program(start_controller, make_driver, world, program):
    fake = start_controller({"modbus_exception": "4", "modbus_exception_on": "status", "modbus_exception_count": "1"})
    drv = make_driver(fake)
    drv.upload(program)
    drv.select()
    with pytest.raises(ModbusExceptionError, match="program stopped"):
        drv.start()  # the first status read of a running program may already be in start's handshake
        drv.wait_done(30.0)
    st = drv.status()
    assert st.state == State.STOPPED
    assert st.moves_done < len(expected_stops(program.program))
    assert_safe(fake, world)


def test_dropped_connection_while_running(start_controller, make_driver, world, program):
    fake = start_controller({"drop_connection": "status"})
    drv = make_driver(fake)
    drv.upload(program)
    drv.select()
    with pytest.raises(ConnectionLost, match="lost.*program stopped"):
        drv.start()
        drv.wait_done(30.0)
    assert drv.status().state == State.STOPPED
    assert_safe(fake, world)


def test_no_reply_is_a_timeout(start_controller, make_driver, world, program):
    fake = start_controller({"modbus_silent": "start"})
    drv = make_driver(fake, timeout_s=0.5)
    drv.upload(program)
    drv.select()
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="no reply .* within 0.5 s") as ei:
        drv.start()
    assert time.monotonic() - t0 < 5.0
    assert "program" in str(ei.value)
    assert drv.status().state != State.RUNNING
    assert_safe(fake, world)


def test_a_status_read_without_reply_is_asked_again_and_the_program_runs_on(start_controller, make_driver, world,
                                                                           program):
    """A status read is idempotent: when its reply does not come (the fake holds it until it closes), the
    driver asks again on a new connection within its deadline instead of stopping a healthy program."""
    fake = start_controller({"modbus_silent": "status"})
    drv = make_driver(fake, timeout_s=1.5)
    drv.upload(program)
    drv.select()
    drv.start()
    st = drv.wait_done(60.0)
    assert fake._modbus._silenced  # one reply was held back, and the run went on without it
    assert st.state == State.FINISHED and st.fault == Fault.NONE
    assert st.moves_done == len(expected_stops(program.program))


class _PausedHost(ModbusTcpClient):
    """pymodbus's client on a host that stops running this process for ``pause_s`` while the first read
    waits for its reply (a busy or paused machine)."""

    def __init__(self, *args, pause_s: float, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.pause_s, self.paused = pause_s, 0

    def recv(self, size):
        if not self.paused:
            self.paused += 1
            time.sleep(self.pause_s)
        return super().recv(size)


def test_a_read_whose_wait_the_host_did_not_run_through_is_asked_again(rng, start_controller, make_driver):
    """The first read gets no reply (the fake holds it), and the host does not run for longer than the whole
    deadline meanwhile: that silence was not the controller's, so the read is asked again (a soak run failed
    with 'no reply ... within 5 s' after a single attempt)."""
    fake = start_controller({"modbus_silent": "any"})  # the first request: connect's status read
    timeout_s = float(rng.uniform(0.6, 1.2))
    client = _PausedHost("127.0.0.1", port=parse_device_url(fake.url).int_option("modbus_port"),
                         timeout=timeout_s, retries=0, reconnect_delay=0,
                         pause_s=timeout_s + float(rng.uniform(0.2, 0.5)))
    drv = make_driver(fake, timeout_s=timeout_s, modbus_client=client)  # connect() reads the status
    assert client.paused == 1 and fake._modbus._silenced
    assert drv.status().state == State.NO_PROGRAM


# ---------------------------------------------------------------- a host that does not run (issue 46)
def _pause_host_in_a_read(monkeypatch, pause_s: float, *, silent: bool = False) -> dict:
    """Once ``hold["armed"]`` and the controller runs a program, the fake's next status reply goes out after
    this host was stopped for ``pause_s`` (the fake's server thread stops the whole process, driver included,
    then replies with the registers it read before): the controller answered at once, late only by the host's
    absence. ``hold["stale"]``: the registers that reply carries instead (a snapshot of the controller taken
    earlier, while its program ran). ``silent``: from then on the controller answers no read (until it
    closes)."""
    from fakes import controller as fake_controller

    hold = {"armed": False, "taken": 0, "stale": None}
    original = fake_controller._ModbusServer._action

    async def held(server, fc, start_address, address, count, registers, values):
        reply = await original(server, fc, start_address, address, count, registers, values)
        stale = hold["stale"]
        if hold["armed"] and values is None and (silent or stale is not None or server.core.state == State.RUNNING):
            if not hold["taken"]:
                hold["taken"] += 1
                if stale is not None:
                    for a in range(address, address + count):
                        registers[a - start_address] = stale.get(a, 0)
                pause_host(pause_s)
            if silent:
                import asyncio

                from pymodbus.constants import ExcCodes

                await asyncio.wait_for(server._closing.wait(), timeout=30.0)
                return ExcCodes.DEVICE_BUSY
        return reply

    monkeypatch.setattr(fake_controller._ModbusServer, "_action", held)
    return hold


def _run_beside_a_pause(monkeypatch, start_controller, make_driver, program, pause_s: float):
    """A fake controller running ``program`` and the pause of :func:`_pause_host_in_a_read` ready (not
    armed): (hold, fake, driver)."""
    hold = _pause_host_in_a_read(monkeypatch, pause_s)
    fake = start_controller()
    drv = make_driver(fake)
    drv.upload(render_rapid(program))
    drv.select()
    drv.start()
    return hold, fake, drv


def test_a_host_that_did_not_run_while_a_program_ran_is_no_timeout_of_the_program(rng, monkeypatch, start_controller,
                                                                                    make_driver, robot, iso_poses):
    """The controller said 'running' (its program then ended), and the host was stopped for a drawn 1.5-2.5
    times the program's timeout before the driver read that reply: the driver reads on and finds the
    program finished. Counting the host's wall time, it said 'program did not finish' every time. (The
    reply is a snapshot taken while the program ran, so the program's own pace on this host plays no part.)"""
    from drivers.controller import LISTEN_SLICE_S

    timeout_s = LISTEN_SLICE_S + float(rng.uniform(0.5, 1.0))
    pause_s = float(rng.uniform(1.5, 2.5)) * timeout_s
    hold, fake, drv = _run_beside_a_pause(monkeypatch, start_controller, make_driver,
                                          iso_pose_program(robot, iso_poses, cycles=1, speed_frac=0.5), pause_s)
    running = fake.core.snapshot()
    assert drv.status().state == State.RUNNING
    drv.wait_settled(60.0)  # the program ends on the controller; its 'running' reply is yet to be read
    hold["stale"], hold["armed"] = running, True
    started = time.monotonic()
    final = drv.wait_done(timeout_s)
    assert hold["taken"] == 1 and time.monotonic() - started > pause_s
    assert final.state == State.FINISHED and final.cycle_count == 1


def test_a_program_that_does_not_finish_still_times_out_beside_a_host_pause(rng, monkeypatch, start_controller,
                                                                              make_driver, world, robot, iso_poses):
    """A program far longer than the timeout, and the host stopped once meanwhile for longer than the
    timeout: 'program did not finish within T s', after T of polling beside the pause (it counted one slice
    at most), and the program is stopped."""
    from drivers.controller import LISTEN_SLICE_S

    timeout_s = float(rng.uniform(0.5, 1.0))
    pause_s = float(rng.uniform(1.5, 2.5)) * timeout_s
    hold, fake, drv = _run_beside_a_pause(monkeypatch, start_controller, make_driver,
                                          iso_pose_program(robot, iso_poses, cycles=30, speed_frac=0.1), pause_s)
    hold["armed"] = True
    started = time.monotonic()
    with pytest.raises(DeviceTimeout, match=rf"program did not finish within {timeout_s:g} s"):
        drv.wait_done(timeout_s)
    assert hold["taken"] == 1
    assert time.monotonic() - started >= pause_s + timeout_s - LISTEN_SLICE_S
    assert_safe(fake, world)


def test_a_silent_controller_still_times_out_beside_a_host_pause(rng, monkeypatch, start_controller, make_driver):
    """The controller answers no status read any more, and the host is stopped for longer than the driver's
    timeout during the first attempt: 'no reply ... within T s (3 attempts)', after the pause and the other
    attempts' waits (the paused one counted its own wait)."""
    timeout_s = float(rng.uniform(0.6, 1.2))
    pause_s = float(rng.uniform(1.5, 2.5)) * timeout_s
    hold = _pause_host_in_a_read(monkeypatch, pause_s, silent=True)
    fake = start_controller()
    drv = make_driver(fake, timeout_s=timeout_s)
    hold["armed"] = True
    started = time.monotonic()
    with pytest.raises(DeviceTimeout, match=rf"no reply .* within {timeout_s:g} s \(3 attempts\)"):
        drv.status()
    assert hold["taken"] == 1
    assert time.monotonic() - started >= pause_s + 2 * timeout_s / 3 * 0.99


@pytest.mark.parametrize("register", ["watchdog_ms", "command"])
def test_a_write_whose_reply_is_lost_is_no_failed_start(rng, monkeypatch, start_controller, make_driver, robot,
                                                         iso_poses, register):
    """The controller acts on START's write (or the watchdog's, written just before) but its reply does not
    come within the driver's timeout (it is 1.5-2.5 timeouts late): the watchdog is written again, START is
    not (its acknowledge says it arrived), and the program runs once to its end. A driver that took the
    missing reply for a failed write refused the start and stopped the program."""
    import asyncio

    from fakes import controller as fake_controller

    timeout_s = float(rng.uniform(0.4, 0.8))
    late_s = float(rng.uniform(1.5, 2.5)) * timeout_s
    hold = {"armed": False, "taken": 0}
    original = fake_controller._ModbusServer._action

    async def held(server, fc, start_address, address, count, registers, values):
        reply = await original(server, fc, start_address, address, count, registers, values)
        if hold["armed"] and values is not None and address == getattr(server.core.map, register) and not hold["taken"]:
            hold["taken"] += 1
            await asyncio.sleep(late_s)  # acted on, the reply lost on the way
        return reply

    monkeypatch.setattr(fake_controller._ModbusServer, "_action", held)
    fake = start_controller()
    drv = make_driver(fake, timeout_s=timeout_s)
    drv.upload(render_rapid(iso_pose_program(robot, iso_poses, cycles=1, speed_frac=0.5)))
    drv.select()
    hold["armed"] = True
    st = drv.start()
    assert hold["taken"] == 1
    assert st.state in (State.RUNNING, State.FINISHED) and st.fault == Fault.NONE
    final = drv.wait_done(60.0)
    assert final.state == State.FINISHED and final.cycle_count == 1
    assert sum(fake.core._runs_by_name.values()) == 1  # START acted on once


def test_missing_acknowledge_is_a_timeout(start_controller, make_driver, world, program):
    fake = start_controller({"ack_stall": "start"})
    drv = make_driver(fake, timeout_s=0.5)
    drv.upload(program)
    drv.select()
    with pytest.raises(DeviceTimeout, match="did not acknowledge START.*STOP acknowledged"):
        drv.start()
    assert drv.status().state == State.READY
    assert_safe(fake, world)
    assert world.arm.moves == []


@pytest.mark.parametrize("key, fault", [("protective_stop_move", Fault.PROTECTIVE_STOP), ("emergency_stop_move", Fault.EMERGENCY_STOP)])
def test_stop_in_the_middle_of_a_move(rng, start_controller, make_driver, world, robot, iso_poses, key, fault):
    n = int(rng.integers(2, 12))
    world.clock.set_time_scale(20.0)  # the fault must land inside a move of ~1.5 s: leave the fake time
    fake = start_controller({key: str(n)})
    drv = make_driver(fake)
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=4))
    moves = [ins for s in r.program.statements for ins in getattr(s, "body", (s,)) if hasattr(ins, "target")]
    order = [moves[0]] + moves[1:] * 4  # execution order of the moves
    drv.upload(r)
    drv.select()
    t0 = world.clock.now()
    drv.start()
    seen = []
    with pytest.raises(ControllerFault, match=fault.name) as ei:
        drv.wait_done(30.0, on_status=seen.append)
    st = ei.value.status
    assert st.fault == fault and st.state == State.FAULT
    assert st.moves_done == n - 1
    assert st.line == order[n - 1].source_line
    # what was reported before the fault is still there, and agrees with the error's status
    assert seen and seen[-1].moves_done == st.moves_done and seen[-1].cycle_count == st.cycle_count
    assert st.cycle_count == max(0, (n - 2) // 5)
    # the arm halted between the previous target and the n-th one, and stays there
    assert world.arm.state == "protective_stop"
    assert_safe(fake, world, allowed=(State.FAULT,))
    p_end = world.arm.tool_position_mm(np.array([world.clock.now()]))[0]
    a = np.array(order[n - 2].target.xyz_mm)
    b = np.array(order[n - 1].target.xyz_mm)
    stops = [m for m in world.arm.moves if m.kind == "stop" and m.t_start >= t0]
    motions = [m for m in world.arm.moves if m.kind in ("joint", "linear") and m.t_start >= t0]
    info = f"n={n} stops={[(m.t_start, m.t_end) for m in stops]} move={motions[n - 1].t_start, motions[n - 1].t_end}"
    assert len(stops) == 1, info
    assert np.linalg.norm(p_end - b) > 10.0 and np.linalg.norm(p_end - a) > 10.0, info
    # start is refused until the fault is reset; reset brings it back
    with pytest.raises(DeviceError, match="FAULT_ACTIVE"):
        drv.start()
    st = drv.reset()
    assert st.state == State.READY and st.fault == Fault.NONE
    assert world.arm.state == "idle"


def test_watchdog_stops_a_program_when_the_station_falls_silent(start_controller, make_driver, world, robot, iso_poses):
    program = render_rapid(iso_pose_program(robot, iso_poses, cycles=20))
    fake = start_controller()
    drv = make_driver(fake, watchdog_ms=150)
    drv.upload(program)
    drv.select()
    drv.start()
    wait_moves(drv, 1)
    drv.close()  # the station "crashes": no STOP, no more requests
    end = time.monotonic() + 10.0
    while fake.core.state == State.RUNNING:
        assert time.monotonic() < end, "watchdog did not stop the program"
        time.sleep(0.01)
    assert fake.core.state == State.FAULT and fake.core.fault == Fault.COMM_WATCHDOG
    assert fake.core.moves_done < len(expected_stops(program.program))
    assert_safe(fake, world, allowed=(State.FAULT,))


def _stalling_run(start_controller, make_driver, robot, iso_poses, *, keepalive_max_s, stall_s=None):
    """A 20-cycle run (about 4.6 s of host time) whose caller stalls in its first ``on_status`` after the
    first move: ``stall_s`` seconds, or (None) until the controller has stopped the program (at most 10 s).
    Returns (fake, driver, outcome, the stall's start and end on the host clock, the program's stops)."""
    program = render_rapid(iso_pose_program(robot, iso_poses, cycles=20))
    fake = start_controller()
    drv = make_driver(fake, watchdog_ms=600, keepalive_max_s=keepalive_max_s)
    stall = []

    def on_status(st):
        if stall or st.moves_done < 1:
            return
        t0 = time.monotonic()
        if stall_s is not None:
            time.sleep(stall_s)  # a journal commit stalled by a loaded disk: the station is alive, busy
        else:
            end = t0 + 10.0
            while fake.core.state == State.RUNNING and time.monotonic() < end:
                time.sleep(0.01)  # a caller that hangs
        stall.append((t0, time.monotonic()))

    try:
        outcome = drv.run(program, timeout_s=120.0, on_status=on_status)
    except ControllerFault as exc:
        outcome = exc
    return fake, drv, outcome, stall, len(expected_stops(program.program))


def test_a_caller_busy_in_on_status_keeps_the_program_running(start_controller, make_driver, world, robot, iso_poses):
    """The keep-alive speaks for the caller: a 2 s stall (3x the 0.6 s watchdog) in ``on_status`` does not stop
    the program, which finishes every move."""
    fake, drv, outcome, stall, _ = _stalling_run(start_controller, make_driver, robot, iso_poses,
                                                 keepalive_max_s=60.0, stall_s=2.0)
    assert not isinstance(outcome, ControllerFault), outcome
    assert outcome.state == State.FINISHED and fake.core.fault == Fault.NONE
    assert len(stall) == 1 and stall[0][1] - stall[0][0] >= 2.0
    assert drv.keepalive_reads >= 3  # a read every 0.15 s while the caller was away


@pytest.mark.parametrize("keepalive_max_s", [0.0, 1.2])
def test_a_caller_that_hangs_falls_silent_and_the_watchdog_stops_the_program(
    start_controller, make_driver, world, robot, iso_poses, keepalive_max_s
):
    """Without a keep-alive, or once it has spoken its ``keepalive_max_s``, a hung caller is a silent station:
    the controller's watchdog stops the program, and the run ends in the COMM_WATCHDOG fault."""
    fake, drv, outcome, stall, stops = _stalling_run(start_controller, make_driver, robot, iso_poses,
                                                     keepalive_max_s=keepalive_max_s)
    assert isinstance(outcome, ControllerFault), outcome
    assert outcome.status.fault == Fault.COMM_WATCHDOG and fake.core.fault == Fault.COMM_WATCHDOG
    t0, t1 = stall[0]
    # with a keep-alive, the program ran on for the keep-alive's time (2x the watchdog: impossible without it)
    # and was stopped once it was out (else the program would have finished)
    if keepalive_max_s:
        assert t1 - t0 >= keepalive_max_s and drv.keepalive_reads >= 1
    else:
        assert drv.keepalive_reads == 0
    assert outcome.status.moves_done < stops
    assert_safe(fake, world, allowed=(State.FAULT,))


def test_unknown_fault_keys_are_refused(start_controller):
    from station.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown fault 'ftp_refsue'"):
        start_controller({"ftp_refsue": "stor"})
    with pytest.raises(ConfigError, match="modbus_exception needs an integer"):
        start_controller({"modbus_exception": "busy"})
    with pytest.raises(ConfigError, match="loopback"):
        start_controller(host="::")  # the wildcard address: refused before anything binds
