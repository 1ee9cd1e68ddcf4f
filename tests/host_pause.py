"""A host that does not run: the tests' processes stopped (SIGSTOP) for a while, then continued (SIGCONT).

A busy host does this to a process at random; here a child shell does it at the moment a test chooses, so a
deadline that counts the host's time as a device's silence fails every time, not once in a while under load.
"""

from __future__ import annotations

import os
import subprocess


def pause_host(seconds: float, pids=None) -> None:
    """Stop ``pids`` (default: this process) for ``seconds``, then continue them; returns once they run again
    (called from a thread of a stopped process, it returns after the process was continued). The shell
    continues them however it ends, so a test cannot leave them stopped."""
    pids = [os.getpid()] if pids is None else [int(p) for p in pids]
    if not 0 < seconds < 60:
        raise ValueError(f"a host pause of {seconds!r} s is not one a test should take")
    listed = " ".join(str(p) for p in pids)
    script = (f"trap 'kill -CONT {listed} 2>/dev/null' EXIT; trap 'exit 1' TERM INT HUP; "
              f"kill -STOP {listed}; sleep {float(seconds):.3f}")
    subprocess.run(["sh", "-c", script], check=True, stdin=subprocess.DEVNULL)
