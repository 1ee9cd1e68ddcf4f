"""A pty that a serial fake serves: the slave path is the device a driver opens.

The slave is put in raw mode (no echo, no CR/LF translation, as a real
serial line) and the master is non-blocking, read and written by the fake's
own thread with ``select``.
"""

from __future__ import annotations

import errno
import os
import pty
import tty


class PtyPort:
    """``master`` fd for the fake, ``device`` path (``/dev/pts/N``) for the driver."""

    def __init__(self) -> None:
        self.master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self.master, False)
        self.device = os.ttyname(self._slave)

    def read(self, n: int = 4096) -> bytes | None:
        """What the driver wrote, up to ``n`` bytes: ``b""`` if nothing yet, ``None`` while no driver has
        the device open (the master then reads as EIO: wait a little before asking again)."""
        try:
            return os.read(self.master, n)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return None
            raise

    def close(self) -> None:
        """Close both ends (idempotent); call after the serving thread has stopped."""
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
