"""The FTP library behind the fake controller imports without asyncore/asynchat deprecation warnings."""

import subprocess
import sys


def test_the_fake_controller_imports_without_deprecation_warnings():
    proc = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c",
                           "import fakes.controller, pyftpdlib.servers, pyftpdlib.handlers"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "asyncore" not in proc.stderr and "asynchat" not in proc.stderr
