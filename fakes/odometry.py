"""A simulated trailer odometry unit streaming NMEA 0183 on a pty (raw mode).

Driven by a :class:`fakes.sim.trailer.SimTrailer` on the world clock: every
``1 / rate_hz`` simulated seconds it sends
``$PODO,<t_s>,<v_m_s>,<kappa_1_m>,<psi_rad>*hh`` (device time, m/s, 1/m,
rad; speed and curvature averaged over the interval since the previous
sample, as odometry measures them, the joint angle at ``t_s``). It takes commands on the same line — ``$PODOC,<kappa>*hh`` (hold a
path curvature) and ``$PODOV,<v>*hh`` (speed) — latches them at the next
sample tick (the unit's control cycle), and answers
``$PODOA,<C|V>,<t_s>,<value>*hh``, or ``$PODON,<C|V|?>,<reason>*hh`` when it
refuses one (reasons: ``BOUND`` beyond eq. (25), ``PSI_LIMIT`` beyond 45 deg,
``RANGE`` bad speed, ``CHECKSUM``, ``FORMAT``, ``UNKNOWN``). Every sentence it
writes parses with pynmea2 (a test checks).

Two ways to run (``lockstep``):

* **real time** (default): the unit keeps the world clock running while it
  serves, as a real unit runs whatever its host does; a host that lags sets
  its points late in device time;
* **lockstep** (the dry run's cells; the driver's ``?lockstep=1``): the unit
  holds the world clock at its newest sample until the host sends
  ``$PODOS,<token>,<t_s>*hh`` naming it (the host has it and has sent what the
  next cycle is to latch); then the clock runs (paced) to the next cycle,
  which latches the commands read before the sync and sends the next sample.
  A sync naming an older sample (or none, from a host that has had none of
  this attachment's samples) gets the newest sample again, without faults;
  a new token is a new host, which gets the next cycle's sample;
  ``$PODOS,<token>,END`` says the host leaves. While the line is stalled the
  unit runs on, unheld (nothing is sent, syncs are lost); with no host, it
  holds nothing. The same seed then gives the same samples at any load and
  pace.

Fault injection (``faults``: dict of strings)::

    rate_hz        "X"    sample rate (default 10)
    checksum_rate  "P"    fraction of sentences sent with a wrong checksum
    drop_rate      "P"    fraction of sentences that lose one character
                          (sometimes the line end: two lines run together)
    stall          "T0:DUR[,T0:DUR...]"  the line goes silent (no samples, no
                          replies) from T0 for DUR simulated seconds after start;
                          "drive+T0:DUR": T0 after the first set point that sets
                          the trailer moving (a speed other than 0), an event of
                          the unit's own, whenever the host sends it
    seed           "N"    seed of the fault randomness (default: from the world)

``start_fake(world, host=None, port=None, faults=None)`` -> handle with
``endpoint = {"device": "/dev/pts/N"}``, ``stats`` and ``close()``; host and
port do not apply to a pty.
"""

from __future__ import annotations

import math
import os
import select
import threading

import numpy as np

from fakes.pty_port import PtyPort
from fakes.sim.clock import keep_running, stop_running
from station.errors import ConfigError, DataError
from station.models.trailer import CurvatureBoundError, JointAngleLimitError

ODOMETRY_FAULTS = frozenset({"rate_hz", "checksum_rate", "drop_rate", "stall", "seed"})
_MAX_LINE = 256
_MAX_QUEUE = 64 * 1024  # output the unit buffers while the line is not read, bytes


def _checksum(body: bytes) -> int:
    c = 0
    for b in body:
        c ^= b
    return c


def _sentence(body: str) -> bytes:
    raw = body.encode("ascii")
    return b"$" + raw + b"*%02X\r\n" % _checksum(raw)


def _fraction(faults: dict, key: str) -> float:
    try:
        value = float(faults.get(key, "0"))
    except ValueError as exc:
        raise ConfigError(f"fault {key} must be a number in [0, 1], got {faults[key]!r}") from exc
    if not 0.0 <= value <= 1.0:
        raise ConfigError(f"fault {key} must be in [0, 1], got {faults[key]!r}")
    return value


def parse_odometry_faults(faults: dict | None) -> dict:
    """Validate the fault dict; ConfigError names an unknown key or a bad value."""
    faults = dict(faults or {})
    unknown = set(faults) - ODOMETRY_FAULTS
    if unknown:
        raise ConfigError(f"unknown odometry fault(s) {sorted(unknown)}; known: {sorted(ODOMETRY_FAULTS)}")
    out = {"checksum_rate": _fraction(faults, "checksum_rate"), "drop_rate": _fraction(faults, "drop_rate")}
    try:
        rate = float(faults.get("rate_hz", "10"))
    except ValueError as exc:
        raise ConfigError(f"rate_hz must be a number, got {faults['rate_hz']!r}") from exc
    if not (math.isfinite(rate) and 0 < rate <= 1000):
        raise ConfigError(f"rate_hz must be in (0, 1000], got {faults.get('rate_hz')!r}")
    out["rate_hz"] = rate
    stalls = []
    for item in filter(None, (s.strip() for s in faults.get("stall", "").split(","))):
        origin = "drive" if item.startswith("drive+") else "start"
        start, sep, dur = item.removeprefix("drive+").partition(":")
        try:
            s0, d = float(start), float(dur)
        except ValueError as exc:
            raise ConfigError(f"stall must be [drive+]T0:DURATION[,...] in seconds, got {item!r}") from exc
        if not sep or not (s0 >= 0 and d > 0 and math.isfinite(s0 + d)):
            raise ConfigError(f"stall must be T0:DURATION with T0 >= 0 and DURATION > 0, got {item!r}")
        stalls.append((origin, s0, d))
    out["stall"] = stalls
    seed = faults.get("seed")
    if seed is not None and not str(seed).lstrip("-").isdigit():
        raise ConfigError(f"seed must be an integer, got {seed!r}")
    out["seed"] = None if seed is None else int(seed)
    return out


class OdometryFake:
    """Handle of a running odometry fake: ``endpoint``, ``stats``, ``close()``.

    Parameters
    ----------
    trailer : SimTrailer
    clock : SimClock
        The world clock (the trailer's).
    faults : dict, optional
        See the module docstring.
    rng : numpy.random.Generator, optional
        Source of fault randomness (overridden by ``faults["seed"]``).
    lockstep : bool
        Step one control cycle per sync of the host (module docstring).
    """

    def __init__(self, trailer, clock, *, faults: dict | None = None,
                 rng: np.random.Generator | None = None, lockstep: bool = False) -> None:
        self._faults = parse_odometry_faults(faults)
        self.trailer = trailer
        self._clock = clock
        if self._faults["seed"] is not None:
            rng = np.random.default_rng(self._faults["seed"])
        self._rng = rng if rng is not None else np.random.default_rng()
        self._dt = 1.0 / self._faults["rate_hz"]
        self.stats = {"samples": 0, "sentences": 0, "corrupted": 0, "dropped_chars": 0,
                      "stalled_samples": 0, "commands": 0, "acks": 0, "naks": 0, "overflow_bytes": 0,
                      "syncs": 0, "resent_samples": 0}
        self._pending: list[tuple[str, float]] = []
        self._out = bytearray()
        self._port = PtyPort()
        self._master = self._port.master
        self.endpoint = {"device": self._port.device}
        self._t0 = float(clock.now())
        #: device time of the first set point that set the trailer moving (None: not yet)
        self._t_drive: float | None = None
        self._k = 1  # the next control cycle, at t0 + k / rate
        self.lockstep = bool(lockstep)
        # lockstep: the host being served (its token), whether it let the next cycle run, the newest sample
        # of its attachment (device time as sent, and the sentence without faults)
        self._host: str | None = None
        self._granted = False
        self._newest: tuple[float, bytes] | None = None
        self._demand = None
        self._hold = clock.producer("odometry") if self.lockstep else None
        # real time: the driver steers the trailer from the samples it reads, the clock runs while served
        self._running = None if self.lockstep else keep_running(clock)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="odometry-fake", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._port.close()
        stop_running(self._running)
        self._detach()

    def __enter__(self) -> "OdometryFake":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ loop
    def _serve(self) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            t_next = self._t0 + self._k * self._dt
            now = self._clock.now()
            if now >= t_next and (self._host is None or self._granted):
                self._tick(t_next)
                self._k += 1
                if self._host is not None and self._granted:  # stalled: nothing sent, the unit runs on
                    self._run_to_next()
                # a unit behind its clock (this host loaded, at many times real time) still hears its line
                # between the cycles it catches up on: a command is latched by the next, not lost for good
                wait = 0.0
            else:
                wait = min(max(self._clock.real_seconds(t_next - now), 0.0005), 0.05)
            ready, writable, _ = select.select([self._master], [self._master] if self._out else [], [], wait)
            if writable:
                self._flush()
            if not ready:
                continue
            data = self._port.read()
            if data is None:  # no driver has the device open at the moment
                self._detach()
                self._stop.wait(0.01)
                continue
            if not data:
                continue
            if self._stalled(self._clock.now()):
                continue  # the line is dead: input is lost
            buf += data
            while True:
                idx = buf.find(b"\n")
                if idx < 0:
                    if len(buf) > _MAX_LINE:
                        self.stats["overflow_bytes"] += len(buf)
                        buf.clear()
                    break
                line = bytes(buf[:idx]).rstrip(b"\r")
                del buf[: idx + 1]
                self._command_line(line)

    def _stalled(self, t: float) -> bool:
        origins = {"start": self._t0, "drive": self._t_drive}
        return any(origins[o] is not None and s <= t - origins[o] < s + d for o, s, d in self._faults["stall"])

    def _tick(self, t: float) -> None:
        """One control cycle at device time ``t``: latch commands, then sample."""
        stalled = self._stalled(t)
        pending, self._pending = self._pending, []
        if self._t_drive is None and any(cmd == "V" and value != 0.0 for cmd, value in pending):
            self._t_drive = t  # the trailer is set moving: a "drive+" stall counts from here
        for cmd, value in pending:
            self._apply(cmd, value, t, send=not stalled)
        if stalled:
            self.trailer.advance_to(t)
            self.stats["stalled_samples"] += 1
            return
        r = self.trailer.read_sensors(t)
        self.stats["samples"] += 1
        body = f"PODO,{r.t_s:.3f},{r.v_m_s:.4f},{r.kappa_1_m:.6f},{r.psi_rad:.6f}"
        self._send(body)
        if self._host is not None:  # lockstep: held here until the host has it
            self._newest = (float(f"{r.t_s:.3f}"), _sentence(body))
            self._granted = False
            self._hold.hold_until(t)

    # ------------------------------------------------------------------ lockstep
    def _run_to_next(self) -> None:
        """Let the clock run (paced) to the next control cycle and no further."""
        t_next = self._t0 + self._k * self._dt
        self._hold.hold_until(t_next)
        if self._demand is not None:
            self._demand.cancel()
        self._demand = self._clock.schedule(t_next)

    def _detach(self) -> None:
        """No host on the line: hold the clock nowhere."""
        self._host, self._granted, self._newest = None, False, None
        if self._demand is not None:
            self._demand.cancel()
            self._demand = None
        if self._hold is not None:
            self._hold.release()

    def _sync(self, fields: list[str]) -> None:
        """``$PODOS,<token>,<t_s>``: step one cycle, or send the newest sample again (module docstring)."""
        token, t_text = fields[1], fields[2]
        if t_text == "END":  # the host leaves
            if token == self._host:
                self._detach()
            return
        try:
            t_host = None if t_text == "" else float(t_text)
        except ValueError:
            self._nak("S", "FORMAT")
            return
        if not token or (t_host is not None and not math.isfinite(t_host)):
            self._nak("S", "FORMAT")
            return
        self.stats["syncs"] += 1
        if token != self._host:  # a new host: the next cycle is its first sample
            self._detach()
            self._host = token
        elif self._newest is not None and (t_host is None or t_host < self._newest[0] - 5e-4):
            self.stats["resent_samples"] += 1  # the host lacks the newest sample: again, as it was
            self._write(self._newest[1])
            return
        if not self._granted:
            self._granted = True
            self._run_to_next()

    def _apply(self, cmd: str, value: float, t: float, *, send: bool) -> None:
        try:
            if cmd == "C":
                applied = self.trailer.command_curvature(value, t)
            else:
                applied = self.trailer.command_speed(value, t)
        except CurvatureBoundError:
            reply = f"PODON,{cmd},BOUND"
        except JointAngleLimitError:
            reply = f"PODON,{cmd},PSI_LIMIT"
        except (ConfigError, DataError):
            reply = f"PODON,{cmd},RANGE"
        else:
            reply = f"PODOA,{cmd},{applied:.3f},{value:.6f}"
        if send:
            self.stats["acks" if reply.startswith("PODOA") else "naks"] += 1
            self._send(reply)

    def _command_line(self, line: bytes) -> None:
        if not line.strip():
            return
        self.stats["commands"] += 1
        start = line.find(b"$")
        star = line.rfind(b"*")
        if start < 0 or star < start or len(line) - star != 3:
            self._nak("?", "FORMAT")
            return
        body = line[start + 1:star]
        try:
            ok = int(line[star + 1:].decode("ascii"), 16) == _checksum(body)
        except (ValueError, UnicodeDecodeError):
            ok = False
        if not ok:
            self._nak("?", "CHECKSUM")
            return
        fields = body.decode("ascii", "replace").split(",")
        if fields[0] == "PODOS" and len(fields) == 3 and self.lockstep:
            self._sync(fields)
            return
        if fields[0] not in ("PODOC", "PODOV") or len(fields) != 2:
            self._nak("?", "UNKNOWN")
            return
        cmd = fields[0][-1]
        try:
            value = float(fields[1])
        except ValueError:
            self._nak(cmd, "FORMAT")
            return
        if not math.isfinite(value):
            self._nak(cmd, "FORMAT")
            return
        self._pending.append((cmd, value))

    def _nak(self, cmd: str, reason: str) -> None:
        self.stats["naks"] += 1
        self._send(f"PODON,{cmd},{reason}")

    def _send(self, body: str) -> None:
        data = _sentence(body)
        if self._faults["checksum_rate"] and self._rng.random() < self._faults["checksum_rate"]:
            star = data.rfind(b"*")
            wrong = (_checksum(data[1:star]) ^ int(self._rng.integers(1, 256))) & 0xFF
            data = data[:star + 1] + b"%02X\r\n" % wrong
            self.stats["corrupted"] += 1
        if self._faults["drop_rate"] and self._rng.random() < self._faults["drop_rate"]:
            i = int(self._rng.integers(1, len(data)))  # never the leading '$'
            data = data[:i] + data[i + 1:]
            self.stats["dropped_chars"] += 1
        self.stats["sentences"] += 1
        self._write(data)

    def _write(self, data: bytes) -> None:
        """Queue whole sentences; a full queue (nobody reads the line) drops whole sentences."""
        if len(self._out) + len(data) > _MAX_QUEUE:
            self.stats["overflow_bytes"] += len(data)
            return
        self._out += data
        self._flush()

    def _flush(self) -> None:
        while self._out:
            try:
                n = os.write(self._master, self._out)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # the line is gone
                self.stats["overflow_bytes"] += len(self._out)
                self._out.clear()
                return
            del self._out[:n]


def start_fake(world, *, host=None, port=None, faults: dict | None = None, lockstep: bool = False) -> OdometryFake:
    """Start the odometry fake on a new pty; see the module docstring for ``faults`` and ``lockstep`` (its
    driver then needs ``?lockstep=1``)."""
    if host is not None or port is not None:
        raise ConfigError("the odometry fake serves a pty; host and port do not apply")
    getter = getattr(world, "get_trailer", None)
    if callable(getter):
        trailer = getter()
    else:
        from fakes.sim.trailer import SimTrailer

        trailer = SimTrailer(world.clock, rng=world.rng)
    rng = getattr(world, "rng", None)
    fault_rng = np.random.default_rng(rng.integers(2**63)) if rng is not None else None
    return OdometryFake(trailer, world.clock, faults=faults, rng=fault_rng, lockstep=lockstep)


__all__ = ["start_fake", "OdometryFake", "ODOMETRY_FAULTS", "parse_odometry_faults"]
