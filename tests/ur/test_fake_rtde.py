"""``ur_rtde``'s own RTDEReceiveInterface judges the fake's RTDE server."""

from __future__ import annotations

import socket
import struct
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fakes import rtde_protocol as rp
from station.models import kinematics
from tests.ur.conftest import finish_probe, run_probe, start_probe


def _expected_pose(world, q: np.ndarray) -> np.ndarray:
    """What a controller reports: nominal FK of the measured joints, m + rotation vector."""
    T = kinematics.fk(world.robot.dh_nominal, q)
    return np.hstack([T[:, :3, 3] / 1000.0, Rotation.from_matrix(T[:, :3, :3]).as_rotvec()])


@pytest.mark.parametrize("frequency_hz", [125.0, 500.0])
def test_ur_rtde_reads_true_joints_and_pose_at_the_requested_rate(world, fake, rng, frequency_hz):
    arm = world.arm
    world.clock.set_time_scale(1.0)  # real time, so the probe can see consecutive samples
    # the probe polls ur_rtde's latest sample: on a busy host it catches only some of them (20 of 300 in 0.6 s
    # at 500 Hz beside two busy processes), so it samples on until it has 50 rows and a consecutive pair
    probe = start_probe(fake.endpoint["host"], frequency_hz, 0.6, min_rows=50)
    # move while the client samples, so the values change from sample to sample: once the stream has started
    deadline = time.monotonic() + 20.0
    while fake.packets_sent == 0 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert fake.packets_sent > 0, "the probe's RTDE stream did not start within 20 s"
    q_goal = world.robot.home_q_rad + rng.uniform(-0.4, 0.4, 6)
    arm.move_joint(q_goal, speed_frac=0.5, accel_frac=1.0)
    report = finish_probe(probe)
    assert "error" not in report, report
    rows = np.array(report["rows"])
    assert len(rows) >= 50, len(rows)
    t, q, pose = rows[:, 0], rows[:, 1:7], rows[:, 7:13]
    # timestamps are the world's clock on a grid of 1/f: every gap a whole number of periods
    period = 1.0 / frequency_hz
    k = np.diff(t) / period
    assert np.all(k >= 1 - 1e-6), k.min()
    assert np.allclose(k, np.round(k), atol=1e-6)
    assert np.min(np.round(k)) == 1  # consecutive samples were seen: nothing faster, nothing coarser
    # the values are the arm's truth at those timestamps, bit for bit through the wire
    np.testing.assert_allclose(q, arm.actual_q_rad(t), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pose, _expected_pose(world, q), rtol=0, atol=1e-9)
    assert np.ptp(q, axis=0).max() > 0.01  # the arm really moved during the sampling
    assert report["robot_mode"] == 7 and report["safety_mode"] == 1
    assert report["joint_mode"] == [253] * 6 and report["speed_scaling"] == 1.0
    assert report["protective_stopped"] is False


def test_custom_variable_list_and_not_found(fake):
    ok = run_probe(fake.endpoint["host"], 125.0, 0.1, ["timestamp", "actual_q", "actual_TCP_pose"])
    assert "error" not in ok and len(ok["rows"]) >= 1
    bad = run_probe(fake.endpoint["host"], 125.0, 0.1, ["timestamp", "actual_qq"])
    assert "error" in bad and "actual_qq" in bad["error"]


def _raw(host):
    s = socket.create_connection((host, 30004), timeout=5)
    buf = bytearray()

    def ask(cmd, payload=b""):
        s.sendall(rp.encode(cmd, payload))
        while True:
            n, p = rp.decode(buf)
            if n:
                del buf[:n]
                return p
            buf.extend(s.recv(65536))

    return s, ask


def test_handshake_replies_in_use_and_frequency_cap(fake):
    host = fake.endpoint["host"]
    s1, ask1 = _raw(host)
    s2, ask2 = _raw(host)
    try:
        assert ask1(rp.CMD_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2)).payload == b"\x01"
        assert ask1(rp.CMD_REQUEST_PROTOCOL_VERSION, struct.pack(">H", 3)).payload == b"\x00"
        major, minor, *_ = struct.unpack(">IIII", ask1(rp.CMD_GET_URCONTROL_VERSION).payload)
        assert (major, minor) >= (5, 11)
        p = ask1(rp.CMD_SETUP_INPUTS, b"input_int_register_30,input_double_register_30")
        assert p.payload == b"\x01INT32,DOUBLE"
        p = ask2(rp.CMD_SETUP_INPUTS, b"input_int_register_30,input_int_register_31")
        assert p.payload == b"\x00IN_USE,INT32"  # another client owns register 30
        p = ask2(rp.CMD_SETUP_OUTPUTS, struct.pack(">d", 1000.0) + b"timestamp")
        assert p.payload[0] == 0  # above the 500 Hz e-Series limit: no recipe
        p = ask2(rp.CMD_SETUP_OUTPUTS, struct.pack(">d", 10.0) + b"timestamp,input_int_register_30")
        assert p.payload == b"\x01DOUBLE,INT32"
        # client 1 writes its input register, client 2 sees it in its output stream
        assert ask1(rp.CMD_START).payload == b"\x01"
        s1.sendall(rp.Recipe(1, ["input_int_register_30", "input_double_register_30"], ["INT32", "DOUBLE"])
                   .encode({"input_int_register_30": 4242, "input_double_register_30": 1.5}))
        assert ask2(rp.CMD_START).payload == b"\x01"
        recipe = rp.Recipe(1, ["timestamp", "input_int_register_30"], ["DOUBLE", "INT32"])
        buf, got = bytearray(), None
        for _ in range(200):
            buf.extend(s2.recv(65536))
            while True:
                n, pkt = rp.decode(buf)
                if not n:
                    break
                del buf[:n]
                if pkt.command == rp.CMD_DATA_PACKAGE:
                    got = recipe.decode(pkt.payload)
            if got and got["input_int_register_30"] == 4242:
                break
        assert got is not None and got["input_int_register_30"] == 4242
    finally:
        s1.close()
        s2.close()


def test_garbage_gets_a_text_message_and_a_closed_link_and_the_fake_keeps_serving(fake):
    host = fake.endpoint["host"]
    s = socket.create_connection((host, 30004), timeout=5)
    try:
        s.sendall(struct.pack(">HB", 1, ord("V")))  # declared size below the header
        buf = bytearray()
        while True:
            data = s.recv(4096)
            if not data:
                break
            buf.extend(data)
        n, pkt = rp.decode(buf)
        assert pkt.command == rp.CMD_TEXT_MESSAGE
        msg, _source, level = rp.parse_text_message(pkt.payload)
        assert "declares size 1" in msg and level == rp.MESSAGE_ERROR
    finally:
        s.close()
    assert fake.protocol_errors and "declares size 1" in fake.protocol_errors[0]
    ok = run_probe(host, 125.0, 0.05, ["timestamp", "actual_q", "actual_TCP_pose"])
    assert "error" not in ok and ok["rows"]

