"""The FTP server of the fake controller starts without asyncore/asynchat deprecation warnings.

pyftpdlib (2.2, the newest) silences them where its IO loop imports the two
modules, but its handlers import asynchat again: imported first, they warn.
The fake controller imports the servers first; a fresh interpreter that
turns the warnings into errors starts and closes the fake's FTP server.
"""

import subprocess
import sys

START_FTP = """
import tempfile
from pathlib import Path
from fakes.controller import FaultPlan, _FtpServer
server = _FtpServer(Path(tempfile.mkdtemp()), "127.0.0.1", FaultPlan(), "a-drawn-password")
server.close()
"""


def test_the_fake_controllers_ftp_server_starts_without_deprecation_warnings():
    proc = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", START_FTP],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "asyncore" not in proc.stderr and "asynchat" not in proc.stderr
