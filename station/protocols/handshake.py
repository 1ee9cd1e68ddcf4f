"""The controller's Modbus TCP interface: register map and codes.

One block of holding registers (function codes 3 read, 6/16 write) carries
the whole handshake between the station (Modbus client) and the robot
controller (Modbus server). :class:`RegisterMap` holds the addresses; the
station config embeds it so a cell whose PLC mapping differs only edits
numbers. The default layout (offsets from ``base``):

====  ===============  ====  =====================================================
addr  name             dir   meaning
====  ===============  ====  =====================================================
0     command          W     :class:`Command` code (written together with 1)
1     command_seq      W     client's sequence number of that command, 1..65535
2     watchdog_ms      W     comm watchdog: a running program is stopped when no
                             Modbus request arrives for this long (0 = off)
3-18  program_name     W     selected file name, ASCII, 2 chars per register,
                             high byte first, NUL padded (32 chars)
20    ack_seq          R     ``command_seq`` of the last command processed
21    result           R     :class:`Result` of that command
22    state            R     :class:`State` of the controller
23    cycle_count      R     finished cycles (group output ``go_cycle_count``)
24    fault_code       R     :class:`Fault` (0 = none)
25    line             R     program line running, or the line refused/faulted
26-27 program_crc32    R     CRC-32 of the selected file, high word first
28-39 joint_mdeg       R     6 x int32 actual joint angles, millidegrees,
                             two's complement, high word first
40    moves_done       R     motion instructions completed since start
====  ===============  ====  =====================================================

Handshake (each step with a timeout on the monotonic clock):

1. select: write ``program_name``; then write ``[command, command_seq]`` in
   one request (FC 16) with ``Command.SELECT`` and a new sequence number;
2. poll ``ack_seq`` until it equals the sequence number, then read
   ``result`` (0 = OK); after a select ``program_crc32`` names the loaded
   file, which the station compares with what it uploaded;
3. start / stop / reset the same way; while running poll ``state``,
   ``cycle_count``, ``fault_code`` and ``line``.

A controller that sees a command with the sequence number it already
acknowledged does nothing (a repeated write after a lost reply is harmless).
Writes to read-only registers are refused with Modbus exception 2.
"""

from __future__ import annotations

import enum
from typing import ClassVar

from pydantic import BaseModel, ConfigDict, Field, model_validator

from station.errors import ConfigError

#: registers of the program name field (2 ASCII characters each)
PROGRAM_NAME_REGS = 16
#: number of joint registers (6 joints x int32)
JOINT_REGS = 12


class Command(enum.IntEnum):
    NONE = 0
    SELECT = 1
    START = 2
    STOP = 3
    RESET = 4


class Result(enum.IntEnum):
    OK = 0
    UNKNOWN_COMMAND = 1
    NO_SUCH_PROGRAM = 2
    PROGRAM_ERROR = 3
    SAFETY_REFUSED = 4
    NOT_ALLOWED = 5
    FAULT_ACTIVE = 6
    UNSUPPORTED_DIALECT = 7


class State(enum.IntEnum):
    NO_PROGRAM = 0
    READY = 1
    RUNNING = 2
    STOPPED = 3
    FINISHED = 4
    FAULT = 5


class Fault(enum.IntEnum):
    NONE = 0
    EMERGENCY_STOP = 1
    PROTECTIVE_STOP = 2
    PROGRAM_ERROR = 3
    COMM_WATCHDOG = 4
    SAFETY = 5


def describe(enum_cls: type[enum.IntEnum], value: int) -> str:
    """``"PROTECTIVE_STOP (2)"``, or ``"unknown code 99"``."""
    try:
        return f"{enum_cls(value).name} ({int(value)})"
    except ValueError:
        return f"unknown {enum_cls.__name__.lower()} code {int(value)}"


class RegisterMap(BaseModel):
    """Addresses of the handshake registers (holding registers, 0-based).

    Every field is an absolute register address; multi-register fields
    (``program_name``: 16, ``program_crc32``: 2, ``joint_mdeg``: 12) start
    there. The validator refuses overlapping fields and addresses beyond
    65535. ``device_id`` is the Modbus unit id the controller answers.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    device_id: int = Field(1, ge=0, le=255)
    command: int = Field(0, ge=0, le=65535)
    command_seq: int = Field(1, ge=0, le=65535)
    watchdog_ms: int = Field(2, ge=0, le=65535)
    program_name: int = Field(3, ge=0, le=65535)
    ack_seq: int = Field(20, ge=0, le=65535)
    result: int = Field(21, ge=0, le=65535)
    state: int = Field(22, ge=0, le=65535)
    cycle_count: int = Field(23, ge=0, le=65535)
    fault_code: int = Field(24, ge=0, le=65535)
    line: int = Field(25, ge=0, le=65535)
    program_crc32: int = Field(26, ge=0, le=65535)
    joint_mdeg: int = Field(28, ge=0, le=65535)
    moves_done: int = Field(40, ge=0, le=65535)

    #: field -> number of registers
    WIDTHS: ClassVar[dict[str, int]] = {"program_name": PROGRAM_NAME_REGS, "program_crc32": 2, "joint_mdeg": JOINT_REGS}
    #: fields the station writes; every other field is read-only
    WRITABLE: ClassVar[tuple[str, ...]] = ("command", "command_seq", "watchdog_ms", "program_name")

    @classmethod
    def fields(cls) -> tuple[str, ...]:
        return tuple(n for n in cls.model_fields if n != "device_id")

    def span(self, name: str) -> range:
        start = getattr(self, name)
        return range(start, start + self.WIDTHS.get(name, 1))

    @model_validator(mode="after")
    def _no_overlap(self) -> "RegisterMap":
        owner: dict[int, str] = {}
        for name in self.fields():
            r = self.span(name)
            if r.stop - 1 > 65535:
                raise ValueError(f"{name}: registers {r.start}..{r.stop - 1} run past 65535")
            for a in r:
                if a in owner:
                    raise ValueError(f"{name} overlaps {owner[a]} at register {a}")
                owner[a] = name
        if self.command_seq != self.command + 1:
            raise ValueError("command_seq must directly follow command (both are written in one request)")
        return self

    @property
    def lowest(self) -> int:
        return min(getattr(self, n) for n in self.fields())

    @property
    def highest(self) -> int:
        return max(self.span(n).stop - 1 for n in self.fields())

    def status_span(self) -> tuple[int, int]:
        """``(start, count)`` of one read covering every read-only field."""
        ro = [n for n in self.fields() if n not in self.WRITABLE]
        lo = min(getattr(self, n) for n in ro)
        hi = max(self.span(n).stop for n in ro)
        if hi - lo > 125:
            raise ConfigError(f"read-only registers span {hi - lo} registers; one Modbus read holds at most 125")
        return lo, hi - lo


def encode_name(name: str) -> list[int]:
    """File name -> 16 registers (ASCII, 2 chars per register, high byte first)."""
    if not isinstance(name, str) or not name.isascii() or not name.isprintable():
        raise ConfigError(f"program name {name!r} must be printable ASCII")
    raw = name.encode("ascii")
    if not raw or len(raw) > 2 * PROGRAM_NAME_REGS:
        raise ConfigError(f"program name {name!r} must have 1..{2 * PROGRAM_NAME_REGS} characters")
    raw = raw.ljust(2 * PROGRAM_NAME_REGS, b"\0")
    return [(raw[i] << 8) | raw[i + 1] for i in range(0, len(raw), 2)]


def decode_name(regs: list[int]) -> str:
    """16 registers -> file name (NUL padding removed); ValueError if not ASCII."""
    raw = b"".join(int(r).to_bytes(2, "big") for r in regs)
    raw = raw.split(b"\0", 1)[0]
    return raw.decode("ascii")


def split_u32(value: int) -> list[int]:
    value &= 0xFFFFFFFF
    return [value >> 16, value & 0xFFFF]


def join_u32(hi: int, lo: int) -> int:
    return ((int(hi) & 0xFFFF) << 16) | (int(lo) & 0xFFFF)


def join_i32(hi: int, lo: int) -> int:
    v = join_u32(hi, lo)
    return v - (1 << 32) if v & 0x80000000 else v
