"""The GeoCOM wire format, pure: rpc numbers, return codes and their exceptions, requests and replies.

::

    request  %R1Q,<rpc>,<trid>:<p1>,<p2>,...
    reply    %R1P,<com_rc>,<trid>:<rc>[,<v1>,...]

No I/O here: :mod:`drivers.geocom` sends what :func:`encode_request` makes and
reads what :func:`parse_reply` takes, over its transport.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from station.errors import ConfigError, DeviceError, DeviceFault, DeviceNotReady, DeviceTimeout, ProtocolError
from drivers.tracker import BeamBroken


class Rpc:
    NULL_PROC = 0
    GET_DOUBLE_PRECISION = 108
    GET_GEOCOM_VERSION = 110
    GET_INSTRUMENT_NO = 5003
    GET_INSTRUMENT_NAME = 5004
    GET_SW_VERSION = 5034
    DO_MEASURE = 2008
    GET_COORDINATE = 2082
    GET_ANGLE = 2107
    GET_SIMPLE_MEA = 2108
    GET_SIMPLE_COORD = 2116


#: number of values each rpc returns after its return code
REPLY_VALUES = {0: 0, 108: 1, 110: 3, 5003: 1, 5004: 1, 5034: 3, 2008: 0, 2082: 8, 2107: 2,
                2108: 3, 2116: 3}


class MeasureProgram:
    """``TMC_MEASURE_PRG``."""

    STOP = 0
    DISTANCE = 1
    TRACK = 2
    CLEAR = 3


INCLINATION_AUTO = 1

#: return codes (GeoCOM reference) with names for messages
RC_NAMES = {
    0: "OK", 1: "UNDEFINED", 2: "IVPARAM", 3: "IVRESULT", 4: "FATAL", 5: "NOT_IMPL", 6: "TIME_OUT",
    7: "SET_INCOMPL", 8: "ABORT", 9: "NOMEMORY", 10: "NOTINIT", 12: "SHUT_DOWN", 13: "SYSBUSY",
    14: "HWFAILURE", 1283: "TMC_NO_FULL_CORRECTION", 1284: "TMC_ACCURACY_GUARANTEE",
    1285: "TMC_ANGLE_OK", 1288: "TMC_ANGLE_NO_FULL_CORRECTION", 1289: "TMC_ANGLE_ACCURACY_GUARANTEE",
    1290: "TMC_ANGLE_ERROR", 1291: "TMC_DIST_PPM", 1292: "TMC_DIST_ERROR", 1293: "TMC_BUSY",
    1294: "TMC_SIGNAL_ERROR", 3073: "COM_CANT_ENCODE", 3074: "COM_CANT_DECODE", 3075: "COM_CANT_SEND",
    3076: "COM_CANT_RECV", 3077: "COM_TIMEDOUT", 3078: "COM_WRONG_FORMAT", 3079: "COM_VER_MISMATCH",
    3080: "COM_CANT_DECODE_REQ", 8710: "AUT_NO_TARGET",
}
#: codes after which the values are still valid (accuracy warnings)
RC_WARNINGS = frozenset({1283, 1284})
RC_NO_TARGET = frozenset({1285, 1288, 1289, 1292, 1294, 8710})
RC_NOT_READY = frozenset({10, 13, 1293})
RC_FAULT = frozenset({4, 8, 12, 14, 1290})


def idempotent(rpc: int, params=()) -> bool:
    """Whether sending ``rpc`` twice does what sending it once does (so a lost reply may be retried).

    Every query is; of ``TMC_DoMeasure`` the programs that set a state (stop, track, clear) are, a
    distance measurement (a new measurement each time) is not.
    """
    if rpc == Rpc.DO_MEASURE:
        return bool(params) and params[0] in (MeasureProgram.STOP, MeasureProgram.TRACK, MeasureProgram.CLEAR)
    return rpc in REPLY_VALUES


def rc_name(rc: int) -> str:
    name = RC_NAMES.get(rc)
    return f"{rc} ({name})" if name else str(rc)


def geocom_error(rpc: int, rc: int) -> DeviceError | DeviceTimeout:
    """The exception for a non-OK return code of ``rpc``."""
    text = f"GeoCOM rpc {rpc} failed with rc {rc_name(rc)}"
    if rc in RC_NO_TARGET:
        return BeamBroken(text + ": no distance (no target, beam broken?)")
    if rc in RC_NOT_READY:
        return DeviceNotReady(text)
    if rc in RC_FAULT:
        return DeviceFault(text)
    if rc == 6:
        return DeviceTimeout(text)
    if rc == 5:
        return DeviceError(text + ": the instrument does not implement this rpc")
    if rc == 2:
        return DeviceError(text + ": invalid parameter")
    return DeviceError(text)


# ----------------------------------------------------------------------------- codec

def _format_param(value) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ConfigError(f"GeoCOM parameter must be finite, got {value!r}")
        return repr(value)
    if isinstance(value, str):
        if '"' in value or "\r" in value or "\n" in value:
            raise ConfigError(f"GeoCOM string parameter cannot hold quotes or line ends: {value!r}")
        return f'"{value}"'
    raise ConfigError(f"unsupported GeoCOM parameter type {type(value).__name__}")


def encode_request(rpc: int, trid: int, params=()) -> bytes:
    """``%R1Q,<rpc>,<trid>:<params>`` + CR LF."""
    if not (isinstance(rpc, int) and 0 <= rpc <= 65535):
        raise ConfigError(f"rpc must be an integer in 0..65535, got {rpc!r}")
    if not (isinstance(trid, int) and 0 <= trid < 2**15):
        raise ConfigError(f"trid must be an integer in 0..32767, got {trid!r}")
    return f"%R1Q,{rpc},{trid}:{','.join(_format_param(p) for p in params)}\r\n".encode("ascii")


@dataclass(frozen=True)
class GeoComReply:
    com_rc: int
    trid: int
    rc: int
    values: tuple


_REPLY = re.compile(r"^%R1P,(\d+),(\d+)(?:,\d+)?:(\d+)(?:,(.*))?$")


def split_values(text: str) -> tuple:
    """Split reply values on commas outside double quotes."""
    out, cur, quoted = [], [], False
    for ch in text:
        if ch == '"':
            quoted = not quoted
            cur.append(ch)
        elif ch == "," and not quoted:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    if quoted:
        raise ProtocolError(f"unterminated string in GeoCOM reply values {text[:60]!r}")
    out.append("".join(cur))
    return tuple(out)


def parse_reply(line: bytes) -> GeoComReply:
    """Parse one reply line (without its terminator); ProtocolError if malformed."""
    text = line.decode("latin-1")
    m = _REPLY.match(text)
    if not m:
        raise ProtocolError(f"not a GeoCOM reply: {text[:80]!r}")
    com_rc, trid, rc, values = m.groups()
    return GeoComReply(int(com_rc), int(trid), int(rc), split_values(values) if values is not None else ())


def parse_float(rpc: int, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ProtocolError(f"reply to rpc {rpc}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ProtocolError(f"reply to rpc {rpc}: {text!r} is not finite")
    return value


#: GeoCOM integers are 32-bit (signed or unsigned)
INT_MIN, INT_MAX = -(2**31), 2**32 - 1


def parse_int(rpc: int, text: str) -> int:
    if len(text) > 12:  # more digits than any 32-bit value has (and no 4,300-digit conversion)
        raise ProtocolError(f"reply to rpc {rpc}: {text[:16]!r}... ({len(text)} characters) is not a 32-bit integer")
    try:
        value = int(text)
    except ValueError:
        raise ProtocolError(f"reply to rpc {rpc}: {text!r} is not an integer") from None
    if not INT_MIN <= value <= INT_MAX:
        raise ProtocolError(f"reply to rpc {rpc}: {text!r} is outside the 32-bit range")
    return value


# ----------------------------------------------------------------------------- driver
