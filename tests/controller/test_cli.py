"""`station fakes serve controller` prints its endpoints first and serves real FTP and Modbus."""

from __future__ import annotations

import ftplib
import io
import json
import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from station.protocols.handshake import RegisterMap, State

ROOT = Path(__file__).resolve().parents[2]


def _readline(proc, timeout_s: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout_s
    buf = b""
    while not buf.endswith(b"\n"):
        left = end - time.monotonic()
        assert left > 0, f"no endpoint line within {timeout_s} s (got {buf!r})"
        if sel.select(left):
            chunk = os.read(proc.stdout.fileno(), 4096)
            assert chunk, f"the fake exited: {proc.stderr.read().decode(errors='replace')}"
            buf += chunk
    return buf.decode()


def test_serve_controller_from_the_command_line():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "fakes", "serve", "controller", "--time-scale", "50", "--fault", "ftp_refuse=retr"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        endpoint = json.loads(_readline(proc, 30.0).splitlines()[0])
        assert endpoint["host"] == "127.0.0.1" and endpoint["ftp_port"] > 0 and endpoint["modbus_port"] > 0
        ftp = ftplib.FTP(timeout=5)
        ftp.connect(endpoint["host"], endpoint["ftp_port"])
        ftp.login(endpoint["ftp_user"], endpoint["ftp_password"])
        ftp.storbinary("STOR X.mod", io.BytesIO(b"MODULE X\nENDMODULE\n"))
        try:
            ftp.retrbinary("RETR X.mod", lambda b: None)
            raise AssertionError("the injected RETR refusal did not happen")
        except ftplib.error_perm as exc:
            assert str(exc).startswith("550")
        ftp.quit()
        m = RegisterMap()
        c = ModbusTcpClient(endpoint["host"], port=endpoint["modbus_port"], timeout=3, retries=0)
        assert c.connect()
        rr = c.read_holding_registers(m.state, count=1, device_id=m.device_id)
        assert not rr.isError() and rr.registers == [State.NO_PROGRAM]
        c.close()
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            proc.stdout.close()
            proc.stderr.close()
    assert rc == 0
