"""The RTDE codec with plain bytes: framing, handshake payloads, recipes."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from fakes import rtde_protocol as rp
from station.errors import ProtocolError


def test_decode_waits_for_whole_packets_and_consumes_exactly_one():
    pkt = rp.encode(rp.CMD_START, b"")
    data = rp.encode_controller_version(5, 11, 0, 108318) + pkt
    for cut in range(0, 19):  # any prefix of the first packet is "need more"
        assert rp.decode(data[:cut]) == (0, None)
    n, p = rp.decode(data)
    assert n == 19 and p.command == rp.CMD_GET_URCONTROL_VERSION
    assert struct.unpack(">IIII", p.payload) == (5, 11, 0, 108318)
    n2, p2 = rp.decode(data[n:])
    assert n2 == 3 and p2 == rp.Packet(rp.CMD_START, b"")


@pytest.mark.parametrize("size", [0, 1, 2])
def test_declared_size_below_header_is_an_error(size):
    with pytest.raises(ProtocolError, match=f"size {size}"):
        rp.decode(struct.pack(">HB", size, rp.CMD_START))


def test_unknown_command_is_an_error_naming_it():
    with pytest.raises(ProtocolError, match="command byte 120"):
        rp.decode(struct.pack(">HB", 3, 120))


def test_oversized_payload_refused():
    with pytest.raises(ProtocolError, match="exceeds"):
        rp.encode(rp.CMD_TEXT_MESSAGE, b"x" * 65533)


def test_setup_outputs_parsing_as_ur_rtde_sends_it():
    payload = struct.pack(">d", 500.0) + b"timestamp,actual_q,actual_TCP_pose,"
    freq, names = rp.parse_setup_outputs(payload)
    assert freq == 500.0 and names == ["timestamp", "actual_q", "actual_TCP_pose"]
    with pytest.raises(ProtocolError, match="frequency"):
        rp.parse_setup_outputs(struct.pack(">d", -1.0) + b"timestamp,")
    with pytest.raises(ProtocolError, match="too short"):
        rp.parse_setup_outputs(b"\x00" * 8)
    with pytest.raises(ProtocolError, match="empty variable name"):
        rp.parse_setup_outputs(struct.pack(">d", 125.0) + b"timestamp,,actual_q")


def test_variable_types_follow_the_rtde_guide():
    assert rp.output_type("timestamp") == "DOUBLE"
    assert rp.output_type("actual_q") == "VECTOR6D"
    assert rp.output_type("actual_tool_accelerometer") == "VECTOR3D"
    assert rp.output_type("robot_mode") == "INT32"
    assert rp.output_type("joint_mode") == "VECTOR6INT32"
    assert rp.output_type("runtime_state") == "UINT32"
    assert rp.output_type("actual_digital_input_bits") == "UINT64"
    assert rp.output_type("output_int_register_47") == "INT32"
    assert rp.output_type("output_double_register_0") == "DOUBLE"
    assert rp.output_type("output_bit_register_64") == "BOOL"
    for bad in ("output_int_register_48", "output_bit_register_63", "actual_qq", "Timestamp"):
        assert rp.output_type(bad) == rp.NOT_FOUND
    assert rp.input_type("input_double_register_3") == "DOUBLE"
    assert rp.input_type("output_int_register_3") == rp.NOT_FOUND
    assert rp.input_type("speed_slider_fraction") == "DOUBLE"


def test_setup_reply_layout():
    b = rp.encode_setup_reply(rp.CMD_SETUP_OUTPUTS, 1, ["DOUBLE", "VECTOR6D"])
    assert b == struct.pack(">HB", 3 + 1 + 15, ord("O")) + b"\x01DOUBLE,VECTOR6D"


def test_recipe_round_trip_and_batch_equals_single_packets(rng):
    names = ["timestamp", "actual_q", "robot_mode", "joint_mode", "runtime_state",
             "actual_digital_output_bits", "payload_cog", "output_bit_register_64", "tool_output_mode"]
    types = [rp.output_type(n) for n in names]
    r = rp.Recipe(1, names, types)
    n = 7
    cols = {
        "timestamp": rng.uniform(0, 1e4, n),
        "actual_q": rng.normal(size=(n, 6)),
        "robot_mode": rng.integers(-1, 9, n),
        "joint_mode": rng.integers(235, 256, (n, 6)),
        "runtime_state": rng.integers(0, 6, n),
        "actual_digital_output_bits": rng.integers(0, 2**62, n),
        "payload_cog": rng.normal(size=(n, 3)),
        "output_bit_register_64": rng.integers(0, 2, n).astype(bool),
        "tool_output_mode": rng.integers(0, 256, n),
    }
    batch = r.encode_batch(cols, n)
    assert len(batch) == n * r.packet_size
    off = 0
    for i in range(n):
        k, pkt = rp.decode(batch[off:])
        assert k == r.packet_size and pkt.command == rp.CMD_DATA_PACKAGE
        single = r.encode({name: (v[i] if np.ndim(v) else v) for name, v in cols.items()})
        assert batch[off:off + k] == single
        got = r.decode(pkt.payload)
        assert got["timestamp"] == cols["timestamp"][i]
        assert got["actual_q"] == tuple(cols["actual_q"][i])
        assert got["joint_mode"] == tuple(int(x) for x in cols["joint_mode"][i])
        assert got["actual_digital_output_bits"] == int(cols["actual_digital_output_bits"][i])
        off += k


def test_recipe_decode_refuses_wrong_sizes_and_ids():
    r = rp.Recipe(2, ["input_int_register_0", "input_double_register_1"], ["INT32", "DOUBLE"])
    payload = r.encode({"input_int_register_0": 7, "input_double_register_1": 0.5})[3:]
    assert r.decode(payload) == {"input_int_register_0": 7, "input_double_register_1": 0.5}
    with pytest.raises(ProtocolError, match="has 12 bytes, expected 13"):
        r.decode(payload[:-1])
    with pytest.raises(ProtocolError, match="recipe id 3"):
        r.decode(b"\x03" + payload[1:])
    with pytest.raises(ProtocolError, match="without a type"):
        rp.Recipe(1, ["x"], [rp.NOT_FOUND])


def test_text_message_round_trip_and_truncation():
    b = rp.encode_text_message("Compile error: line 3", "Controller", rp.MESSAGE_ERROR)
    _, p = rp.decode(b)
    assert rp.parse_text_message(p.payload) == ("Compile error: line 3", "Controller", rp.MESSAGE_ERROR)
    with pytest.raises(ProtocolError, match="truncated"):
        rp.parse_text_message(p.payload[:5])
