"""A person at a terminal, for tests that drive armed runs against the fakes.

An armed run takes its confirmations only from a person: the terminal
operator (:class:`~app.terminal.InteractiveOperator`) with both its streams
on a real terminal, or the operator's page. These tests stand in for the
person by typing into a pseudo-terminal (``pty.openpty``) whose other end the
station reads and writes, in this process or in a ``station run`` child, so
every prompt is really asked on a tty and its text can be checked. A pipe or
a file in the same place is refused (tests/station/test_operator_safety.py).
"""

from __future__ import annotations

import os
import pty
import subprocess
import termios
import threading
import weakref

from app.terminal import InteractiveOperator

#: more answers than any procedure asks
TYPED_YES = "y\n" * 50


class Terminal:
    """A pseudo-terminal with ``typed`` already typed into it; what the program writes is in :meth:`output`.

    Echo and output processing are off, so the output is the program's own
    text. A reader thread drains the terminal so a program never blocks on
    a full one; :meth:`close` (or the ``with`` block) closes both ends and
    joins it.
    """

    def __init__(self, typed: str = TYPED_YES) -> None:
        self.master, self.slave = pty.openpty()
        attrs = termios.tcgetattr(self.slave)
        attrs[1] &= ~termios.OPOST
        attrs[3] &= ~termios.ECHO
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
        self._chunks: list[bytes] = []
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._drain, name="terminal-reader")
        self._reader.start()
        os.write(self.master, typed.encode())
        self._files: list = []

    def _drain(self) -> None:
        while True:
            try:
                chunk = os.read(self.master, 4096)
            except OSError:  # EIO: every slave end is closed
                return
            if not chunk:
                return
            with self._lock:
                self._chunks.append(chunk)

    def output(self) -> str:
        with self._lock:
            return b"".join(self._chunks).decode(errors="replace")

    def operator(self) -> InteractiveOperator:
        """The station's terminal operator on this terminal (both streams a tty)."""
        stdin = open(self.slave, "r", closefd=False, encoding="utf-8")
        stdout = open(self.slave, "w", closefd=False, encoding="utf-8")
        self._files += [stdin, stdout]
        return InteractiveOperator(stdin=stdin, stdout=stdout)

    def child_streams(self) -> dict:
        """``subprocess`` keywords that put a child's standard input and error (the prompts) on this terminal."""
        return {"stdin": self.slave, "stderr": self.slave}

    def close(self) -> str:
        """Close both ends, join the reader; returns everything written to the terminal."""
        for f in self._files:
            f.close()
        if self.slave >= 0:
            os.close(self.slave)
            self.slave = -1
        self._reader.join(timeout=10)
        if self.master >= 0:
            os.close(self.master)
            self.master = -1
        return self.output()

    def __enter__(self) -> "Terminal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def person_typing_yes() -> InteractiveOperator:
    """An operator at a terminal who answers yes to each prompt; what was asked is in
    ``.terminal.output()``. The terminal closes when the operator is collected (or by ``.terminal.close()``)."""
    term = Terminal()
    op = term.operator()
    op.terminal = term
    weakref.finalize(op, term.close)
    return op


def run_at_terminal(args, *, timeout: float, **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run`` of a child whose standard input and error are a terminal a person types yes
    into; ``stdout`` is captured as text, ``stderr`` is what the terminal showed."""
    with Terminal() as term:
        proc = subprocess.run(args, stdout=subprocess.PIPE, text=True, timeout=timeout, **term.child_streams(),
                              **kwargs)
        shown = term.close()
    return subprocess.CompletedProcess(proc.args, proc.returncode, proc.stdout, shown)
