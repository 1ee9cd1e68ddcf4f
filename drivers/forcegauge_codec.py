"""ASCII request/reply of handheld force gauges and load-cell indicators: pure encode/decode, no I/O.

The grammar the station speaks (the common subset of the command sets of
handheld digital force gauges, e.g. Mark-10's: a one-line command, one
line back)::

    host -> gauge   <command> CR [LF]
    gauge -> host   <reply> CR LF

    command   reply                      meaning
    ?         <value> <unit>             the displayed (current) reading, e.g. ``-12.34 N``,
                                         ``0.512 kN``, ``4.285 lbF``; sign: tension
                                         positive, compression negative
              OVER                       the load is beyond the gauge's capacity
    Z         R                          zero (tare) the reading
    N|KN|KGF|LBF   R                     select the unit of the replies
    RM        <model>                    the gauge's model (e.g. ``FG-1000``)
    RS        <serial>                   its serial number
    anything  *10                        illegal command
    else

Units accepted in a reading: ``N``, ``kN``, ``gF``, ``kgF``, ``ozF``,
``lbF`` (case-insensitive), converted to newtons by :data:`UNIT_TO_N`. A
reading without a unit (a gauge set to omit it) is refused: a number whose
unit the station would have to guess is no force.

:func:`parse_reply` reads one line; it never raises for a reply that is
well formed but unwelcome (``OVER``, an error code): the driver decides.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from station.errors import ConfigError

#: newtons per unit of a reading (the unit's spelling on the wire, upper-cased)
UNIT_TO_N = {
    "N": 1.0,
    "KN": 1000.0,
    "GF": 9.80665e-3,
    "KGF": 9.80665,
    "OZF": 0.27801385,
    "LBF": 4.4482216,
}
#: the unit-select commands and the unit the replies then carry
UNIT_COMMANDS = {"N": "N", "KN": "kN", "KGF": "kgF", "LBF": "lbF"}
#: commands of the grammar (anything else is answered ``*10``)
COMMANDS = ("?", "Z", "RM", "RS") + tuple(UNIT_COMMANDS)
#: longest reply line accepted, bytes
MAX_REPLY_BYTES = 64

#: error codes a gauge answers with
ERROR_CODES = {"10": "illegal command", "11": "not applicable", "12": "invalid specifier", "22": "value too large"}

_READING = re.compile(r"\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+))\s*([A-Za-z]+)\s*")
_ERROR = re.compile(r"\s*\*(\d{1,3})\s*")


@dataclass(frozen=True)
class Reading:
    """A reading as the gauge sent it and in newtons (tension positive)."""

    value: float
    unit: str
    force_N: float


@dataclass(frozen=True)
class Overload:
    """The load is beyond the gauge's capacity (``OVER``)."""


@dataclass(frozen=True)
class Ack:
    """A set command was done (``R``)."""


@dataclass(frozen=True)
class ErrorReply:
    """The gauge refused the command: ``*<code>``."""

    code: str

    @property
    def meaning(self) -> str:
        return ERROR_CODES.get(self.code, "unknown error code")


@dataclass(frozen=True)
class Text:
    """A free text reply (model, serial number)."""

    text: str


def encode_command(command: str) -> bytes:
    """``"?"`` -> ``b"?\\r"``: one command of :data:`COMMANDS` (ConfigError names anything else)."""
    if command not in COMMANDS:
        raise ConfigError(f"force gauge command {command!r} is not one of {', '.join(COMMANDS)}")
    return command.encode("ascii") + b"\r"


def parse_reply(line: bytes):
    """One reply line (without its CR LF) -> :class:`Reading`, :class:`Overload`, :class:`Ack`,
    :class:`ErrorReply` or :class:`Text`. ValueError says why a line is not a reply (not ASCII, too long,
    empty, a number without a unit or with an unknown one, a non-finite number)."""
    if len(line) > MAX_REPLY_BYTES:
        raise ValueError(f"reply of {len(line)} bytes is longer than {MAX_REPLY_BYTES}")
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        raise ValueError(f"reply {line[:20]!r} is not ASCII") from None
    if any(ord(c) < 32 and c not in "\t" for c in text):
        raise ValueError(f"reply {text[:20]!r} holds control characters")
    stripped = text.strip()
    if not stripped:
        raise ValueError("empty reply")
    if stripped.upper() == "OVER":
        return Overload()
    if stripped == "R":
        return Ack()
    m = _ERROR.fullmatch(text)
    if m:
        return ErrorReply(m.group(1))
    m = _READING.fullmatch(text)
    if m:
        unit = m.group(2)
        if unit.upper() not in UNIT_TO_N:
            raise ValueError(f"reading {stripped!r}: unknown unit {unit!r} (known: {', '.join(UNIT_TO_N)})")
        value = float(m.group(1))
        return Reading(value, unit, value * UNIT_TO_N[unit.upper()])
    if re.fullmatch(r"\s*[+-]?[\d.]+\s*", text):
        raise ValueError(f"reading {stripped!r} has no unit (set the gauge to send its unit)")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9 ._/-]*", stripped):
        raise ValueError(f"reply {stripped[:20]!r} is neither a reading, OVER, R, an error code nor a name")
    return Text(stripped)


__all__ = ["UNIT_TO_N", "UNIT_COMMANDS", "COMMANDS", "MAX_REPLY_BYTES", "ERROR_CODES", "Reading", "Overload",
           "Ack", "ErrorReply", "Text", "encode_command", "parse_reply"]
