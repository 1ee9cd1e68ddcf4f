"""NMEA 0183 sentences of the trailer odometry unit: pure encode/decode, no I/O.

Wire format: NMEA 0183 sentences ``$<body>*hh\\r\\n`` where ``hh`` is the XOR
of the body's bytes in two upper-case hex digits. The odometry unit speaks a
proprietary talker (``P`` + manufacturer ``ODO``); the first field's tail
names the sentence (see :mod:`drivers.odometry` for the messages).

:class:`NmeaDecoder` frames a byte stream into messages with
resynchronisation; :func:`encode_sentence` and the command encoders build
frames; :func:`parse_body` reads one checksum-verified body.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from station.errors import ConfigError

#: manufacturer code of the proprietary talker
MANUFACTURER = "ODO"
#: longest sentence accepted, bytes from ``$`` to the line end (NMEA says 82)
MAX_SENTENCE_BYTES = 120


# ----------------------------------------------------------------------------- messages
@dataclass(frozen=True)
class OdometrySample:
    """One odometry sample in device time."""

    t_s: float
    v_m_s: float
    kappa_1_m: float
    psi_rad: float


@dataclass(frozen=True)
class CommandAck:
    """The device applied command ``cmd`` (``"C"`` or ``"V"``) at ``t_s``."""

    cmd: str
    t_s: float
    value: float


@dataclass(frozen=True)
class CommandNak:
    """The device refused command ``cmd``."""

    cmd: str
    reason: str


@dataclass
class LineStats:
    """Counters of what the decoder saw (never reset silently)."""

    sentences: int = 0
    samples: int = 0
    checksum_errors: int = 0
    partial_lines: int = 0
    malformed: int = 0
    ignored: int = 0
    bytes_discarded: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


# ----------------------------------------------------------------------------- codec
def checksum(body: bytes) -> int:
    """XOR of the bytes between ``$`` and ``*``."""
    c = 0
    for b in body:
        c ^= b
    return c


def _fmt(value: float) -> str:
    if not math.isfinite(value):
        raise ConfigError(f"cannot send a non-finite value {value!r}")
    return f"{value:.6f}"


def encode_sentence(fields: list[str]) -> bytes:
    """``["PODOC", "0.1"]`` -> ``b"$PODOC,0.1*hh\\r\\n"``."""
    body = ",".join(fields).encode("ascii")
    if b"*" in body or b"$" in body or b"\n" in body or b"\r" in body:
        raise ConfigError(f"NMEA fields must not contain $ * or line ends: {fields!r}")
    if len(body) + 6 > MAX_SENTENCE_BYTES:
        raise ConfigError(f"sentence of {len(body) + 6} bytes is longer than {MAX_SENTENCE_BYTES}")
    return b"$" + body + b"*%02X\r\n" % checksum(body)


def encode_curvature_command(kappa_1_m: float) -> bytes:
    """``$PODOC,<kappa>*hh``."""
    return encode_sentence([f"P{MANUFACTURER}C", _fmt(kappa_1_m)])


def encode_speed_command(v_m_s: float) -> bytes:
    """``$PODOV,<v>*hh``."""
    return encode_sentence([f"P{MANUFACTURER}V", _fmt(v_m_s)])


def encode_sync(token: str, t_s: float | None, *, end: bool = False) -> bytes:
    """``$PODOS,<token>,<t_s>*hh`` (simulated unit only): the host ``token`` has every sample up to device
    time ``t_s`` (empty: none yet) and sent what the next control cycle is to latch; step one cycle.
    ``end``: ``$PODOS,<token>,END*hh``, the host leaves (the unit holds the clock for nobody)."""
    if not (token and token.isascii() and token.isalnum()):
        raise ConfigError(f"a sync token is letters and digits, got {token!r}")
    return encode_sentence([f"P{MANUFACTURER}S", token, "END" if end else "" if t_s is None else f"{t_s:.3f}"])


#: a field's number as NMEA writes it: optional sign, digits, optional fraction, optional exponent (Python's
#: float() also takes '1_0', ' 8', 'inf', 'nan', which no sentence holds)
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?")
_HEX2 = re.compile(rb"[0-9A-Fa-f]{2}")


#: largest value the unit reports per field (s, m/s, 1/m, rad): the year 2286 in seconds, 100 m/s, a curvature of
#: 1 mm radius, a hitch angle of a full turn; a sentence beyond is malformed, never a sample
LIMITS = {"t": 1.0e10, "v": 100.0, "kappa": 1.0e3, "psi": 2.0 * math.pi}


def _floats(fields: list[str], n: int, what: str, limits: tuple = ()) -> list[float]:
    if len(fields) != n:
        raise ValueError(f"{what} needs {n} fields, got {len(fields)}")
    for f in fields:
        if not _NUMBER.fullmatch(f):
            raise ValueError(f"{what}: {f[:20]!r} is not a decimal number")
    out = [float(f) for f in fields]
    if not all(math.isfinite(x) for x in out):
        raise ValueError(f"{what} has a non-finite field")
    for x, key in zip(out, limits):
        if abs(x) > LIMITS[key]:
            raise ValueError(f"{what}: {key} = {x:.6g} is beyond {LIMITS[key]:g}")
    return out


def parse_body(body: str):
    """Message of a checksum-verified body (without ``$`` and ``*hh``).

    Returns an :class:`OdometrySample`, :class:`CommandAck`,
    :class:`CommandNak`, or ``None`` for another talker. Raises ValueError
    for a malformed odometry sentence.
    """
    fields = body.split(",")
    head = fields[0]
    if not head.startswith("P" + MANUFACTURER):
        return None
    kind = head[1 + len(MANUFACTURER):]
    if kind == "":
        t, v, k, p = _floats(fields[1:], 4, "$PODO", ("t", "v", "kappa", "psi"))
        return OdometrySample(t, v, k, p)
    if kind == "A":
        if len(fields) != 4 or fields[1] not in ("C", "V"):
            raise ValueError("$PODOA needs cmd,t,value")
        t, val = _floats(fields[2:], 2, "$PODOA", ("t", "kappa" if fields[1] == "C" else "v"))
        return CommandAck(fields[1], t, val)
    if kind == "N":
        if len(fields) != 3:
            raise ValueError("$PODON needs cmd,reason")
        return CommandNak(fields[1], fields[2])
    return None  # another sentence of the unit (e.g. a command echoed by a loopback)


class NmeaDecoder:
    """Incremental NMEA 0183 framer and parser with resynchronisation.

    ``feed(data)`` returns the messages completed by ``data`` (samples, acks,
    naks) in order; errors are counted in :attr:`stats`, never raised.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._discarding = False  # inside the tail of an overlong line (already counted)
        self.stats = LineStats()

    def _junk(self, data: bytes) -> None:
        junk = data.strip()
        if junk:
            self.stats.bytes_discarded += len(junk)
            if not self._discarding:
                self.stats.partial_lines += 1

    def feed(self, data: bytes) -> list:
        self._buf += data
        out = []
        buf = self._buf
        while True:
            start = buf.find(b"$")
            if start < 0:
                nl = buf.rfind(b"\n")
                if nl >= 0:  # junk up to a line end: one partial line, the rest waits
                    self._junk(bytes(buf[:nl + 1]))
                    self._discarding = False
                    del buf[:nl + 1]
                elif len(buf) > MAX_SENTENCE_BYTES:
                    self._junk(bytes(buf))
                    self._discarding = True
                    buf.clear()
                break
            if start > 0:
                self._junk(bytes(buf[:start]))
                del buf[:start]
            self._discarding = False
            # search no further than a sentence can reach: linear however the bytes arrive
            reach = MAX_SENTENCE_BYTES + 2
            end = buf.find(b"\n", 0, reach)
            nxt = buf.find(b"$", 1, end if end >= 0 else reach)
            if nxt >= 0:
                # a new sentence starts before this one ended: characters were lost
                self._junk(bytes(buf[:nxt]))
                del buf[:nxt]
                continue
            if end < 0:
                if len(buf) > MAX_SENTENCE_BYTES:  # overlong: its first bytes go, the rest is read on
                    self._junk(bytes(buf[:reach]))
                    self._discarding = True
                    del buf[:reach]
                    continue
                break
            line = bytes(buf[:end]).rstrip(b"\r")
            del buf[:end + 1]
            msg = self._line(line)
            if msg is not None:
                out.append(msg)
        return out

    def _line(self, line: bytes):
        star = line.rfind(b"*")
        if len(line) > MAX_SENTENCE_BYTES or star < 0 or len(line) - star != 3:
            self.stats.partial_lines += 1
            self.stats.bytes_discarded += len(line)
            return None
        body, hh = line[1:star], line[star + 1:]
        try:
            if not _HEX2.fullmatch(hh):
                raise ValueError("checksum must be two hex digits")
            expected = int(hh.decode("ascii"), 16)
            text = body.decode("ascii")
        except (ValueError, UnicodeDecodeError):
            self.stats.partial_lines += 1
            self.stats.bytes_discarded += len(line)
            return None
        if checksum(body) != expected:
            self.stats.checksum_errors += 1
            self.stats.bytes_discarded += len(line)
            return None
        self.stats.sentences += 1
        try:
            msg = parse_body(text)
        except ValueError:
            self.stats.malformed += 1
            return None
        if msg is None:
            self.stats.ignored += 1
        elif isinstance(msg, OdometrySample):
            self.stats.samples += 1
        return msg


__all__ = [
    "MANUFACTURER", "MAX_SENTENCE_BYTES", "OdometrySample", "CommandAck", "CommandNak", "LineStats", "checksum",
    "encode_sentence", "encode_curvature_command", "encode_speed_command", "encode_sync", "parse_body",
    "NmeaDecoder",
]
