"""Robot controller driver: program upload by FTP, control by Modbus TCP.

Device URL: ``modbus+ftp://HOST[:FTP_PORT]?modbus_port=502&user=U&password_env=VAR&dir=D`` (or
``password_file=PATH``; a password in the URL is refused)
(FTP port 21 and Modbus port 502 by default).

What the driver does, in order, and what it refuses:

1. **Gate** -- :meth:`ControllerDriver.upload` takes a
   :class:`~station.programs.program.RenderedProgram` (text made by the
   station's generators from a validated model) and runs the safety gate on
   it (:meth:`station.safety.SafetyGate.check_program`) from the joints the
   controller reports; a refused program never leaves the host.
2. **Upload** -- ``STOR`` of every file over FTP (binary), then read-back
   verification: ``SIZE`` must equal the byte count and a ``RETR`` of the
   file must hash (SHA-256) to what was sent. A mismatch raises
   :class:`UploadVerificationError`.
3. **Handshake** over Modbus TCP, register map
   :class:`~station.programs.handshake.RegisterMap` (documented there):
   select (the controller's CRC-32 of the loaded file must equal the
   uploaded one: what starts is what was gated), start, stop, reset, status,
   cycle counter, fault code.

Errors (all from :mod:`station.errors`)::

    FTP 4xx/5xx reply            -> DeviceError naming the command and reply
    read-back differs            -> UploadVerificationError(DeviceError)
    Modbus exception response    -> ModbusExceptionError(ProtocolError), .exception_code
    no reply / no acknowledge    -> DeviceTimeout
    connection dropped           -> ConnectionLost
    command refused (result!=0)  -> CommandRefused(DeviceError), .result
    controller fault (e-stop...) -> ControllerFault(DeviceFault), .status
    unsafe program               -> SafetyError (before anything is sent)

Safe state: when anything goes wrong while a program may be running
(:meth:`start`, :meth:`wait_done`, :meth:`status` during a run), the driver
sends STOP before raising (reconnecting once if the link dropped) and says in
the message whether the stop was confirmed. If it cannot be, the
controller's communication watchdog (``watchdog_ms``, written at start)
stops the program on its own once the station falls silent. While
:meth:`wait_done` hands a status to the caller (``on_status``: journaling,
which a loaded disk can stall for seconds), a keep-alive thread reads one
register every quarter of the watchdog, for at most ``keepalive_max_s``: a
station that is alive but busy is not taken for a dead one, and one whose
caller hangs still falls silent and is stopped.

Measurement data: this driver never holds measurements. The tracker driver
streams samples to the run's journal as they arrive (the runner journals
each before a step is marked done); when a controller error interrupts a
run, the caller catches it, keeps the journaled samples, and uses the
error's ``status`` (``cycle_count``, ``moves_done``, ``line``) to know which
cycles are complete. ``wait_done(on_status=...)`` reports progress so the
caller can journal it too.
"""

from __future__ import annotations

import ftplib
import hashlib
import io
import logging
import math
import re
import socket
import threading
import time
import zlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from drivers.transport import ListeningDeadline
from station.device_urls import parse_device_url
from station.errors import (
    ConfigError,
    ConnectionLost,
    DeviceError,
    DeviceFault,
    DeviceTimeout,
    ProtocolError,
    SafetyError,
)
from station.protocols.handshake import (
    Command,
    Fault,
    RegisterMap,
    Result,
    State,
    describe,
    encode_name,
    join_i32,
    join_u32,
)
from station.programs import RENDERERS
from station.programs.program import Program, RenderedProgram

__all__ = [
    "CommandRefused",
    "ControllerDriver",
    "ControllerFault",
    "ControllerStatus",
    "ModbusExceptionError",
    "RegisterMap",
    "UploadReceipt",
    "UploadVerificationError",
]

_REMOTE_NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,31}\.(mod|src|dat)", re.ASCII)


class ModbusExceptionError(ProtocolError):
    """The controller answered with a Modbus exception response."""

    def __init__(self, message: str, exception_code: int) -> None:
        super().__init__(message)
        self.exception_code = exception_code


class CommandRefused(DeviceError):
    """The controller acknowledged a command with a non-OK result."""

    def __init__(self, message: str, result: int, status: "ControllerStatus | None" = None) -> None:
        super().__init__(message)
        self.result = result
        self.status = status


class ControllerFault(DeviceFault):
    """The controller is in fault (emergency stop, protective stop, ...)."""

    def __init__(self, message: str, status: "ControllerStatus") -> None:
        super().__init__(message)
        self.status = status


class UploadVerificationError(DeviceError):
    """The file read back from the controller differs from the one sent."""


@dataclass(frozen=True)
class ControllerStatus:
    """One read of the controller's status registers.

    Attributes
    ----------
    state : State
    result : Result
        Result of the last acknowledged command.
    ack_seq : int
    cycle_count : int
        Finished cycles of the running (or last) program.
    fault : Fault
    line : int
        Program line running, or the line refused / faulted (0 = none).
    program_crc32 : int
        CRC-32 of the selected program file.
    q_deg : ndarray, shape (6,)
        Actual joint angles (controller's report), degrees.
    moves_done : int
        Motion instructions completed since start.
    host_time_s : float
        Host monotonic time of the read (not a measurement time base).
    """

    state: State
    result: Result | int
    ack_seq: int
    cycle_count: int
    fault: Fault | int
    line: int
    program_crc32: int
    q_deg: np.ndarray
    moves_done: int
    host_time_s: float

    def summary(self) -> str:
        return (
            f"state {describe(State, self.state)}, fault {describe(Fault, self.fault)}, line {self.line}, "
            f"cycles {self.cycle_count}, moves {self.moves_done}"
        )


@dataclass(frozen=True)
class FileCheck:
    size: int
    sha256: str
    crc32: int


@dataclass(frozen=True)
class UploadReceipt:
    """What was uploaded and verified: file name -> size and hashes."""

    main_file: str
    files: dict[str, FileCheck] = field(default_factory=dict)

    @property
    def main_crc32(self) -> int:
        return self.files[self.main_file].crc32


#: the first pause between two status reads, s (it doubles up to the driver's poll interval)
FIRST_POLL_S = 0.002

# pymodbus logs a lost reply (with its last frames) at ERROR through the root logger, i.e. onto the
# operator's terminal across the progress bar; the driver's own errors name the request, the peer and the
# deadline, and a retried read needs no word. A user who wants pymodbus's frames sets its level again.
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
_log = logging.getLogger(__name__)

#: a read, or a write of a parameter register, whose reply does not come is asked again, on a new connection,
#: this many times in all within the driver's ``timeout_s`` (a command is never repeated: it is acted on once)
READ_ATTEMPTS = 3
#: s: while it waits for an acknowledge or for rest the driver looks at least every poll interval (a status
#: read between), so a longer gap between two looks is a host that did not run this process (nor a simulated
#: controller in it), and only this much of it counts (:class:`drivers.transport.ListeningDeadline`)
LISTEN_SLICE_S = 1.0


def poll_pauses(interval_s: float):
    """Pauses between two status reads: 2, 4, 8 ... ms, doubling up to ``interval_s``, then ``interval_s``.

    A command is acknowledged within one Modbus round trip and the
    controller's next scan, a short program ends soon after its start; a long
    one is polled at the steady interval. Latency is a few ms where the
    answer is quick, the load on the controller that of the steady interval.
    """
    pause = min(FIRST_POLL_S, interval_s)
    while True:
        yield pause
        pause = min(2.0 * pause, interval_s)


def _enum(enum_cls, value: int):
    try:
        return enum_cls(value)
    except ValueError:
        return int(value)


class ControllerDriver:
    """Uploads gated programs by FTP and runs them through a Modbus TCP handshake.

    Parameters
    ----------
    host : str
        Controller address.
    gate : SafetyGate
        The safety gate every program passes before upload (required).
    ftp_port, modbus_port : int
    register_map : RegisterMap, optional
        Default: the documented layout.
    ftp_user, ftp_password : str
    remote_dir : str
        FTP directory the programs go to ("" = login directory).
    timeout_s : float
        Timeout of every network call and of each handshake step.
    poll_interval_s : float
        Steady status polling interval of the handshake and of :meth:`wait_done` (reached by
        doubling from 2 ms, :func:`poll_pauses`).
    watchdog_ms : int
        Communication watchdog written at start (0 = off).
    keepalive_max_s : float
        How long the keep-alive speaks for a caller's ``on_status`` that has not returned (0 = no
        keep-alive); after that the station falls silent and the watchdog stops the program.
    ftp_factory : callable, optional
        ``ftp_factory(timeout_s) -> ftplib.FTP``-like object (injected transport).
    dialect : {"rapid", "krl"}
        The language a dialect-neutral :class:`~station.programs.program.Program` given to :meth:`run` is
        rendered in (a :class:`RenderedProgram` is uploaded as it is).
    modbus_client : object, optional
        A pymodbus-compatible sync client (``connect``, ``close``,
        ``read_holding_registers``, ``write_registers``); default
        ``pymodbus.client.ModbusTcpClient(host, port=modbus_port)``.
    """

    def __init__(
        self,
        host: str,
        *,
        gate,
        ftp_port: int = 21,
        modbus_port: int = 502,
        register_map: RegisterMap | None = None,
        ftp_user: str = "anonymous",
        ftp_password: str = "",
        remote_dir: str = "",
        timeout_s: float = 5.0,
        poll_interval_s: float = 0.02,
        watchdog_ms: int = 2000,
        keepalive_max_s: float = 60.0,
        ftp_factory: Callable[[float], Any] | None = None,
        modbus_client: Any = None,
        dialect: str = "rapid",
    ) -> None:
        if gate is None or not hasattr(gate, "check_program"):
            raise ConfigError("ControllerDriver needs a safety gate (station.safety.SafetyGate)")
        for name, val in (("timeout_s", timeout_s), ("poll_interval_s", poll_interval_s)):
            if not (isinstance(val, (int, float)) and math.isfinite(val) and val > 0):
                raise ConfigError(f"{name} must be a positive number, got {val!r}")
        if not (isinstance(watchdog_ms, int) and 0 <= watchdog_ms <= 65535):
            raise ConfigError(f"watchdog_ms must be an integer in [0, 65535], got {watchdog_ms!r}")
        if not (isinstance(keepalive_max_s, (int, float)) and math.isfinite(keepalive_max_s) and keepalive_max_s >= 0):
            raise ConfigError(f"keepalive_max_s must be a number >= 0, got {keepalive_max_s!r}")
        for name, port in (("ftp_port", ftp_port), ("modbus_port", modbus_port)):
            if not (isinstance(port, int) and 0 < port < 65536):
                raise ConfigError(f"{name} must be in 1..65535, got {port!r}")
        if dialect not in RENDERERS:
            raise ConfigError(f"dialect must be one of {', '.join(RENDERERS)}, got {dialect!r}")
        self.dialect = dialect
        self.host = host
        self.gate = gate
        self.ftp_port = ftp_port
        self.modbus_port = modbus_port
        self.map = register_map or RegisterMap()
        self.ftp_user = ftp_user
        self.ftp_password = ftp_password
        self.remote_dir = remote_dir
        self.timeout_s = float(timeout_s)
        self.poll_interval_s = float(poll_interval_s)
        self.watchdog_ms = watchdog_ms
        self.keepalive_max_s = float(keepalive_max_s)
        self._io_lock = threading.RLock()  # one request at a time on the link (the keep-alive's thread too)
        self.keepalive_reads = 0
        self._ftp_factory = ftp_factory or (lambda t: ftplib.FTP(timeout=t))
        if modbus_client is None:
            from pymodbus.client import ModbusTcpClient

            modbus_client = ModbusTcpClient(
                host, port=modbus_port, timeout=self.timeout_s, retries=0, reconnect_delay=0
            )
        self._mb = modbus_client
        self._seq = 0
        self._receipt: UploadReceipt | None = None
        self._selected: str | None = None
        self._running = False

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_url(cls, url, *, gate, timeout_s: float | None = None, **kwargs) -> "ControllerDriver":
        """``modbus+ftp://host[:ftp_port]?modbus_port=..&user=..&password_env=..&dir=..``
        (defaults from :mod:`station.device_urls`: FTP 21, Modbus 502, user anonymous)."""
        u = parse_device_url(url, scheme="modbus+ftp")
        if timeout_s is not None:
            kwargs["timeout_s"] = timeout_s
        return cls(
            u.host,
            gate=gate,
            ftp_port=u.port,
            modbus_port=u.int_option("modbus_port"),
            ftp_user=u.options["user"],
            ftp_password=u.password(),  # from password_env / password_file, never the URL
            remote_dir=u.options["dir"],
            **kwargs,
        )

    def connect(self) -> "ControllerDriver":
        """Open the Modbus connection (FTP sessions are opened per upload)."""
        try:
            ok = self._mb.connect()
        except Exception as exc:  # noqa: BLE001 - translated at the boundary
            raise ConnectionLost(f"Modbus connect to {self.host}:{self.modbus_port} failed: {exc}") from exc
        if not ok:
            raise ConnectionLost(f"Modbus connect to {self.host}:{self.modbus_port} failed")
        # start numbering after whatever the controller acknowledged last
        self._seq = self.status().ack_seq
        return self

    def close(self) -> None:
        try:
            self._mb.close()
        except Exception:  # noqa: BLE001 - closing is best effort
            pass

    def __enter__(self) -> "ControllerDriver":
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ Modbus primitives
    def _call(self, what: str, fn, *args, retry: bool = False, **kwargs):
        """One Modbus request; ``retry``: an idempotent one (a read) whose reply does not come is asked
        again, on a new connection, up to :data:`READ_ATTEMPTS` times within the same ``timeout_s``.

        The deadline counts the controller's silence (:class:`drivers.transport.ListeningDeadline`): an
        attempt without reply counts as its own wait at most, however long it took, since one that outlasted
        its wait says this process did not run meanwhile (a busy or paused host) and the controller's silence
        was not measured for that time; the next attempt still gets its wait."""
        with self._io_lock:
            return self._call_locked(what, fn, *args, retry=retry, **kwargs)

    def _call_locked(self, what: str, fn, *args, retry: bool = False, **kwargs):
        from pymodbus.exceptions import ConnectionException, ModbusIOException

        deadline = ListeningDeadline(self.timeout_s, self.timeout_s)
        attempts = 0
        while True:
            attempts += 1
            t_sent = time.monotonic()
            wait_s = min(self.timeout_s / READ_ATTEMPTS, deadline.time_left()) if retry else self.timeout_s
            self._reply_timeout(wait_s)
            try:
                rr = fn(*args, device_id=self.map.device_id, **kwargs)
            except ConnectionException as exc:
                self._drop()
                raise ConnectionLost(f"Modbus {what}: connection to {self.host}:{self.modbus_port} lost ({exc})") from exc
            except ModbusIOException as exc:
                self._drop()  # a late reply must not be taken for the next one
                deadline.count_gap(min(time.monotonic() - t_sent, wait_s))  # the host's absence: docstring
                if retry and attempts < READ_ATTEMPTS and deadline.time_left() > 0:
                    continue
                tries = f" ({attempts} attempts)" if attempts > 1 else ""
                raise DeviceTimeout(
                    f"Modbus {what}: no reply from {self.host}:{self.modbus_port} within {self.timeout_s:g} s{tries}"
                ) from exc
            except (OSError, socket.timeout) as exc:
                self._drop()
                raise ConnectionLost(f"Modbus {what}: {exc}") from exc
            break
        if rr is None:
            raise ProtocolError(f"Modbus {what}: empty reply")
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0) or 0)
            raise ModbusExceptionError(f"Modbus {what}: controller answered exception code {code} ({_exc_name(code)})", code)
        return rr

    def _reply_timeout(self, seconds: float) -> None:
        """How long the client waits for the next reply (pymodbus keeps it in ``comm_params``)."""
        params = getattr(self._mb, "comm_params", None)
        if params is not None:
            params.timeout_connect = max(float(seconds), 1e-3)

    def _drop(self) -> None:
        try:
            self._mb.close()
        except Exception:  # noqa: BLE001
            pass

    def _read(self, address: int, count: int) -> list[int]:
        rr = self._call(f"read of registers {address}..{address + count - 1}", self._mb.read_holding_registers, address,
                        count=count, retry=True)
        regs = list(getattr(rr, "registers", []) or [])
        if len(regs) != count:
            raise ProtocolError(f"Modbus read of {count} registers at {address} returned {len(regs)}")
        return regs

    def _write(self, address: int, values: list[int], *, repeatable: bool = True) -> None:
        """Write registers. ``repeatable``: writing the same values again does nothing more (a parameter
        register), so a write whose reply does not come is sent again like a read; a command is not
        (:meth:`_command` learns from the acknowledge whether it arrived)."""
        self._call(f"write of registers {address}..{address + len(values) - 1}", self._mb.write_registers, address,
                   values, retry=repeatable)

    # ------------------------------------------------------------------ status
    def status(self) -> ControllerStatus:
        """Read every status register in one request."""
        start, count = self.map.status_span()
        regs = self._read(start, count)

        def reg(name: str, k: int = 0) -> int:
            return regs[getattr(self.map, name) - start + k]

        q_mdeg = [join_i32(reg("joint_mdeg", 2 * j), reg("joint_mdeg", 2 * j + 1)) for j in range(6)]
        return ControllerStatus(
            state=_enum(State, reg("state")),
            result=_enum(Result, reg("result")),
            ack_seq=reg("ack_seq"),
            cycle_count=reg("cycle_count"),
            fault=_enum(Fault, reg("fault_code")),
            line=reg("line"),
            program_crc32=join_u32(reg("program_crc32"), reg("program_crc32", 1)),
            q_deg=np.array(q_mdeg, dtype=float) / 1000.0,
            moves_done=reg("moves_done"),
            host_time_s=time.monotonic(),
        )

    def _command(self, command: Command, *, prefix: list[tuple[int, list[int]]] = ()) -> ControllerStatus:
        """Write ``prefix`` registers, then ``[command, seq]``; wait for the acknowledge."""
        for address, values in prefix:
            self._write(address, values)
        self._seq = self._seq % 65535 + 1
        seq = self._seq
        unanswered = ""
        try:
            self._write(self.map.command, [int(command), seq], repeatable=False)
        except DeviceTimeout as exc:
            # the request may have arrived and only its reply be late (a host that did not run while it came):
            # the acknowledge tells, and the command is never sent twice
            unanswered = f"; its write had no reply either ({exc})"
        deadline = ListeningDeadline(self.timeout_s, max(LISTEN_SLICE_S, self.poll_interval_s))
        pauses = poll_pauses(self.poll_interval_s)
        while True:
            st = self.status()
            if st.ack_seq == seq:
                break
            if deadline.expired():
                raise DeviceTimeout(
                    f"controller did not acknowledge {command.name} (seq {seq}) within {self.timeout_s:g} s "
                    f"({st.summary()}){unanswered}"
                )
            time.sleep(next(pauses))
        if st.result != Result.OK:
            where = f" at line {st.line}" if st.line else ""
            raise CommandRefused(
                f"controller refused {command.name}: {describe(Result, st.result)}{where} ({st.summary()})",
                int(st.result),
                st,
            )
        return st

    # ------------------------------------------------------------------ upload
    def upload(self, rendered: RenderedProgram, *, q_start=None) -> UploadReceipt:
        """Gate, upload and verify a rendered program.

        Parameters
        ----------
        rendered : RenderedProgram
        q_start : array_like, shape (6,), optional
            Joints the program starts from (rad); default: the joints the
            controller reports now.

        Returns
        -------
        UploadReceipt

        Raises
        ------
        SafetyError
            The gate refused the program; nothing was sent.
        DeviceError, UploadVerificationError, ConnectionLost, DeviceTimeout
        """
        if not isinstance(rendered, RenderedProgram) or rendered.program is None:
            raise SafetyError("only programs rendered by the station's generators can be uploaded (RenderedProgram)")
        if q_start is None:
            q_start = np.radians(self.status().q_deg)
        self.gate.check_program(rendered, q_start=q_start)
        payloads: dict[str, bytes] = {}
        for name, text in rendered.files.items():
            if not _REMOTE_NAME_RE.fullmatch(name):
                raise ConfigError(f"remote file name {name!r} is not a plain program file name")
            try:
                payloads[name] = text.encode("ascii")
            except UnicodeEncodeError as exc:
                raise ConfigError(f"{name}: program text is not ASCII ({exc})") from None
        checks: dict[str, FileCheck] = {}
        ftp = self._ftp_open()
        try:
            for name, data in payloads.items():
                self._ftp(f"STOR {name}", ftp.storbinary, f"STOR {name}", io.BytesIO(data))
                checks[name] = self._verify(ftp, name, data)
        finally:
            try:
                ftp.quit()
            except Exception:  # noqa: BLE001 - the session is over either way
                ftp.close()
        self._receipt = UploadReceipt(rendered.main_file, checks)
        return self._receipt

    def _ftp_open(self):
        ftp = self._ftp_factory(self.timeout_s)
        self._ftp(f"connect {self.host}:{self.ftp_port}", ftp.connect, self.host, self.ftp_port, timeout=self.timeout_s)
        self._ftp(f"login as {self.ftp_user!r}", ftp.login, self.ftp_user, self.ftp_password)
        if self.remote_dir:
            self._ftp(f"CWD {self.remote_dir}", ftp.cwd, self.remote_dir)
        self._ftp("TYPE I", ftp.voidcmd, "TYPE I")
        return ftp

    def _ftp(self, what: str, fn, *args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except ftplib.error_perm as exc:
            raise DeviceError(f"FTP {what} refused by {self.host}: {exc}") from exc
        except ftplib.error_temp as exc:
            raise DeviceError(f"FTP {what}: temporary failure at {self.host}: {exc}") from exc
        except ftplib.Error as exc:
            raise ProtocolError(f"FTP {what}: unexpected reply from {self.host}: {exc}") from exc
        except (socket.timeout, TimeoutError) as exc:
            raise DeviceTimeout(f"FTP {what}: no reply from {self.host} within {self.timeout_s:g} s") from exc
        except (EOFError, OSError) as exc:
            raise ConnectionLost(f"FTP {what}: connection to {self.host}:{self.ftp_port} lost ({exc})") from exc

    def _verify(self, ftp, name: str, data: bytes) -> FileCheck:
        size_reply = self._ftp(f"SIZE {name}", ftp.size, name)
        if size_reply != len(data):
            raise UploadVerificationError(f"{name}: controller reports {size_reply} bytes, {len(data)} were sent")
        got = bytearray()

        def collect(block: bytes) -> None:
            got.extend(block)
            if len(got) > len(data):  # never buffer more than was sent
                raise UploadVerificationError(f"{name}: read-back is longer than the {len(data)} bytes sent")

        self._ftp(f"RETR {name}", ftp.retrbinary, f"RETR {name}", collect)
        sent, back = hashlib.sha256(data).hexdigest(), hashlib.sha256(bytes(got)).hexdigest()
        if len(got) != len(data) or back != sent:
            raise UploadVerificationError(
                f"{name}: read-back differs from what was sent ({len(got)} vs {len(data)} bytes, "
                f"sha256 {back[:12]} vs {sent[:12]})"
            )
        return FileCheck(len(data), sent, zlib.crc32(data) & 0xFFFFFFFF)

    # ------------------------------------------------------------------ handshake
    def select(self, receipt: UploadReceipt | None = None) -> ControllerStatus:
        """Select the uploaded program; the controller's CRC-32 must match the upload."""
        receipt = receipt or self._receipt
        if receipt is None:
            raise SafetyError("select: no verified upload; upload (and gate) a program first")
        st = self._command(Command.SELECT, prefix=[(self.map.program_name, encode_name(receipt.main_file))])
        if st.program_crc32 != receipt.main_crc32:
            raise SafetyError(
                f"select: controller loaded {receipt.main_file} with CRC-32 {st.program_crc32:08x}, "
                f"the gated upload has {receipt.main_crc32:08x}; refusing to start it"
            )
        self._selected = receipt.main_file
        return st

    def start(self) -> ControllerStatus:
        """Start the selected program (watchdog armed first)."""
        if self._selected is None or self._receipt is None:
            raise SafetyError("start: no gated, uploaded and selected program")
        self._write(self.map.watchdog_ms, [self.watchdog_ms])
        self._running = True
        try:
            st = self._command(Command.START)
        except (DeviceError, DeviceTimeout, ConnectionLost) as exc:
            raise self._stop_after(exc)
        if st.program_crc32 != self._receipt.main_crc32:
            raise self._stop_after(SafetyError("start: the controller runs a program other than the gated upload"))
        return st

    def stop(self) -> ControllerStatus:
        """Stop the program (controlled stop) and wait for the acknowledge."""
        st = self._command(Command.STOP)
        self._running = False
        return st

    def reset(self) -> ControllerStatus:
        """Clear a fault (after the cause is removed)."""
        return self._command(Command.RESET)

    def _stop_after(self, exc: BaseException) -> BaseException:
        """Best-effort STOP after ``exc``; returns ``exc`` with the outcome noted."""
        note = self._safe_stop()
        msg = f"{exc.args[0] if exc.args else exc}; {note}"
        exc.args = (msg,) + tuple(exc.args[1:])
        return exc

    def _safe_stop(self) -> str:
        self._running = False
        for attempt in range(2):
            try:
                if attempt:
                    self._drop()
                    if not self._mb.connect():
                        continue
                    self._seq = max(self._seq, self.status().ack_seq)
                self._command(Command.STOP)
                return "program stopped (STOP acknowledged)"
            except CommandRefused as exc:
                if exc.status is not None and exc.status.state in (State.FAULT, State.STOPPED, State.FINISHED, State.READY):
                    return f"program not running ({exc.status.summary()})"
                return f"STOP refused: {exc}"
            except (DeviceError, DeviceTimeout, ConnectionLost):
                continue
        wd = f"{self.watchdog_ms} ms" if self.watchdog_ms else "off"
        return f"STOP could not be confirmed; the controller's comm watchdog ({wd}) stops the program"

    def wait_done(
        self,
        timeout_s: float,
        *,
        on_status: Callable[[ControllerStatus], None] | None = None,
    ) -> ControllerStatus:
        """Poll until the program finishes.

        Parameters
        ----------
        timeout_s : float
            Seconds the program may run at most, counted only while this process polls
            (:class:`drivers.transport.ListeningDeadline`: a host that did not run it for longer than
            :data:`LISTEN_SLICE_S` between two status reads counts that slice only), not counting the time
            ``on_status`` takes.
        on_status : callable, optional
            Called with every status read (progress for the caller's journal). The time it takes is the
            caller's own work (committing samples to a disk that may stall in a sync for many seconds): it
            does not count against ``timeout_s``, and the status it saw is read again before a timeout is
            declared, so a program that finished meanwhile is reported finished.

        Returns
        -------
        ControllerStatus
            The final status (state FINISHED).

        Raises
        ------
        ControllerFault
            The controller went into fault (its ``status`` says where).
        DeviceTimeout, ConnectionLost, ModbusExceptionError
            After a best-effort STOP (noted in the message).
        """
        deadline = ListeningDeadline(float(timeout_s), max(LISTEN_SLICE_S, self.poll_interval_s))
        pauses = poll_pauses(self.poll_interval_s)
        try:
            while True:
                st = self.status()
                if on_status is not None:
                    deadline.time_left()  # the polling up to here counts, the caller's work does not
                    with self._keeping_alive():
                        on_status(st)
                    deadline.count_gap(0.0)
                if st.state == State.FINISHED:
                    self._running = False
                    return st
                if st.state == State.FAULT:
                    self._running = False
                    raise ControllerFault(
                        f"controller fault {describe(Fault, st.fault)} at line {st.line} after "
                        f"{st.cycle_count} cycles, {st.moves_done} moves; the program is stopped",
                        st,
                    )
                if st.state in (State.STOPPED, State.READY, State.NO_PROGRAM):
                    self._running = False
                    raise CommandRefused(f"program is no longer running ({st.summary()})", int(st.result), st)
                if deadline.expired():
                    raise DeviceTimeout(f"program did not finish within {timeout_s:g} s ({st.summary()})")
                time.sleep(next(pauses))
        except ControllerFault:
            raise
        except CommandRefused:
            raise
        except (DeviceError, DeviceTimeout, ConnectionLost) as exc:
            raise self._stop_after(exc)

    @contextmanager
    def _keeping_alive(self):
        """While the body runs (the caller's ``on_status``), read the state register every quarter of the
        watchdog, for at most ``keepalive_max_s``: the controller hears a live station.

        The first read comes a quarter watchdog after entry, so a callback that returns at once costs no
        request. A failed read ends the keep-alive quietly: the next status read of :meth:`wait_done`
        meets the same link and reports it."""
        if not (self.watchdog_ms and self.keepalive_max_s > 0):
            yield
            return
        done = threading.Event()
        every_s = self.watchdog_ms / 4000.0

        def speak() -> None:
            end = time.monotonic() + self.keepalive_max_s
            while not done.wait(every_s) and time.monotonic() < end:
                try:
                    self._read(self.map.state, 1)
                except (DeviceError, DeviceTimeout, ConnectionLost) as exc:
                    _log.debug("keep-alive ended: %s", exc)
                    return
                self.keepalive_reads += 1

        thread = threading.Thread(target=speak, name="controller-keepalive", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()

    def run(self, rendered, *, timeout_s: float, on_status=None) -> ControllerStatus:
        """Gate, upload, verify, select, start and wait: the whole sequence.

        ``rendered`` is a :class:`RenderedProgram`, or a dialect-neutral
        :class:`~station.programs.program.Program` that is rendered here in the driver's ``dialect``.
        """
        if isinstance(rendered, Program):
            rendered = RENDERERS[self.dialect](rendered)
        self.upload(rendered)
        self.select()
        self.start()
        return self.wait_done(timeout_s, on_status=on_status)

    # ------------------------------------------------------------------ the robot interface (drivers.robot)
    def take_over(self) -> tuple[str, str]:
        """Stop a program an earlier session left running; clear the comm-watchdog fault its death caused.

        Any other fault (e-stop, protective stop, ...) is a person's to clear: ``DeviceFault``.
        """
        status = self.status()
        took_over = ""
        if status.state == State.RUNNING:
            # a program of an earlier session (killed station process) is still running: stop it first
            status = self.stop()
            took_over = "stopped a program left running by an earlier session"
        elif status.state == State.FAULT:
            if status.fault != Fault.COMM_WATCHDOG:
                raise DeviceFault(f"controller is in fault {describe(Fault, status.fault)}: clear its cause, "
                                  f"then resume")
            # the watchdog stopped the program when the earlier session died: that is ours to clear
            status = self.reset()
            took_over = "cleared the comm-watchdog fault of an earlier session"
        return status.summary(), took_over

    def release(self) -> None:
        """Stop the station's program if one runs (a program not running is already released)."""
        if self.status().state == State.RUNNING:
            self.stop()

    def move_to(self, target, *, speed_frac: float = 0.2, interpolation: str = "joint",
                timeout_s: float = 60.0) -> ControllerStatus:
        """One gated move as a one-move program: joints (6,) rad, or a Cartesian (4, 4) pose mm."""
        from station.programs.program import CartesianTarget, JointTarget, Move, quat_from_matrix

        t = np.asarray(target, dtype=float)
        if t.shape == (6,):
            tgt = JointTarget("T1", tuple(float(v) for v in np.degrees(t)))
        elif t.shape == (4, 4):
            tgt = CartesianTarget("T1", tuple(float(v) for v in t[:3, 3]), quat_from_matrix(t[:3, :3]))
        else:
            raise SafetyError(f"move_to: target must be joints (6,) rad or a (4, 4) pose, got shape {t.shape}")
        robot = self.gate.robot
        prog = Program(name="ST_MOVE", robot_name=robot.name, rated_tcp_speed_mm_s=float(robot.max_tcp_speed_mm_s),
                       statements=(Move(tgt, interpolation, speed_frac),), accel_frac=0.5, title="station: one move")
        return self.run(prog, timeout_s=timeout_s)

    def wait_settled(self, timeout_s: float) -> ControllerStatus:
        """Until the controller runs no program (it reports a program done only with the arm at rest)."""
        deadline = ListeningDeadline(float(timeout_s), max(LISTEN_SLICE_S, self.poll_interval_s))
        pauses = poll_pauses(self.poll_interval_s)
        while True:
            st = self.status()
            if st.state != State.RUNNING:
                return st
            if deadline.expired():
                raise DeviceTimeout(f"controller still running a program after {timeout_s:g} s ({st.summary()})")
            time.sleep(next(pauses))

    def joints_rad(self) -> np.ndarray:
        return np.radians(self.status().q_deg)

    def tcp_mm(self) -> np.ndarray:
        from station.models import kinematics

        return kinematics.tool_position(self.gate.robot.dh_nominal, self.joints_rad())

    def fault_state(self) -> str | None:
        st = self.status()
        return f"fault {describe(Fault, st.fault)} at line {st.line}" if st.state == State.FAULT else None

    def readings(self) -> None:
        """The Modbus status gives point reads of the joints only (:meth:`joints_rad`), no stream."""
        return None


def _exc_name(code: int) -> str:
    names = {
        1: "illegal function",
        2: "illegal data address",
        3: "illegal data value",
        4: "server device failure",
        5: "acknowledge",
        6: "server device busy",
        8: "memory parity error",
        10: "gateway path unavailable",
        11: "gateway target device failed to respond",
    }
    return names.get(code, "unknown exception")
