"""The run's progress in an 80-column terminal (a pty, judged by the pyte terminal emulator) and on a pipe.

A dry run of the ISO 9283 procedure on the fake cell asks its confirmations on the terminal; the test
types the answers as a person would. On the screen every bar fits its line (nothing wraps), and every
prompt starts a line of its own; on a pipe the progress is plain lines without terminal controls.
"""

from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import termios
import time

import pyte

from app.cli import main
from tests.pace import LOCKSTEP

COLS = 80


def _station(tmp_path):
    assert main(["init", "--out", str(tmp_path / "station.toml")]) == 0
    return [sys.executable, "-m", "app.cli", "run", "iso9283", "--config", str(tmp_path / "station.toml"),
            "--time-scale", str(LOCKSTEP)]


def test_an_80_column_terminal_shows_the_bar_and_the_prompts_cleanly(tmp_path, capsys):
    argv = _station(tmp_path)
    capsys.readouterr()
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, COLS, 0, 0))
    env = dict(os.environ, COLUMNS=str(COLS), LINES="24", TERM="xterm")
    env.pop("NO_COLOR", None)
    proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, cwd=tmp_path, env=env,
                            close_fds=True, start_new_session=True)
    os.close(slave)
    screen = pyte.Screen(COLS, 300)
    stream = pyte.ByteStream(screen)
    raw = b""
    answered = 0
    bars_seen = 0
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline:
            r, _, _ = select.select([master], [], [], 0.5)
            if r:
                try:
                    chunk = os.read(master, 65536)
                except OSError:
                    break
                if not chunk:
                    break
                raw += chunk
                stream.feed(chunk)
                shown = [line.rstrip() for line in screen.display]
                for k, line in enumerate(shown):
                    if "elapsed" in line:  # the bar as drawn now: whole on one line of 80 columns
                        bars_seen += 1
                        assert "remaining" in line and "/15" in line, shown[k:k + 2]
                if raw.count(b"[y/N]") > answered:
                    answered += 1
                    os.write(master, b"y\n")
            elif proc.poll() is not None:
                break
        assert proc.wait(timeout=60) == 0, raw[-2000:].decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    lines = [line.rstrip() for line in screen.display]
    prompts = [line for line in lines if "[y/N]" in line]
    assert answered >= 1 and len(prompts) == answered
    for line in prompts:
        assert line.startswith("? "), line  # a line of its own: no bar before it
        assert "elapsed" not in line and "━" not in line
    assert bars_seen > 0 and b"\x1b[" in raw
    # the outcome, verdict first (PASS / FAIL / NOT DECIDED: run ...), on a line of its own
    assert any(line.startswith(("PASS: run", "FAIL: run", "NOT DECIDED: run")) for line in lines), lines
    if os.environ.get("STATION_SHOW_SCREEN"):
        print("\n".join(x for x in lines if x))


def test_a_pipe_gets_plain_lines(tmp_path, capsys):
    argv = _station(tmp_path) + ["--yes"]
    capsys.readouterr()
    out = subprocess.run(argv, cwd=tmp_path, capture_output=True, timeout=240)
    assert out.returncode == 0, out.stderr[-2000:]
    err = out.stderr.decode()
    assert "\x1b[" not in err and "\r" not in err
    bars = [line for line in err.splitlines() if line.startswith("[")]
    assert bars and all("elapsed" in line for line in bars)
