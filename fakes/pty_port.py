"""A pty that a serial fake serves: the slave path is the device a driver opens.

The slave is put in raw mode (no echo, no CR/LF translation, as a real
serial line) and the master is non-blocking, read and written by the fake's
own thread with ``select``.
"""

from __future__ import annotations

import errno
import os
import pty
import select
import threading
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

    def wait_read(self, stop: threading.Event, timeout_s: float = 0.05) -> bytes:
        """What the driver wrote, waiting up to ``timeout_s`` for it (``b""``: nothing, or no driver has the
        device open: then a little wait on ``stop`` too)."""
        ready, _, _ = select.select([self.master], [], [], timeout_s)
        if not ready:
            return b""
        data = self.read()
        if data is None:
            stop.wait(0.01)
            return b""
        return data

    def write_all(self, data: bytes, stop: threading.Event, give_up_s: float = 1.0) -> bool:
        """Write all of ``data`` to the driver; False if nobody read the line for ``give_up_s`` (or ``stop``)."""
        view = memoryview(data)
        waited = 0.0
        while view:
            try:
                view = view[os.write(self.master, view):]
            except BlockingIOError:
                if waited > give_up_s or stop.wait(0.005):
                    return False
                waited += 0.005
        return True

    def close(self) -> None:
        """Close both ends (idempotent); call after the serving thread has stopped."""
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
