"""Third-party clients judge the controller fake: plain ftplib and pymodbus."""

from __future__ import annotations

import ftplib
import io
import time
import zlib

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from station.programs import iso_pose_program, render_krl, render_rapid
from station.protocols.handshake import Command, Fault, RegisterMap, Result, State, encode_name, join_i32, join_u32

MAP = RegisterMap()


def ftp_login(fake) -> ftplib.FTP:
    e = fake.endpoint
    ftp = ftplib.FTP(timeout=5)
    ftp.connect(e["host"], e["ftp_port"])
    ftp.login(e["ftp_user"], e["ftp_password"])
    return ftp


def modbus(fake) -> ModbusTcpClient:
    c = ModbusTcpClient(fake.endpoint["host"], port=fake.endpoint["modbus_port"], timeout=3, retries=0)
    assert c.connect()
    return c


def read_status(c) -> dict:
    start, count = MAP.status_span()
    rr = c.read_holding_registers(start, count=count, device_id=MAP.device_id)
    assert not rr.isError(), rr
    r = rr.registers
    g = lambda name, k=0: r[getattr(MAP, name) - start + k]  # noqa: E731
    return {
        "ack": g("ack_seq"),
        "result": g("result"),
        "state": g("state"),
        "cycles": g("cycle_count"),
        "fault": g("fault_code"),
        "line": g("line"),
        "crc": join_u32(g("program_crc32"), g("program_crc32", 1)),
        "q_deg": np.array([join_i32(g("joint_mdeg", 2 * j), g("joint_mdeg", 2 * j + 1)) for j in range(6)]) / 1000.0,
        "moves": g("moves_done"),
    }


def command(c, cmd: Command, seq: int, timeout_s: float = 5.0) -> dict:
    rr = c.write_registers(MAP.command, [int(cmd), seq], device_id=MAP.device_id)
    assert not rr.isError(), rr
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        st = read_status(c)
        if st["ack"] == seq:
            return st
        time.sleep(0.01)
    raise AssertionError(f"{cmd.name} not acknowledged")


def wait_state(c, states, timeout_s: float = 20.0) -> dict:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        st = read_status(c)
        if st["state"] in states:
            return st
        time.sleep(0.01)
    raise AssertionError(f"state never reached {states}: {st}")


def test_ftp_with_plain_ftplib(rng, start_controller):
    fake = start_controller()
    data = bytes(rng.integers(32, 127, size=int(rng.integers(100, 5000)), dtype=np.uint8))
    ftp = ftp_login(fake)
    try:
        ftp.storbinary("STOR PROBE.mod", io.BytesIO(data))
        ftp.voidcmd("TYPE I")
        assert ftp.size("PROBE.mod") == len(data)
        got = bytearray()
        ftp.retrbinary("RETR PROBE.mod", got.extend)
        assert bytes(got) == data
        assert "PROBE.mod" in ftp.nlst()
        # the root is the program directory: ".." cannot leave it
        ftp.storbinary("STOR ../../escape.mod", io.BytesIO(b"x"))
    finally:
        ftp.quit()
    assert (fake.program_dir / "PROBE.mod").read_bytes() == data
    assert (fake.program_dir / "escape.mod").read_bytes() == b"x"
    assert not (fake.program_dir.parent / "escape.mod").exists()
    anon = ftplib.FTP(timeout=5)
    anon.connect(fake.endpoint["host"], fake.endpoint["ftp_port"])
    try:
        with pytest.raises(ftplib.error_perm, match="530"):
            anon.login("anonymous", "x@y")
    finally:
        anon.close()


def test_modbus_registers_with_pymodbus(start_controller, world):
    fake = start_controller()
    c = modbus(fake)
    try:
        st = read_status(c)
        assert st["state"] == State.NO_PROGRAM and st["fault"] == Fault.NONE
        q_home = np.degrees(world.robot.home_q_rad)
        assert np.allclose(st["q_deg"], q_home, atol=2e-3)
        # read-only registers refuse writes with exception 2 (illegal data address)
        rr = c.write_register(MAP.state, 4, device_id=MAP.device_id)
        assert rr.isError() and rr.exception_code == 2
        # a command without its sequence number is refused with exception 3
        rr = c.write_register(MAP.command, int(Command.START), device_id=MAP.device_id)
        assert rr.isError() and rr.exception_code == 3
        # reading beyond the map is an illegal address
        rr = c.read_holding_registers(MAP.highest + 1, count=2, device_id=MAP.device_id)
        assert rr.isError() and rr.exception_code == 2
        # select of a file that is not there
        c.write_registers(MAP.program_name, encode_name("NOPE.mod"), device_id=MAP.device_id)
        st = command(c, Command.SELECT, 7)
        assert st["result"] == Result.NO_SUCH_PROGRAM
        # path tricks in the name are not programs
        c.write_registers(MAP.program_name, encode_name("../x.mod"), device_id=MAP.device_id)
        assert command(c, Command.SELECT, 8)["result"] == Result.NO_SUCH_PROGRAM
        # the same sequence number again is not a new command
        c.write_registers(MAP.command, [int(Command.START), 8], device_id=MAP.device_id)
        assert read_status(c)["state"] == State.NO_PROGRAM
        assert command(c, Command.START, 9)["result"] == Result.NOT_ALLOWED
        assert command(c, 99, 10)["result"] == Result.UNKNOWN_COMMAND
    finally:
        c.close()


def test_program_uploaded_by_ftplib_runs_via_pymodbus(rng, start_controller, world, robot, iso_poses):
    """Generate -> plain FTP upload -> pymodbus select/start -> the arm runs the cycles."""
    fake = start_controller()
    cycles = int(rng.integers(2, 4))
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=cycles, dwell_s=0.5))
    data = r.text.encode()
    ftp = ftp_login(fake)
    ftp.storbinary(f"STOR {r.main_file}", io.BytesIO(data))
    ftp.quit()
    c = modbus(fake)
    try:
        c.write_registers(MAP.program_name, encode_name(r.main_file), device_id=MAP.device_id)
        st = command(c, Command.SELECT, 1)
        assert st["result"] == Result.OK and st["state"] == State.READY
        assert st["crc"] == zlib.crc32(data) & 0xFFFFFFFF
        t0 = world.clock.now()
        st = command(c, Command.START, 2)
        assert st["result"] == Result.OK
        st = wait_state(c, {State.FINISHED, State.FAULT})
        assert st["state"] == State.FINISHED, fake.sim_last_error()
        assert st["cycles"] == cycles and st["moves"] == 1 + 5 * cycles
    finally:
        c.close()
    # the arm stood still at every commanded pose during each dwell
    dwells = [m for m in world.arm.moves if m.kind == "dwell" and m.t_start >= t0]
    assert len(dwells) == 1 + 5 * cycles
    t_end = np.array([m.t_end for m in dwells]) - 1e-3
    order = ["P1"] + ["P2", "P3", "P4", "P5", "P1"] * cycles
    want = np.array([iso_poses[n] for n in order])
    got = world.arm.tool_position_mm(t_end)
    assert np.max(np.linalg.norm(got - want, axis=1)) < 0.05


def test_unsafe_and_broken_programs_are_refused_by_the_controller(start_controller, robot, iso_poses):
    """Programs that never passed the station's gate: the controller refuses them itself."""
    fake = start_controller()
    poses = dict(iso_poses)
    poses["P3"] = (500.0, 3500.0, 1900.0)  # outside the controller's reach
    unsafe = render_rapid(iso_pose_program(robot, poses, cycles=2, name="UNSAFE"))
    broken = "MODULE BROKEN\n  PROC main()\n    MoveJ pX, v100, fine, tool0;\n  ENDPROC\nENDMODULE\n"
    krl = render_krl(iso_pose_program(robot, iso_poses, cycles=2, name="KPROG"))
    ftp = ftp_login(fake)
    ftp.storbinary("STOR UNSAFE.mod", io.BytesIO(unsafe.text.encode()))
    ftp.storbinary("STOR BROKEN.mod", io.BytesIO(broken.encode()))
    for name, text in krl.files.items():
        ftp.storbinary(f"STOR {name}", io.BytesIO(text.encode()))
    ftp.quit()
    c = modbus(fake)
    try:
        c.write_registers(MAP.program_name, encode_name("UNSAFE.mod"), device_id=MAP.device_id)
        st = command(c, Command.SELECT, 1)
        assert st["result"] == Result.SAFETY_REFUSED and st["state"] == State.NO_PROGRAM
        assert "p_P3," in unsafe.text.splitlines()[st["line"] - 1]
        assert "not reachable" in fake.sim_last_error()
        c.write_registers(MAP.program_name, encode_name("BROKEN.mod"), device_id=MAP.device_id)
        st = command(c, Command.SELECT, 2)
        assert st["result"] == Result.PROGRAM_ERROR and st["line"] == 3
        c.write_registers(MAP.program_name, encode_name("KPROG.src"), device_id=MAP.device_id)
        assert command(c, Command.SELECT, 3)["result"] == Result.UNSUPPORTED_DIALECT
        assert command(c, Command.START, 4)["result"] == Result.NOT_ALLOWED
    finally:
        c.close()
