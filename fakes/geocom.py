"""A simulated Leica instrument answering GeoCOM on a pty (raw mode).

Requests ``%R1Q,<rpc>,<trid>:<params>`` CR LF are answered with
``%R1P,0,<trid>:<rc>[,values]`` CR LF; the transaction id is echoed. Empty
lines (the ``\\n`` a client sends on connect) get no reply. Coordinates are in
metres (E, N, H = tracker x, y, z), angles in radians (Hz clockwise from N,
V zenith angle), times in milliseconds of the instrument clock (the source's
``device_time`` when it has one, else the world clock). Measurements come
from ``world.tracker_source()`` on the world's clock.

RPCs: 0 COM_NullProc; 108 COM_GetDoublePrecision; 110 COM_GetSWVersion;
5003 CSV_GetInstrumentNo; 5004 CSV_GetInstrumentName; 5034 CSV_GetSWVersion;
2008 TMC_DoMeasure (program 0 stop, 1 distance, 2 track, 3 clear, 6 measure,
8 rapid track, 10 reduced track); 2082 TMC_GetCoordinate; 2107 TMC_GetAngle5;
2108 TMC_GetSimpleMea; 2116 TMC_GetSimpleCoord. Other rpcs: rc 5 (NOT_IMPL);
wrong parameters: rc 2 (IVPARAM); a ``%R1Q`` line that does not parse:
COM code 3078 (COM_WRONG_FORMAT).

Fault injection (``faults`` dict, string values; times in simulated seconds
after the first TMC_DoMeasure, unless noted)::

    beam_break       "START:DURATION[,...]"  no target: rc 1292 (TMC_DIST_ERROR)
    drop_connection  "START[:DURATION][,...]"  line dead (no replies, input
                     discarded) for DURATION s (default 1)
    garbage          "N"   random 1..64 bytes before every Nth reply
    truncate         "N"   every Nth reply loses its tail (terminator kept)
    slow_reply_s     "X"   every reply delayed X seconds
    not_ready        "always" or "X"  measuring rpcs answer rc 1293 (TMC_BUSY)
                     until X s after the fake started
    seed             "N"   seed of the fault randomness

``start_fake(world, host=None, port=None, faults=None)``: the endpoint is
``{"device": "/dev/pts/N"}``; host and port do not apply to a pty.
"""

from __future__ import annotations

import math
import os
import re
import select
import threading

import numpy as np

from fakes.emscon import parse_tracker_faults
from fakes.pty_port import PtyPort
from fakes.sim.clock import keep_running, stop_running
from station.errors import ConfigError

GEOCOM_FAULTS = frozenset({"beam_break", "drop_connection", "garbage", "truncate", "slow_reply_s",
                           "not_ready", "seed"})

_REQUEST = re.compile(r"^%R1Q,(\d+)(?:,(\d+))?(?:,(\d+))?:(.*)$")
_MAX_LINE = 4096
_OK, _IVPARAM, _NOT_IMPL = 0, 2, 5
_ANGLE_OK, _DIST_ERROR, _BUSY = 1285, 1292, 1293
_COM_WRONG_FORMAT = 3078
_INSTRUMENT_NAME = "AT960"
_SERIAL = 424242


def _num(value: float) -> str:
    return repr(float(value))


class GeoComFake:
    """Handle of a running GeoCOM fake: ``endpoint``, ``stats``, ``close()``."""

    def __init__(self, world, *, host=None, port=None, faults: dict | None = None) -> None:
        if host is not None or port is not None:
            raise ConfigError("the GeoCOM fake serves a pty; host and port do not apply")
        self._faults = parse_tracker_faults(faults, allowed=GEOCOM_FAULTS, drop_default_s=1.0)
        self._source = world.tracker_source()
        self._clock = self._source.clock
        device_time = getattr(self._source, "device_time", None)
        self._offset = float(np.ravel(device_time(np.zeros(1)))[0]) if device_time else 0.0
        self._rng = np.random.default_rng(self._faults.seed)
        self._port = PtyPort()
        self._master = self._port.master
        self.endpoint = {"device": self._port.device}
        self.stats = {"requests": 0, "replies": 0, "ignored_lines": 0, "malformed": 0, "garbage_bytes": 0,
                      "truncated": 0, "dropped_requests": 0, "anchor_t": None}
        self._t_started = self._clock.now()
        # the driver asks for every measurement itself, in real time: the clock runs while it is served
        self._running = keep_running(self._clock)
        self._tracking = False
        self._stored: tuple | None = None  # (xyz_mm, t_s, valid) of the last distance measurement
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="geocom-fake", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._port.close()
        stop_running(self._running)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ I/O
    def _serve(self) -> None:
        buf = bytearray()
        discarding = False  # inside an overlong line
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.05)
            if not ready:
                continue
            data = self._port.read()
            if data is None:  # no driver has the device open at the moment
                self._stop.wait(0.01)
                continue
            if not data:
                continue
            buf += data
            while True:
                idx = buf.find(b"\n")
                if idx < 0:
                    if len(buf) > _MAX_LINE:
                        if not discarding:
                            self.stats["malformed"] += 1
                        discarding = True
                        buf.clear()
                    break
                line = bytes(buf[:idx]).rstrip(b"\r")
                del buf[: idx + 1]
                if discarding or len(line) > _MAX_LINE:
                    if not discarding:
                        self.stats["malformed"] += 1
                    discarding = False
                    continue
                self._line(line)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        waited = 0.0
        while view:
            try:
                n = os.write(self._master, view)
                view = view[n:]
            except BlockingIOError:  # nobody reads the line: give up after a second
                if waited > 1.0 or self._stop.wait(0.005):
                    return
                waited += 0.005

    def _line_dead(self) -> bool:
        anchor = self.stats["anchor_t"]
        if anchor is None:
            return False
        rel = self._clock.now() - anchor
        return any(start <= rel < start + dur for start, dur in self._faults.drop_connection)

    def _line(self, line: bytes) -> None:
        if not line.strip():
            return
        if self._line_dead():
            self.stats["dropped_requests"] += 1
            return
        text = line.decode("latin-1")
        start = text.find("%R1Q,")
        if start < 0:
            self.stats["ignored_lines"] += 1
            return
        m = _REQUEST.match(text[start:])
        if not m:
            self.stats["malformed"] += 1
            trid = re.match(r"^%R1Q,\d+,(\d+)", text[start:])
            self._reply(int(trid.group(1)) % 2**15 if trid else 0, _OK, (), com_rc=_COM_WRONG_FORMAT)
            return
        rpc, trid = int(m.group(1)), int(m.group(2) or 0)
        params = [p for p in m.group(4).split(",")] if m.group(4) else []
        self.stats["requests"] += 1
        rc, values = self._rpc(rpc, params)
        if self._faults.slow_reply_s:
            self._clock.sleep(self._faults.slow_reply_s)
        self._reply(trid, rc, values)

    def _reply(self, trid: int, rc: int, values, com_rc: int = 0) -> None:
        text = f"%R1P,{com_rc},{trid}:{rc}" + "".join("," + v for v in values)
        self.stats["replies"] += 1
        count = self.stats["replies"]
        faults = self._faults
        out = b""
        if faults.garbage_every and count % faults.garbage_every == 0:
            junk = self._rng.integers(0, 256, int(self._rng.integers(1, 65)), dtype=np.uint8).tobytes()
            self.stats["garbage_bytes"] += len(junk)
            out += junk
        body = text.encode("ascii")
        if faults.truncate_every and count % faults.truncate_every == 0 and len(body) > 8:
            body = body[: int(self._rng.integers(8, len(body)))]
            self.stats["truncated"] += 1
        self._write(out + body + b"\r\n")

    # ------------------------------------------------------------------ instrument
    def _not_ready(self) -> bool:
        return self._clock.now() - self._t_started < self._faults.not_ready_s

    def _measure_now(self) -> tuple[np.ndarray, float, bool]:
        """The latest sample on the instrument's grid: (xyz_mm, device t_s, valid)."""
        rate = self._source.rate_hz
        t_dev = math.floor((self._clock.now() + self._offset) * rate) / rate
        t = t_dev - self._offset
        xyz, valid = self._source.measure(np.array([t]))
        ok = bool(np.asarray(valid).ravel()[0])
        anchor = self.stats["anchor_t"]
        if anchor is not None and self._faults.beam_break:
            ok &= not bool(self._faults.beam_blocked(np.array([t - anchor]))[0])
        return np.asarray(xyz, dtype=float).reshape(3), t_dev, ok

    def _rpc(self, rpc: int, params: list[str]) -> tuple[int, tuple]:
        def ints(count: int):
            if len(params) != count:
                return None
            try:
                return [int(p) for p in params]
            except ValueError:
                return None

        if rpc == 0:
            return _OK, ()
        if rpc == 108:
            return _OK, ("15",)
        if rpc == 110:
            return _OK, ("1", "50", "0")
        if rpc == 5003:
            return _OK, (str(_SERIAL),)
        if rpc == 5004:
            return _OK, (f'"{_INSTRUMENT_NAME}"',)
        if rpc == 5034:
            return _OK, ("7", "0", "0")
        if rpc == 2008:
            p = ints(2)
            if p is None:
                return _IVPARAM, ()
            if self.stats["anchor_t"] is None:  # on the instrument's grid, like its samples
                rate = self._source.rate_hz
                self.stats["anchor_t"] = math.floor((self._clock.now() + self._offset) * rate) / rate - self._offset
            if self._not_ready():
                return _BUSY, ()
            program = p[0]
            if program in (1, 6):
                self._stored = self._measure_now()
            elif program in (2, 8, 10):
                self._tracking = True
            elif program == 0:
                self._tracking = False
            elif program == 3:
                self._tracking, self._stored = False, None
            else:
                return _NOT_IMPL, ()
            return _OK, ()
        if rpc in (2082, 2108, 2116):
            p = ints(2)
            if p is None:
                return _IVPARAM, ()
            count = {2082: 8, 2108: 3, 2116: 3}[rpc]
            zeros = ("0.0",) * count
            if rpc == 2082:
                zeros = ("0.0", "0.0", "0.0", "0", "0.0", "0.0", "0.0", "0")
            if self._not_ready():
                return _BUSY, zeros
            current = self._measure_now()
            main = current if self._tracking else self._stored
            if main is None:
                return _ANGLE_OK, zeros
            if not main[2]:
                return _DIST_ERROR, zeros
            e, n, h = main[0] / 1000.0
            if rpc == 2082:
                ce, cn, ch = current[0] / 1000.0 if current[2] else (e, n, h)
                ct = current[1] if current[2] else main[1]
                return _OK, (_num(e), _num(n), _num(h), str(int(round(main[1] * 1000))),
                             _num(ce), _num(cn), _num(ch), str(int(round(ct * 1000))))
            if rpc == 2116:
                return _OK, (_num(e), _num(n), _num(h))
            hz, v, d = _polar(e, n, h)
            return _OK, (_num(hz), _num(v), _num(d))
        if rpc == 2107:
            p = ints(1)
            if p is None:
                return _IVPARAM, ()
            e, n, h = self._measure_now()[0] / 1000.0
            hz, v, _ = _polar(e, n, h)
            return _OK, (_num(hz), _num(v))
        return _NOT_IMPL, ()


def _polar(e: float, n: float, h: float) -> tuple[float, float, float]:
    """Hz clockwise from N, V zenith angle (rad), slope distance (m)."""
    hz = math.atan2(e, n) % (2 * math.pi)
    v = math.atan2(math.hypot(e, n), h)
    return hz, v, math.sqrt(e * e + n * n + h * h)


def start_fake(world, *, host=None, port=None, faults: dict | None = None) -> GeoComFake:
    """Start the GeoCOM fake on a new pty; see the module docstring for ``faults``."""
    return GeoComFake(world, host=host, port=port, faults=faults)


__all__ = ["start_fake", "GeoComFake", "GEOCOM_FAULTS"]
