"""Pure codec of the Universal Robots RTDE protocol (version 2), server side.

Bytes in, packets out; packets to bytes. No I/O here: the UR fake
(:mod:`fakes.ur`) owns the sockets and this module is tested with plain bytes.

Wire format (all big-endian)::

    header   >HB    total size including the 3 header bytes, command byte
    'V' 86   request protocol version   payload >H version     reply >B accepted
    'v' 118  get controller version     payload (none)         reply >IIII
    'O' 79   setup outputs              payload >d freq + "n1,n2,"  reply >B id + "T1,T2"
    'I' 73   setup inputs               payload "n1,n2,"       reply >B id + "T1,T2"
    'S' 83   start                      payload (none)         reply >B success
    'P' 80   pause                      payload (none)         reply >B success
    'U' 85   data package               payload >B recipe id + values in recipe order
    'M' 77   text message               >B len + msg, >B len + source, >B level

A setup reply names ``NOT_FOUND`` for a variable the controller does not know
(recipe id 0) and ``IN_USE`` for an input already owned by another client.
The variable types below are those of the UR RTDE guide for PolyScope 5.11.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

import numpy as np

from station.errors import ProtocolError

HEADER = struct.Struct(">HB")
HEADER_SIZE = HEADER.size
MAX_PACKET_SIZE = 0xFFFF
PROTOCOL_VERSION = 2

CMD_REQUEST_PROTOCOL_VERSION = ord("V")
CMD_GET_URCONTROL_VERSION = ord("v")
CMD_TEXT_MESSAGE = ord("M")
CMD_DATA_PACKAGE = ord("U")
CMD_SETUP_OUTPUTS = ord("O")
CMD_SETUP_INPUTS = ord("I")
CMD_START = ord("S")
CMD_PAUSE = ord("P")

KNOWN_COMMANDS = frozenset(
    {
        CMD_REQUEST_PROTOCOL_VERSION,
        CMD_GET_URCONTROL_VERSION,
        CMD_TEXT_MESSAGE,
        CMD_DATA_PACKAGE,
        CMD_SETUP_OUTPUTS,
        CMD_SETUP_INPUTS,
        CMD_START,
        CMD_PAUSE,
    }
)

#: text message levels
MESSAGE_EXCEPTION, MESSAGE_ERROR, MESSAGE_WARNING, MESSAGE_INFO = 0, 1, 2, 3

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

#: RTDE type name -> struct format of one value
TYPE_FORMATS: dict[str, str] = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

#: RTDE type name -> big-endian numpy dtype of one value (for batch packing)
TYPE_DTYPES: dict[str, tuple] = {
    "BOOL": ("?", ()),
    "UINT8": ("u1", ()),
    "UINT32": (">u4", ()),
    "UINT64": (">u8", ()),
    "INT32": (">i4", ()),
    "DOUBLE": (">f8", ()),
    "VECTOR3D": (">f8", (3,)),
    "VECTOR6D": (">f8", (6,)),
    "VECTOR6INT32": (">i4", (6,)),
    "VECTOR6UINT32": (">u4", (6,)),
}

#: number of scalars one value of each type holds
TYPE_WIDTHS: dict[str, int] = {
    "BOOL": 1, "UINT8": 1, "UINT32": 1, "UINT64": 1, "INT32": 1, "DOUBLE": 1,
    "VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6,
}

_V6D, _V3D = "VECTOR6D", "VECTOR3D"

#: controller -> client variables with fixed names (UR RTDE guide, PolyScope 5.11)
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": _V6D, "target_qd": _V6D, "target_qdd": _V6D,
    "target_current": _V6D, "target_moment": _V6D,
    "actual_q": _V6D, "actual_qd": _V6D, "actual_current": _V6D,
    "actual_current_window": _V6D, "joint_control_output": _V6D,
    "actual_TCP_pose": _V6D, "actual_TCP_speed": _V6D, "actual_TCP_force": _V6D,
    "target_TCP_pose": _V6D, "target_TCP_speed": _V6D,
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6D,
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": _V3D,
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": _V6D,
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": _V3D,
    "elbow_velocity": _V3D,
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE", "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32", "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE", "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE", "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "payload": "DOUBLE",
    "payload_cog": _V3D,
    "payload_inertia": _V6D,
    "script_control_line": "UINT32",
    "ft_raw_wrench": _V6D,
    "joint_position_deviation_ratio": _V6D,
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "INT32",
}

#: client -> controller variables with fixed names
INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": _V6D,
}

_REGISTER = re.compile(r"^(input|output)_(bit|int|double)_register_(\d{1,3})$")
_REGISTER_TYPES = {"bit": "BOOL", "int": "INT32", "double": "DOUBLE"}
_REGISTER_RANGES = {"bit": range(64, 128), "int": range(0, 48), "double": range(0, 48)}


def _register_type(name: str, direction: str) -> str | None:
    m = _REGISTER.match(name)
    if m is None:
        return None
    kind, index = m.group(2), int(m.group(3))
    if index not in _REGISTER_RANGES[kind]:
        return None
    if m.group(1) == "input" or direction == m.group(1):
        return _REGISTER_TYPES[kind]
    return None


def output_type(name: str) -> str:
    """RTDE type of output variable ``name`` or ``NOT_FOUND``.

    Outputs are everything a client may read: the fixed table, output and
    input registers (a client may watch the input registers too).
    """
    return OUTPUT_TYPES.get(name) or _register_type(name, "output") or NOT_FOUND


def input_type(name: str) -> str:
    """RTDE type of input variable ``name`` (client writes) or ``NOT_FOUND``."""
    m = _REGISTER.match(name)
    if m is not None and m.group(1) == "output":
        return NOT_FOUND
    return INPUT_TYPES.get(name) or _register_type(name, "input") or NOT_FOUND


# ---------------------------------------------------------------- framing


@dataclass(frozen=True)
class Packet:
    """One RTDE packet: ``command`` byte and ``payload`` (header stripped)."""

    command: int
    payload: bytes


def decode(buf: bytes | bytearray | memoryview) -> tuple[int, Packet | None]:
    """Take one packet from the front of ``buf``.

    Returns
    -------
    (consumed, packet)
        ``(0, None)`` when ``buf`` holds less than one whole packet.

    Raises
    ------
    ProtocolError
        If the declared size is smaller than the header (the stream cannot be
        resynchronised) or the command byte is unknown.
    """
    if len(buf) < HEADER_SIZE:
        return 0, None
    size, command = HEADER.unpack_from(buf, 0)
    if size < HEADER_SIZE:
        raise ProtocolError(f"RTDE packet declares size {size} < header size {HEADER_SIZE}")
    if command not in KNOWN_COMMANDS:
        raise ProtocolError(f"RTDE packet has unknown command byte {command} (size {size})")
    if len(buf) < size:
        return 0, None
    return size, Packet(command, bytes(buf[HEADER_SIZE:size]))


def encode(command: int, payload: bytes = b"") -> bytes:
    """Frame ``payload`` as one packet of ``command``."""
    size = HEADER_SIZE + len(payload)
    if size > MAX_PACKET_SIZE:
        raise ProtocolError(f"RTDE payload of {len(payload)} bytes exceeds the 16-bit packet size")
    if not 0 <= command <= 255:
        raise ProtocolError(f"RTDE command byte {command} out of range")
    return HEADER.pack(size, command) + payload


# ---------------------------------------------------------------- requests


def parse_protocol_version_request(payload: bytes) -> int:
    """Protocol version a client asks for (``V`` payload, ``>H``)."""
    if len(payload) != 2:
        raise ProtocolError(f"RTDE request protocol version payload must be 2 bytes, got {len(payload)}")
    return struct.unpack(">H", payload)[0]


def _names(text: bytes, what: str) -> list[str]:
    try:
        s = text.decode("ascii")
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"RTDE {what}: variable names are not ASCII") from exc
    names = [n.strip() for n in s.split(",")]
    if names and names[-1] == "":
        names.pop()  # trailing comma
    if not names:
        raise ProtocolError(f"RTDE {what}: empty variable list")
    for n in names:
        if not n:
            raise ProtocolError(f"RTDE {what}: empty variable name in {s!r}")
    return names


def parse_setup_outputs(payload: bytes) -> tuple[float, list[str]]:
    """``O`` payload (protocol 2) -> (frequency_hz, variable names)."""
    if len(payload) < 9:
        raise ProtocolError(f"RTDE setup outputs payload too short: {len(payload)} bytes")
    (freq,) = struct.unpack_from(">d", payload, 0)
    if not (freq == freq) or freq <= 0:
        raise ProtocolError(f"RTDE setup outputs frequency must be > 0 Hz, got {freq!r}")
    return float(freq), _names(payload[8:], "setup outputs")


def parse_setup_inputs(payload: bytes) -> list[str]:
    """``I`` payload -> variable names."""
    return _names(payload, "setup inputs")


# ---------------------------------------------------------------- replies


def encode_protocol_version_reply(accepted: bool) -> bytes:
    return encode(CMD_REQUEST_PROTOCOL_VERSION, struct.pack(">B", 1 if accepted else 0))


def encode_controller_version(major: int, minor: int, bugfix: int, build: int) -> bytes:
    return encode(CMD_GET_URCONTROL_VERSION, struct.pack(">IIII", major, minor, bugfix, build))


def encode_setup_reply(command: int, recipe_id: int, types: list[str]) -> bytes:
    """Reply to ``O`` or ``I``: recipe id then the comma-separated types."""
    if command not in (CMD_SETUP_OUTPUTS, CMD_SETUP_INPUTS):
        raise ProtocolError(f"setup reply for command {command} is not a setup command")
    return encode(command, struct.pack(">B", recipe_id) + ",".join(types).encode("ascii"))


def encode_start_reply(success: bool) -> bytes:
    return encode(CMD_START, struct.pack(">B", 1 if success else 0))


def encode_pause_reply(success: bool) -> bytes:
    return encode(CMD_PAUSE, struct.pack(">B", 1 if success else 0))


def encode_text_message(message: str, source: str = "Controller", level: int = MESSAGE_ERROR) -> bytes:
    """``M`` packet: message, source and level (protocol 2 layout)."""
    msg = message.encode("utf-8", "replace")[:255]
    src = source.encode("utf-8", "replace")[:255]
    return encode(CMD_TEXT_MESSAGE, bytes([len(msg)]) + msg + bytes([len(src)]) + src + bytes([level & 0xFF]))


def parse_text_message(payload: bytes) -> tuple[str, str, int]:
    """``M`` payload -> (message, source, level)."""
    try:
        n = payload[0]
        msg = payload[1 : 1 + n]
        m = payload[1 + n]
        src = payload[2 + n : 2 + n + m]
        level = payload[2 + n + m]
    except IndexError as exc:
        raise ProtocolError(f"RTDE text message of {len(payload)} bytes is truncated") from exc
    if len(msg) != n or len(src) != m:
        raise ProtocolError(f"RTDE text message of {len(payload)} bytes is truncated")
    return msg.decode("utf-8", "replace"), src.decode("utf-8", "replace"), level


# ---------------------------------------------------------------- recipes


class Recipe:
    """A configured recipe: id, variable names and types, compiled to one struct.

    Parameters
    ----------
    recipe_id : int
        1..255 (0 means "setup failed" on the wire).
    names, types : list of str
        Same length; every type a key of :data:`TYPE_FORMATS`.
    """

    def __init__(self, recipe_id: int, names: list[str], types: list[str]) -> None:
        if not 1 <= recipe_id <= 255:
            raise ProtocolError(f"RTDE recipe id must be 1..255, got {recipe_id}")
        if len(names) != len(types):
            raise ProtocolError(f"RTDE recipe has {len(names)} names but {len(types)} types")
        bad = [n for n, t in zip(names, types) if t not in TYPE_FORMATS]
        if bad:
            raise ProtocolError(f"RTDE recipe has variables without a type: {', '.join(bad)}")
        self.recipe_id = recipe_id
        self.names = list(names)
        self.types = list(types)
        self.widths = [TYPE_WIDTHS[t] for t in types]
        self.struct = struct.Struct(">B" + "".join(TYPE_FORMATS[t] for t in types))
        self.packet_size = HEADER_SIZE + self.struct.size
        if self.packet_size > MAX_PACKET_SIZE:
            raise ProtocolError(f"RTDE recipe of {self.struct.size} bytes exceeds the packet size limit")
        self._header = HEADER.pack(self.packet_size, CMD_DATA_PACKAGE)
        fields = [("size", ">u2"), ("command", "u1"), ("recipe", "u1")]
        for i, t in enumerate(types):
            base, shape = TYPE_DTYPES[t]
            fields.append((f"v{i}", base, shape) if shape else (f"v{i}", base))
        #: one whole data packet (header included) per record, no padding
        self.packet_dtype = np.dtype(fields)
        if self.packet_dtype.itemsize != self.packet_size:
            raise ProtocolError(f"RTDE recipe {recipe_id}: packed size mismatch")

    def encode_batch(self, columns: dict, n: int) -> bytes:
        """``n`` consecutive data packets in one buffer, packed column-wise.

        Parameters
        ----------
        columns : dict
            Variable name -> value broadcastable to ``(n,)`` (scalars) or
            ``(n, width)`` (vectors).
        n : int
            Number of packets.
        """
        out = np.empty(n, dtype=self.packet_dtype)
        out["size"] = self.packet_size
        out["command"] = CMD_DATA_PACKAGE
        out["recipe"] = self.recipe_id
        for i, (name, width) in enumerate(zip(self.names, self.widths)):
            if name not in columns:
                raise ProtocolError(f"RTDE recipe {self.recipe_id}: no value for {name!r}")
            val = np.asarray(columns[name])
            try:
                out[f"v{i}"] = val if width == 1 else np.broadcast_to(val, (n, width))
            except ValueError as exc:
                raise ProtocolError(f"RTDE variable {name!r}: values of shape {val.shape} do not fit {n} packets") from exc
        return out.tobytes()

    def encode_flat(self, flat_values) -> bytes:
        """Data packet from the recipe's values already flattened in order."""
        try:
            return self._header + self.struct.pack(self.recipe_id, *flat_values)
        except struct.error as exc:
            raise ProtocolError(f"RTDE recipe {self.recipe_id}: cannot pack values: {exc}") from exc

    def encode(self, values: dict) -> bytes:
        """Data packet from ``{name: value}`` (vectors as sequences)."""
        flat: list = []
        for name, width in zip(self.names, self.widths):
            if name not in values:
                raise ProtocolError(f"RTDE recipe {self.recipe_id}: no value for {name!r}")
            v = values[name]
            if width == 1:
                flat.append(v)
            else:
                v = list(v)
                if len(v) != width:
                    raise ProtocolError(f"RTDE variable {name!r} needs {width} values, got {len(v)}")
                flat.extend(v)
        return self.encode_flat(flat)

    def decode(self, payload: bytes) -> dict:
        """``U`` payload of this recipe -> ``{name: value}`` (vectors as tuples)."""
        if len(payload) != self.struct.size:
            raise ProtocolError(
                f"RTDE data package for recipe {self.recipe_id} has {len(payload)} bytes, "
                f"expected {self.struct.size}"
            )
        flat = self.struct.unpack(payload)
        if flat[0] != self.recipe_id:
            raise ProtocolError(f"RTDE data package carries recipe id {flat[0]}, expected {self.recipe_id}")
        out: dict = {}
        i = 1
        for name, width in zip(self.names, self.widths):
            out[name] = flat[i] if width == 1 else tuple(flat[i : i + width])
            i += width
        return out


def data_recipe_id(payload: bytes) -> int:
    """Recipe id of a ``U`` payload."""
    if not payload:
        raise ProtocolError("RTDE data package has an empty payload (no recipe id)")
    return payload[0]
