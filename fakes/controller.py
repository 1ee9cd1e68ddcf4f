"""Robot controller fake: a real FTP server, a real Modbus TCP server, a RAPID interpreter.

``start_fake(world, host=None, port=None, faults=None)`` binds on loopback
(default ``127.0.0.1``, never a non-loopback address):

* an FTP server (pyftpdlib) on an ephemeral port whose root is the
  controller's program directory (user ``station``, a password drawn anew
  for each fake; anonymous logins are refused);
* a Modbus TCP server (pymodbus) on ``port`` (default ephemeral) serving the
  handshake registers of :class:`~station.programs.handshake.RegisterMap`;
* a controller thread that processes the handshake commands, compiles the
  selected ``.mod`` file with :func:`fakes.rapid_interp.compile_rapid`
  (syntax, subset and the controller's own safety gate: an unsafe program is
  refused with ``Result.SAFETY_REFUSED`` and its line in the ``line``
  register) and runs it on ``world.arm`` (:class:`fakes.rapid_interp.RapidRun`).

The returned handle has ``endpoint`` = ``{"host": "127.0.0.1", "ftp_port": N,
"modbus_port": M, "ftp_user": "station", "ftp_password": "<drawn>",
"device_id": 1}`` and ``close()``, which stops the program and the servers
and joins every thread.

Fault injection (``faults``: string keys and values, e.g. from
``station fakes serve controller --fault KEY=VALUE``):

=========================  ==================================================
key=value                  effect
=========================  ==================================================
modbus_exception=CODE      answer matching requests with Modbus exception CODE
                           (1..11, e.g. 4 device failure, 6 busy)
modbus_exception_on=WHEN   which requests: select | start | stop | reset |
                           status (reads while a program runs) | any (every
                           request, default)
modbus_exception_count=N   how many matching requests fail (default 1)
drop_connection=WHEN       close the client's TCP connection on the first
                           matching request (select|start|stop|reset|status)
modbus_silent=WHEN         never answer the first matching request (client
                           times out)
ack_stall=COMMAND          never acknowledge COMMAND (select|start|stop|reset)
ftp_refuse=WHAT            refuse login (530) | stor | retr | size (550)
ftp_corrupt=KIND           corrupt stored uploads: flip (one byte changed,
                           same size) | truncate (last byte dropped)
protective_stop_move=N     protective stop in the middle of the N-th move of
                           a run (the arm decelerates and halts; state FAULT,
                           fault PROTECTIVE_STOP; RESET clears it)
emergency_stop_move=N      same, fault EMERGENCY_STOP
=========================  ==================================================

Safe state: every fault ends with the program stopped and the arm at rest
(protective stop ramp); the communication watchdog (``watchdog_ms`` register)
stops a running program when the station falls silent.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import queue
import os
import re
import secrets
import shutil
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import numpy as np

from fakes.rapid_interp import RapidError, RapidRun, RapidSafetyError, ProgramStopped, compile_rapid
from station.errors import ConfigError, SafetyError
from station.protocols.handshake import (
    Command,
    Fault,
    RegisterMap,
    Result,
    State,
    decode_name,
    split_u32,
)
from station.safety import SafetyGate, SafetyLimits, default_limits

_log = logging.getLogger(__name__)

FTP_USER = "station"

_WHEN = {"select", "start", "stop", "reset", "status", "any"}
_FILE_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,31}\.(mod|src|dat)", re.ASCII)
_KNOWN_FAULTS = {
    "modbus_exception",
    "modbus_exception_on",
    "modbus_exception_count",
    "drop_connection",
    "modbus_silent",
    "ack_stall",
    "ftp_refuse",
    "ftp_corrupt",
    "protective_stop_move",
    "emergency_stop_move",
}


@dataclass
class FaultPlan:
    """Parsed fault-injection settings (see the module docstring)."""

    modbus_exception: int = 0
    modbus_exception_on: str = "any"
    modbus_exception_count: int = 1
    drop_connection: str = ""
    modbus_silent: str = ""
    ack_stall: str = ""
    ftp_refuse: str = ""
    ftp_corrupt: str = ""
    protective_stop_move: int = 0
    emergency_stop_move: int = 0

    @classmethod
    def parse(cls, faults: dict[str, str] | None) -> "FaultPlan":
        plan = cls()
        for key, value in (faults or {}).items():
            if key not in _KNOWN_FAULTS:
                raise ConfigError(f"controller fake: unknown fault {key!r} (known: {', '.join(sorted(_KNOWN_FAULTS))})")
            value = str(value).strip().lower()
            if key in ("modbus_exception", "modbus_exception_count", "protective_stop_move", "emergency_stop_move"):
                try:
                    n = int(value)
                except ValueError:
                    raise ConfigError(f"controller fake: fault {key} needs an integer, got {value!r}") from None
                lo, hi = (1, 255) if key == "modbus_exception" else (1, 10**6)
                if not lo <= n <= hi:
                    raise ConfigError(f"controller fake: fault {key}={n} is outside [{lo}, {hi}]")
                setattr(plan, key, n)
            elif key in ("modbus_exception_on", "drop_connection", "modbus_silent"):
                if value not in _WHEN:
                    raise ConfigError(f"controller fake: fault {key} must be one of {', '.join(sorted(_WHEN))}")
                setattr(plan, key, value)
            elif key == "ack_stall":
                if value not in ("select", "start", "stop", "reset"):
                    raise ConfigError("controller fake: fault ack_stall must be select, start, stop or reset")
                plan.ack_stall = value
            elif key == "ftp_refuse":
                if value not in ("login", "stor", "retr", "size"):
                    raise ConfigError("controller fake: fault ftp_refuse must be login, stor, retr or size")
                plan.ftp_refuse = value
            elif key == "ftp_corrupt":
                if value not in ("flip", "truncate"):
                    raise ConfigError("controller fake: fault ftp_corrupt must be flip or truncate")
                plan.ftp_corrupt = value
        return plan


def _loopback(host: str | None) -> str:
    host = host or "127.0.0.1"
    try:
        ok = ipaddress.ip_address(host).is_loopback
    except ValueError:
        ok = host == "localhost"
    if not ok:
        raise ConfigError(f"controller fake binds loopback addresses only, got {host!r}")
    return "127.0.0.1" if host == "localhost" else host


#: a gap this long between two watchdog checks (every 20 ms) means the fake itself was not running, s
_STARVED_S = 0.25


# ---------------------------------------------------------------------- controller core
class ControllerCore:
    """The controller's state machine: handshake commands, program runs, watchdog.

    Thread model: Modbus requests (server loop thread) only read a snapshot
    and queue commands; one worker thread processes commands and the
    watchdog; one run thread executes a program at a time.
    """

    def __init__(self, world, program_dir: Path, gate: SafetyGate, faults: FaultPlan, register_map: RegisterMap) -> None:
        self.world = world
        self.dir = program_dir
        self.gate = gate
        self.faults = faults
        self.map = register_map
        self._lock = threading.RLock()
        self._commands: queue.Queue = queue.Queue()
        self._closing = threading.Event()
        self.state = State.NO_PROGRAM
        self.result = Result.OK
        self.ack_seq = 0
        self.cycle_count = 0
        self.fault = Fault.NONE
        self.line = 0
        self.crc32 = 0
        self.moves_done = 0
        self.watchdog_ms = 0
        self.name_regs = [0] * 16
        self.program = None
        self.messages: list[str] = []
        self.last_error = ""
        self.last_request = time.monotonic()
        self._last_check = self.last_request
        self._run: RapidRun | None = None
        self._runs_by_name: dict[str, int] = {}
        self._run_thread: threading.Thread | None = None
        self._worker = threading.Thread(target=self._work, name="controller-fake-worker")
        self._worker.start()

    # -------------------------------------------------------------- register image
    def touch(self) -> None:
        self.last_request = time.monotonic()

    def snapshot(self) -> dict[int, int]:
        """Register address -> value of every read-only register."""
        m = self.map
        with self._lock:
            try:
                q = np.asarray(self.world.arm.actual_q_rad(self.world.clock.now()), dtype=float).reshape(6)
            except Exception:  # noqa: BLE001 - a query outside the arm's history reads as commanded
                q = np.asarray(self.world.arm.commanded_q_rad(), dtype=float).reshape(6)
            regs = {
                m.ack_seq: self.ack_seq,
                m.result: int(self.result),
                m.state: int(self.state),
                m.cycle_count: self.cycle_count & 0xFFFF,
                m.fault_code: int(self.fault),
                m.line: min(self.line, 0xFFFF),
                m.moves_done: self.moves_done & 0xFFFF,
            }
            hi, lo = split_u32(self.crc32)
            regs[m.program_crc32], regs[m.program_crc32 + 1] = hi, lo
            mdeg = np.round(np.degrees(q) * 1000.0).astype(np.int64)
            for j in range(6):
                hi, lo = split_u32(int(mdeg[j]))
                regs[m.joint_mdeg + 2 * j], regs[m.joint_mdeg + 2 * j + 1] = hi, lo
            regs[m.watchdog_ms] = self.watchdog_ms
            for k, v in enumerate(self.name_regs):
                regs[m.program_name + k] = v
        return regs

    def write(self, address: int, values: list[int]) -> int | None:
        """Apply a client write; return a Modbus exception code or None."""
        m = self.map
        span = range(address, address + len(values))
        writable = set()
        for name in RegisterMap.WRITABLE:
            writable.update(m.span(name))
        if any(a not in writable for a in span):
            return 2  # illegal data address: read-only register
        cmd = seq = None
        with self._lock:
            for a, v in zip(span, values):
                if a == m.command:
                    cmd = v
                elif a == m.command_seq:
                    seq = v
                elif a == m.watchdog_ms:
                    self.watchdog_ms = v
                elif a in m.span("program_name"):
                    self.name_regs[a - m.program_name] = v
        if cmd is not None or seq is not None:
            if cmd is None or seq is None:
                return 3  # illegal data value: command and sequence go in one request
            if seq != self.ack_seq:
                self._commands.put((cmd, seq))
        return None

    # -------------------------------------------------------------- worker
    def _work(self) -> None:
        while not self._closing.is_set():
            try:
                cmd, seq = self._commands.get(timeout=0.02)
            except queue.Empty:
                cmd = None
            if cmd is not None:
                self._process(cmd, seq)
            self._check_watchdog()
            self._reap_run()

    def _ack(self, seq: int, result: Result, line: int | None = None) -> None:
        with self._lock:
            self.result = result
            if line is not None:
                self.line = line
            self.ack_seq = seq

    def _process(self, cmd: int, seq: int) -> None:
        try:
            command = Command(cmd)
        except ValueError:
            self._ack(seq, Result.UNKNOWN_COMMAND)
            return
        if self.faults.ack_stall == command.name.lower():
            return  # injected: the command is swallowed, never acknowledged
        if command == Command.SELECT:
            self._select(seq)
        elif command == Command.START:
            self._start(seq)
        elif command == Command.STOP:
            self._stop(State.STOPPED, Fault.NONE)
            self._ack(seq, Result.OK)
        elif command == Command.RESET:
            self._reset(seq)
        else:
            self._ack(seq, Result.UNKNOWN_COMMAND)

    def _q_now(self) -> np.ndarray:
        return np.asarray(self.world.arm.commanded_q_rad(self.world.clock.now()), dtype=float).reshape(6)

    def _select(self, seq: int) -> None:
        with self._lock:
            state = self.state
            regs = list(self.name_regs)
        if state == State.RUNNING:
            self._ack(seq, Result.NOT_ALLOWED)
            return
        if state == State.FAULT:
            self._ack(seq, Result.FAULT_ACTIVE)
            return
        try:
            name = decode_name(regs)
        except UnicodeDecodeError:
            name = ""
        if not _FILE_RE.fullmatch(name) or not (self.dir / name).is_file():
            self._ack(seq, Result.NO_SUCH_PROGRAM)
            return
        if not name.endswith(".mod"):
            self._ack(seq, Result.UNSUPPORTED_DIALECT)
            return
        data = (self.dir / name).read_bytes()
        crc = zlib.crc32(data) & 0xFFFFFFFF
        try:
            compiled = compile_rapid(data, self.world.robot, self.gate, q_start=self._q_now())
        except RapidSafetyError as exc:
            self._loaded(None, 0, State.NO_PROGRAM)
            self._ack(seq, Result.SAFETY_REFUSED, exc.line)
            self.last_error = str(exc)
            return
        except RapidError as exc:
            self._loaded(None, 0, State.NO_PROGRAM)
            self._ack(seq, Result.PROGRAM_ERROR, exc.line)
            self.last_error = str(exc)
            return
        self._loaded(compiled, crc, State.READY)
        self._ack(seq, Result.OK, 0)

    def _loaded(self, compiled, crc: int, state: State) -> None:
        with self._lock:
            self.program = compiled
            self.crc32 = crc
            self.state = state
            self.cycle_count = 0
            self.moves_done = 0
            self.messages = list(compiled.messages) if compiled else []

    def _start(self, seq: int) -> None:
        with self._lock:
            state, compiled = self.state, self.program
        if state == State.FAULT:
            self._ack(seq, Result.FAULT_ACTIVE)
            return
        if state == State.RUNNING or compiled is None:
            self._ack(seq, Result.NOT_ALLOWED)
            return
        try:  # the arm may have moved since select: gate again from where it stands
            self.gate.check_program(compiled.program, q_start=self._q_now())
        except SafetyError as exc:
            m = re.match(r"line (\d+)", str(exc))
            self.last_error = str(exc)
            self._ack(seq, Result.SAFETY_REFUSED, int(m.group(1)) if m else 0)
            return
        fault_at = {}
        if self.faults.protective_stop_move:
            fault_at["protective_stop"] = self.faults.protective_stop_move
        if self.faults.emergency_stop_move:
            fault_at["emergency_stop"] = self.faults.emergency_stop_move
        name = compiled.program.name
        self._runs_by_name[name] = self._runs_by_name.get(name, 0) + 1
        run = RapidRun(
            self.world, compiled, self.gate, self._on_progress, fault_at_move=fault_at, on_fault=self._on_injected_fault,
            run_no=self._runs_by_name[name],
        )
        with self._lock:
            self.state = State.RUNNING
            self.fault = Fault.NONE
            self.cycle_count = 0
            self.moves_done = 0
            self.line = 0
            self._run = run
            self.touch()
            self._run_thread = threading.Thread(target=self._execute, args=(run,), name="controller-fake-run")
            self._run_thread.start()
        self._ack(seq, Result.OK)

    def _on_progress(self, p) -> None:
        with self._lock:
            self.line = p.line
            self.cycle_count = p.cycle_count
            self.moves_done = p.moves_done

    def _on_injected_fault(self, kind: str, line: int) -> None:
        with self._lock:
            self.state = State.FAULT
            self.fault = Fault.EMERGENCY_STOP if kind == "emergency_stop" else Fault.PROTECTIVE_STOP
            self.line = line

    def _execute(self, run: RapidRun) -> None:
        try:
            run.run()
        except ProgramStopped:
            return  # whoever stopped the run set the state
        except Exception as exc:  # noqa: BLE001 - any runtime error faults the program safely
            if run.stop_event.is_set():
                return  # stopped while a move was being queued: the arm refused it, as intended
            self.last_error = f"{type(exc).__name__}: {exc}"
            fault = Fault.SAFETY if isinstance(exc, SafetyError) else Fault.PROGRAM_ERROR
            self._halt_arm()
            with self._lock:
                self.state, self.fault = State.FAULT, fault
            return
        with self._lock:
            if self.state == State.RUNNING:
                self.state = State.FINISHED

    def _halt_arm(self) -> None:
        arm = self.world.arm
        if arm.state == "moving":
            arm.protective_stop()
            arm.wait_idle(self._closing)

    def _stop(self, state: State, fault: Fault) -> None:
        """Stop a running program (controlled stop), leave ``state``/``fault``."""
        with self._lock:
            run, thread = self._run, self._run_thread
            running = self.state == State.RUNNING
            if running:
                self.state, self.fault = state, fault
        if run is None or not running:
            return
        run.request_stop()
        arm = self.world.arm
        if arm.state == "moving":
            arm.protective_stop()
        if thread is not None:
            thread.join(10.0)
        arm.wait_idle(self._closing)
        if fault == Fault.NONE:
            arm.reset()  # a controlled stop leaves the arm ready

    def _reset(self, seq: int) -> None:
        with self._lock:
            state = self.state
        if state == State.RUNNING:
            self._ack(seq, Result.NOT_ALLOWED)
            return
        self._reap_run()
        self.world.arm.wait_idle(self._closing)
        self.world.arm.reset()
        with self._lock:
            if self.state == State.FAULT:
                self.state = State.READY if self.program is not None else State.NO_PROGRAM
            self.fault = Fault.NONE
        self._ack(seq, Result.OK)

    def _check_watchdog(self) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._last_check > _STARVED_S:
                # this process (which serves the link too) did not run for a while: a silence it could not
                # hear is not the station's; the watchdog counts from now (a real timeout, on the wall)
                self.last_request = max(self.last_request, now)
            self._last_check = now
            wd = self.watchdog_ms
            running = self.state == State.RUNNING
            silent_ms = (now - self.last_request) * 1000.0
        if running and wd > 0 and silent_ms > wd:
            self._stop(State.FAULT, Fault.COMM_WATCHDOG)

    def _reap_run(self) -> None:
        with self._lock:
            thread = self._run_thread
        if thread is not None and not thread.is_alive():
            thread.join()
            with self._lock:
                if self._run_thread is thread:
                    self._run_thread = None

    def close(self) -> None:
        self._stop(State.STOPPED, Fault.NONE)
        self._closing.set()
        self._worker.join(10.0)
        with self._lock:
            thread = self._run_thread
        if thread is not None:
            thread.join(10.0)


# ---------------------------------------------------------------------- Modbus server
class _ModbusServer:
    """pymodbus TCP server in its own event-loop thread."""

    def __init__(self, core: ControllerCore, host: str, port: int, faults: FaultPlan) -> None:
        from pymodbus.simulator import DataType, SimData, SimDevice

        self.core = core
        self.faults = faults
        m = core.map
        self._exc_left = faults.modbus_exception_count if faults.modbus_exception else 0
        self._dropped = False
        self._silenced = False
        self._device = SimDevice(
            m.device_id,
            simdata=[SimData(m.lowest, count=m.highest - m.lowest + 1, values=0, datatype=DataType.REGISTERS)],
            action=self._action,
        )
        self._host, self._port = host, port
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.port = 0
        self.loop: asyncio.AbstractEventLoop | None = None
        self.server = None
        self._closing: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._serve, name="controller-fake-modbus")
        self._thread.start()
        if not self._ready.wait(10.0):
            raise ConfigError("controller fake: Modbus server did not start within 10 s")
        if self._error is not None:
            self._thread.join()
            raise ConfigError(f"controller fake: Modbus server failed to start: {self._error}")

    def _serve(self) -> None:
        from pymodbus.server import ModbusTcpServer

        loop = asyncio.new_event_loop()
        self.loop = loop

        async def main() -> None:
            self._closing = asyncio.Event()
            self.server = ModbusTcpServer(self._device, address=(self._host, self._port))
            await self.server.serve_forever(background=True)
            sock = self.server.transport.sockets[0]
            self.port = sock.getsockname()[1]
            self._ready.set()
            await self.server.serving

        try:
            loop.run_until_complete(main())
        except BaseException as exc:  # noqa: BLE001 - reported to the starting thread
            self._error = exc
            self._ready.set()
        finally:
            pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
            for t in pending:
                t.cancel()
            if pending:
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.close()

    def _classify(self, address: int, values) -> str:
        m = self.core.map
        if values is None:
            return "status" if self.core.state == State.RUNNING else "read"
        if m.command in range(address, address + len(values)):
            code = values[m.command - address]
            try:
                return Command(code).name.lower()
            except ValueError:
                return "write"
        return "write"

    @staticmethod
    def _matches(rule: str, kind: str) -> bool:
        return bool(rule) and (rule == kind or rule == "any")

    async def _action(self, fc, start_address, address, count, registers, values):
        from pymodbus.constants import ExcCodes

        core = self.core
        core.touch()
        kind = self._classify(address, values)
        f = self.faults
        if self._exc_left > 0 and self._matches(f.modbus_exception_on, kind):
            self._exc_left -= 1
            try:
                return ExcCodes(f.modbus_exception)
            except ValueError:
                return ExcCodes.DEVICE_FAILURE
        if f.drop_connection and not self._dropped and self._matches(f.drop_connection, kind):
            self._dropped = True
            for conn in list(self.server.active_connections.values()):
                conn.transport.close()
            return ExcCodes.DEVICE_FAILURE  # never delivered: the connection is gone
        if f.modbus_silent and not self._silenced and self._matches(f.modbus_silent, kind):
            self._silenced = True
            try:
                await asyncio.wait_for(self._closing.wait(), timeout=30.0)
            except asyncio.TimeoutError:
                pass
            return ExcCodes.DEVICE_BUSY
        if values is None:
            snap = core.snapshot()
            for a in range(address, address + count):
                registers[a - start_address] = snap.get(a, 0)
            return None
        code = core.write(address, list(values))
        if code is not None:
            return ExcCodes(code)
        return None

    def close(self) -> None:
        if self.loop is not None and self.server is not None and self._thread.is_alive():
            def stop() -> None:
                if self._closing is not None:
                    self._closing.set()

            self.loop.call_soon_threadsafe(stop)
            fut = asyncio.run_coroutine_threadsafe(self.server.shutdown(), self.loop)
            try:
                fut.result(10.0)
            except Exception:  # noqa: BLE001 - shutting down regardless
                pass
        self._thread.join(10.0)


# ---------------------------------------------------------------------- FTP server
class _FtpServer:
    """pyftpdlib server in its own thread, rooted at the program directory."""

    def __init__(self, root: Path, host: str, faults: FaultPlan, password: str) -> None:
        # servers first: its IO loop imports asyncore/asynchat with their deprecation warnings silenced, so the
        # handlers' own `import asynchat` finds them loaded and warns no more
        from pyftpdlib.servers import FTPServer  # noqa: I001
        from pyftpdlib.authorizers import AuthenticationFailed, DummyAuthorizer
        from pyftpdlib.handlers import FTPHandler

        refuse = faults.ftp_refuse
        corrupt = faults.ftp_corrupt

        class _Authorizer(DummyAuthorizer):
            def validate_authentication(self, username, password, handler):
                if refuse == "login":
                    raise AuthenticationFailed("Login refused by the controller (injected fault).")
                return super().validate_authentication(username, password, handler)

        auth = _Authorizer()
        auth.add_user(FTP_USER, password, str(root), perm="elradfmw")

        class _Handler(FTPHandler):
            authorizer = auth
            banner = "robot controller fake ready"
            timeout = 30
            auth_failed_timeout = 0.1  # pyftpdlib waits 3 s before answering a bad login

            def log(self, msg, logfun=None):  # session chatter at debug level only
                _log.debug("%s %s", self.remote_ip, msg)

            def ftp_STOR(self, file, mode="w"):
                if refuse == "stor":
                    self.respond("550 Program memory write-protected (injected fault).")
                    return None
                return super().ftp_STOR(file, mode)

            def ftp_RETR(self, file):
                if refuse == "retr":
                    self.respond("550 Read-back refused (injected fault).")
                    return None
                return super().ftp_RETR(file)

            def ftp_SIZE(self, path):
                if refuse == "size":
                    self.respond("550 SIZE refused (injected fault).")
                    return None
                return super().ftp_SIZE(path)

            def on_file_received(self, file):
                if not corrupt:
                    return
                p = Path(file)
                data = bytearray(p.read_bytes())
                if not data:
                    return
                if corrupt == "truncate":
                    del data[-1]
                else:
                    i = len(data) // 2
                    data[i] = data[i] ^ 0x01
                p.write_bytes(bytes(data))

        self._server = FTPServer((host, 0), _Handler)
        self.port = self._server.socket.getsockname()[1]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="controller-fake-ftp")
        self._thread.start()

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                # one poll of pyftpdlib's IO loop (at most 50 ms), then check for close()
                self._server.ioloop.loop(0.05, blocking=False)
        finally:
            self._server.close_all()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(10.0)


# ---------------------------------------------------------------------- handle
class ControllerFake:
    """Handle of a running controller fake (``endpoint``, ``close()``, ``sim_*`` inspection)."""

    def __init__(self, world, *, host=None, port=None, faults=None, register_map=None, limits=None) -> None:
        host = _loopback(host)
        if port is not None and not (isinstance(port, int) and 0 <= port < 65536):
            raise ConfigError(f"controller fake: port must be in 0..65535, got {port!r}")
        plan = FaultPlan.parse(faults)
        self.world = world
        self.register_map = register_map or RegisterMap()
        self.gate = SafetyGate(world.robot, limits or default_limits(world.robot))
        self._tmp = tempfile.mkdtemp(prefix="controller-fake-")
        self.program_dir = Path(self._tmp)
        # the FTP password: drawn anew, handed to the station as a file (its URL names the file, never the secret)
        self.ftp_password = secrets.token_hex(12)
        self._secret_dir = tempfile.mkdtemp(prefix="controller-fake-secret-")
        self.password_file = Path(self._secret_dir) / "ftp.pass"
        fd = os.open(self.password_file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(self.ftp_password + "\n")
        self.core = ControllerCore(world, self.program_dir, self.gate, plan, self.register_map)
        self._ftp = self._modbus = None
        try:
            self._ftp = _FtpServer(self.program_dir, host, plan, self.ftp_password)
            self._modbus = _ModbusServer(self.core, host, port or 0, plan)
        except BaseException:
            self.close()
            raise
        self.endpoint = {
            "host": host,
            "ftp_port": self._ftp.port,
            "modbus_port": self._modbus.port,
            "ftp_user": FTP_USER,
            "ftp_password": self.ftp_password,
            "device_id": self.register_map.device_id,
        }

    @property
    def url(self) -> str:
        e = self.endpoint
        return (
            f"modbus+ftp://{e['host']}:{e['ftp_port']}?modbus_port={e['modbus_port']}"
            f"&user={FTP_USER}&password_file={quote(str(self.password_file), safe='/')}"
        )

    def sim_last_error(self) -> str:
        """Why the last program was refused or faulted (test inspection)."""
        return self.core.last_error

    def close(self) -> None:
        if self._modbus is not None:
            self._modbus.close()
            self._modbus = None
        if self._ftp is not None:
            self._ftp.close()
            self._ftp = None
        if getattr(self, "core", None) is not None:
            self.core.close()
            self.core = None
        shutil.rmtree(self._tmp, ignore_errors=True)
        if getattr(self, "_secret_dir", None):
            shutil.rmtree(self._secret_dir, ignore_errors=True)


def start_fake(world, *, host=None, port=None, faults=None, register_map=None, limits: SafetyLimits | None = None) -> ControllerFake:
    """Start the controller fake on loopback; see the module docstring.

    Parameters
    ----------
    world : World
        Simulated world (``clock``, ``robot``, ``arm``).
    host : str, optional
        Loopback address to bind (default 127.0.0.1).
    port : int, optional
        Modbus TCP port (default ephemeral); the FTP port is always ephemeral.
    faults : dict of str to str, optional
        Fault injection (keys in the module docstring).
    register_map : RegisterMap, optional
    limits : SafetyLimits, optional
        The controller's own safety configuration (default: a box around the
        robot's reach and its rated speed).
    """
    return ControllerFake(world, host=host, port=port, faults=faults, register_map=register_map, limits=limits)
