"""A simulated handheld force gauge answering its ASCII request/reply on a pty (raw mode).

It stands in the load path between the operator's hand and the tool: its
reading is the magnitude of the external force on the simulated arm's TCP
(``world.arm.tcp_force_N()`` at the world clock's present; tension
positive), plus the gauge's own zero offset (removed by ``Z``) and noise,
rounded to its resolution. Grammar: :mod:`drivers.forcegauge_codec`.

Fault injection (``faults`` dict, string values)::

    no_reply     "always" or "N"   no reply at all, or to every Nth request
    garbage      "N"               every Nth reply is replaced by a line of non-ASCII bytes
    capacity_N   "X"               capacity (default 2500): beyond it the gauge answers OVER
    noise_N      "X"               standard deviation of a reading (default 0.05 N)
    seed         "N"               seed of the gauge's zero offset, noise and garbage

``start_fake(world, host=None, port=None, faults=None)``: the endpoint is
``{"device": "/dev/pts/N"}``.
"""

from __future__ import annotations

import threading

import numpy as np

from fakes.pty_port import PtyPort
from station.errors import ConfigError

FORCEGAUGE_FAULTS = frozenset({"no_reply", "garbage", "capacity_N", "noise_N", "seed"})
#: unit-select commands -> (unit sent in readings, newtons per unit, decimals)
UNITS = {"N": ("N", 1.0, 2), "KN": ("kN", 1000.0, 5), "KGF": ("kgF", 9.80665, 3), "LBF": ("lbF", 4.4482216, 3)}
MODEL = "FG-2500"
SERIAL = "G-0042"
_MAX_LINE = 256


def _positive(faults: dict, key: str, default: float, kind=float):
    raw = faults.get(key)
    if raw is None:
        return default
    try:
        value = kind(raw)
    except (TypeError, ValueError):
        raise ConfigError(f"force gauge fault {key}={raw!r}: not a number") from None
    if not value > 0:
        raise ConfigError(f"force gauge fault {key}={raw!r}: must be > 0")
    return value


class ForceGaugeFake:
    """Handle of a running gauge fake: ``endpoint``, ``stats``, ``close()``."""

    def __init__(self, world, *, host=None, port=None, faults: dict | None = None) -> None:
        if host is not None or port is not None:
            raise ConfigError("the force gauge fake serves a pty; host and port do not apply")
        faults = dict(faults or {})
        unknown = sorted(set(faults) - FORCEGAUGE_FAULTS)
        if unknown:
            raise ConfigError(f"unknown force gauge fault(s) {', '.join(unknown)} "
                              f"(known: {', '.join(sorted(FORCEGAUGE_FAULTS))})")
        silent = faults.get("no_reply")
        self._silent_always = silent == "always"
        self._silent_every = 0 if silent in (None, "always") else _positive(faults, "no_reply", 0, int)
        self._garbage_every = _positive(faults, "garbage", 0, int) if "garbage" in faults else 0
        self.capacity_N = _positive(faults, "capacity_N", 2500.0)
        self._noise_N = _positive(faults, "noise_N", 0.05)
        self._rng = np.random.default_rng(int(_positive(faults, "seed", world.seed + 1, int)))
        self._offset_N = float(self._rng.uniform(-3.0, 3.0))  # the zero of an untared gauge
        self._unit = UNITS["N"]
        self._arm = world.arm
        self._port = PtyPort()
        self.endpoint = {"device": self._port.device}
        self.url = f"forcegauge://{self._port.device}"
        self.stats = {"requests": 0, "replies": 0, "unanswered": 0, "garbage": 0, "overloads": 0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="forcegauge-fake", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._port.close()

    def __enter__(self) -> "ForceGaugeFake":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ I/O
    def _serve(self) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            buf += self._port.wait_read(self._stop)
            while (idx := min((i for i in (buf.find(b"\r"), buf.find(b"\n")) if i >= 0), default=-1)) >= 0:
                line = bytes(buf[:idx]).strip()
                del buf[: idx + 1]
                if line:
                    self._request(line.decode("latin-1"))
            if len(buf) > _MAX_LINE:  # no line end in sight: not a command of this gauge
                buf.clear()

    # ------------------------------------------------------------------ the gauge
    def applied_force_N(self) -> float:
        """The load in the gauge's path now (the magnitude of the external force on the TCP), N."""
        return float(np.linalg.norm(self._arm.tcp_force_N()))

    def _request(self, command: str) -> None:
        self.stats["requests"] += 1
        n = self.stats["requests"]
        if self._silent_always or (self._silent_every and n % self._silent_every == 0):
            self.stats["unanswered"] += 1
            return
        reply = self._answer(command.upper())
        if self._garbage_every and n % self._garbage_every == 0:
            size = int(self._rng.integers(3, 40))
            reply = self._rng.integers(128, 256, size, dtype=np.uint8).tobytes() + b"\r\n"
            self.stats["garbage"] += 1
        self.stats["replies"] += 1
        self._port.write_all(reply, self._stop)

    def _answer(self, command: str) -> bytes:
        if command == "?":
            load = self.applied_force_N()
            if load > self.capacity_N:
                self.stats["overloads"] += 1
                return b"OVER\r\n"
            reading = load + self._offset_N + float(self._rng.normal(0.0, self._noise_N))
            unit, per_unit, decimals = self._unit
            return f"{reading / per_unit:.{decimals}f} {unit}\r\n".encode("ascii")
        if command == "Z":
            self._offset_N = -self.applied_force_N()
            return b"R\r\n"
        if command in UNITS:
            self._unit = UNITS[command]
            return b"R\r\n"
        if command == "RM":
            return MODEL.encode() + b"\r\n"
        if command == "RS":
            return SERIAL.encode() + b"\r\n"
        return b"*10\r\n"


def start_fake(world, *, host=None, port=None, faults: dict | None = None) -> ForceGaugeFake:
    """Start the force gauge fake on a new pty; see the module docstring for ``faults``."""
    return ForceGaugeFake(world, host=host, port=port, faults=faults)


__all__ = ["start_fake", "ForceGaugeFake", "FORCEGAUGE_FAULTS", "MODEL", "SERIAL"]
