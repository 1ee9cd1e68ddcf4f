"""A handheld force gauge / load-cell indicator over serial (ASCII request/reply, :mod:`drivers.forcegauge_codec`).

One command, one reply line, within the reply timeout. The driver asks and
reads; nothing is streamed. Errors, each naming the gauge's line::

    no reply in time                    -> DeviceTimeout
    a line that is no reply, or a reply
    of the wrong kind (garbage, a name
    where a reading was asked)           -> ProtocolError
    OVER (beyond capacity)              -> GaugeOverload (a DeviceFault)
    *NN (the gauge refused)             -> DeviceFault

A reply left over from a request that timed out would answer the next one:
after a timeout or a refused reply the driver drops what is waiting on the
line before it asks again.
"""

from __future__ import annotations

import math

from drivers.forcegauge_codec import (UNIT_COMMANDS, Ack, ErrorReply, Overload, Reading, Text, encode_command,
                                      parse_reply)
from drivers.transport import Deadline, LineReader, check_positive, serial_factory, transport_or_factory
from station.device_urls import parse_device_url
from station.errors import ConfigError, ConnectionLost, DeviceFault, DeviceTimeout, ProtocolError

#: how often the reply wait looks at the line: a longer gap between two looks is a host that did not run, and only
#: this much of it counts as the gauge's silence (:class:`drivers.transport.ListeningDeadline`)
LISTEN_SLICE_S = 0.05


class GaugeOverload(DeviceFault):
    """The gauge reports a load beyond its capacity."""


class ForceGauge:
    """A force gauge on a serial line (a pty in tests).

    Parameters
    ----------
    transport : Transport or callable returning a Transport
    reply_timeout_s : float
        Time allowed for each reply, s.
    """

    protocol = "forcegauge"

    def __init__(self, transport, *, reply_timeout_s: float = 1.0) -> None:
        check_positive(reply_timeout_s=reply_timeout_s)
        self._factory, self._transport = transport_or_factory(transport)
        self.reply_timeout_s = float(reply_timeout_s)
        self._lines: LineReader | None = None
        self.model: str | None = None
        self.serial: str | None = None

    @classmethod
    def from_url(cls, url, *, timeout_s: float | None = None, **options) -> "ForceGauge":
        """``forcegauge:///dev/ttyX[?baud=N]`` (9600 baud by default, :mod:`station.device_urls`);
        ``timeout_s``: the reply timeout (1 s when None)."""
        u = parse_device_url(url, scheme="forcegauge")
        if timeout_s is not None:
            options["reply_timeout_s"] = timeout_s
        return cls(serial_factory(u.path, baudrate=u.int_option("baud")), **options)

    @property
    def description(self) -> str:
        t = self._transport
        return f"force gauge on {t.description}" if t is not None else "force gauge (not connected)"

    # ------------------------------------------------------------------ connection
    def connect(self) -> dict:
        """Open the line; read the gauge's model and serial number."""
        if self._transport is None or self._transport.closed:
            if self._factory is None:
                raise ConnectionLost("the force gauge driver was closed and a bare transport cannot be reopened")
            self._transport = self._factory()
        self._lines = LineReader(self._transport, terminator=b"\n", max_line_bytes=256)
        self._flush()
        self.model = self._text("RM")
        self.serial = self._text("RS")
        return {"model": self.model, "serial": self.serial}

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    def __enter__(self) -> "ForceGauge":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ commands
    def read_force_N(self) -> float:
        """The current reading in newtons (tension positive)."""
        reply = self._ask("?")
        if isinstance(reply, Reading):
            return reply.force_N
        raise self._wrong("?", reply, "a reading")

    def read_force_avg_N(self, n: int) -> tuple[float, float]:
        """``(mean, standard deviation)`` of ``n`` consecutive readings, N (the sd is 0 for one)."""
        if not (isinstance(n, int) and n >= 1):
            raise ConfigError(f"n must be an integer >= 1, got {n!r}")
        values = [self.read_force_N() for _ in range(n)]
        mean = sum(values) / n
        sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else 0.0
        return mean, sd

    def zero(self) -> None:
        """Zero (tare) the reading."""
        self._expect_ack("Z")

    def set_unit(self, unit: str) -> None:
        """Have the gauge reply in ``unit`` (``N``, ``kN``, ``kgF``, ``lbF``); readings come out in N either way."""
        key = str(unit).upper()
        if key not in UNIT_COMMANDS:
            raise ConfigError(f"force gauge unit {unit!r} is not one of {', '.join(UNIT_COMMANDS.values())}")
        self._expect_ack(key)

    # ------------------------------------------------------------------ internals
    def _expect_ack(self, command: str) -> None:
        reply = self._ask(command)
        if not isinstance(reply, Ack):
            raise self._wrong(command, reply, "R")

    def _text(self, command: str) -> str:
        reply = self._ask(command)
        if isinstance(reply, Text):
            return reply.text
        if isinstance(reply, Reading):  # a name that reads as a number and a unit, e.g. "5 N"
            return f"{reply.value:g} {reply.unit}"
        raise self._wrong(command, reply, "a name")

    def _wrong(self, command: str, reply, wanted: str) -> Exception:
        if isinstance(reply, Overload):
            return GaugeOverload(f"{self.description} reports an overload (OVER) to {command!r}: the load is beyond "
                                 "its capacity")
        if isinstance(reply, ErrorReply):
            return DeviceFault(f"{self.description} refused {command!r}: *{reply.code} ({reply.meaning})")
        self._flush()
        return ProtocolError(f"{self.description} answered {command!r} with {reply!r}, not {wanted}")

    def _ask(self, command: str):
        if self._lines is None:
            raise ConnectionLost(f"{self.description}: connect() first")
        self._transport.write(encode_command(command), self.reply_timeout_s)
        try:
            line = self._lines.read_line(self.reply_timeout_s, LISTEN_SLICE_S)
        except DeviceTimeout:
            self._flush()
            raise DeviceTimeout(f"no reply from {self.description} to {command!r} within "
                                f"{self.reply_timeout_s:g} s") from None
        except ProtocolError as exc:
            self._flush()
            raise ProtocolError(f"{self.description} answered {command!r} with an overlong line ({exc})") from None
        try:
            return parse_reply(line.rstrip(b"\r"))
        except ValueError as exc:
            self._flush()
            raise ProtocolError(f"{self.description} answered {command!r} with a refused reply: {exc}") from None

    def _flush(self) -> None:
        """Drop what is waiting on the line (a late reply to an earlier request), without waiting long."""
        if self._lines is None:
            return
        self._lines.clear()
        deadline = Deadline(0.05)
        while not deadline.expired():
            if not self._transport.read(4096, min(0.01, deadline.time_left())):
                break


__all__ = ["ForceGauge", "GaugeOverload"]
