"""The page's listening socket under file-descriptor pressure (issue 47 item 6).

A process at its file limit cannot accept: the kernel keeps the connection
queued and says EMFILE. asyncio then logs a traceback for every try (up to
its backlog per tick) and pauses accepting for a second, so a flood of slow
clients filled the log and kept the token holder waiting. Here:

* :func:`raise_file_limit` lifts the soft limit to the hard one at start;
* :class:`ReservingListener` keeps one spare descriptor: on EMFILE it asks
  the server to make room (the server lowers its connection cap to leave
  descriptors to the rest of the station, whose requests need files too, and
  closes the connections that have waited longest for their heads), closes
  the spare and accepts into its place (the spare comes back once a closed
  connection's descriptor is free); with nothing to close, the new connection
  is accepted and dropped, so the queue moves on instead of stalling;
* a refused accept is logged at most once per :data:`ACCEPT_LOG_INTERVAL_S`,
  with the count since the last line (:func:`quiet_accept_errors` keeps
  asyncio's own traceback for it out of the log).
"""

from __future__ import annotations

import errno
import logging
import os
import resource
import socket
import time
from collections.abc import Callable

#: a refused accept is logged at most once per this many seconds, with a count
ACCEPT_LOG_INTERVAL_S = 10.0
#: connections accepted in one turn of the event loop: the server counts (and caps) a connection only once its
#: protocol is made, a turn later, so an unbounded burst could take every free descriptor first
ACCEPTS_PER_ROUND = 8
#: the soft file limit asked for when the hard limit is unlimited
UNLIMITED_WANTED = 65536
#: asyncio's message for an accept that failed for want of a resource
_ASYNCIO_ACCEPT_MESSAGE = "socket.accept() out of system resource"
_NO_DESCRIPTOR = (errno.EMFILE, errno.ENFILE)
_NO_RESOURCE = (errno.ENOBUFS, errno.ENOMEM)

log = logging.getLogger("uvicorn.error")


def raise_file_limit() -> int:
    """Raise this process's soft RLIMIT_NOFILE to its hard limit where allowed; the soft limit after."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    wanted = UNLIMITED_WANTED if hard == resource.RLIM_INFINITY else hard
    if soft != resource.RLIM_INFINITY and soft < wanted:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))
        except (ValueError, OSError):
            pass  # not allowed here: the connection cap and the spare descriptor still hold
    return resource.getrlimit(resource.RLIMIT_NOFILE)[0]


def quiet_accept_errors(loop, context: dict) -> None:
    """An asyncio exception handler: a refused accept is logged by the listener, everything else as usual."""
    if context.get("message") == _ASYNCIO_ACCEPT_MESSAGE:
        return
    loop.default_exception_handler(context)


class ReservingListener(socket.socket):
    """A listening TCP socket whose ``accept()`` keeps a spare descriptor for a full file table.

    ``make_room`` (set by the server; called on the event loop's thread) closes
    connections still waiting for their heads and says whether a new one fits.
    """

    def __init__(self, family: int) -> None:
        super().__init__(family, socket.SOCK_STREAM)
        self.make_room: Callable[[], bool] = lambda: False
        self._spare: int | None = None
        self._round_over = False
        self._in_round = 0
        self._logged_at: float | None = None
        self.refused = self.evicted = self.dropped = 0  # since the last log line
        self._open_spare()

    def _open_spare(self) -> None:
        if self._spare is None:
            try:
                self._spare = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                self._spare = None  # still out of descriptors: tried again at the next accept

    def _close_spare(self) -> None:
        if self._spare is not None:
            os.close(self._spare)
            self._spare = None

    def accept(self):
        if self._round_over:  # asyncio goes on calling within one tick: end its round here
            self._round_over = False
            raise BlockingIOError(errno.EAGAIN, "accepting goes on next tick")
        try:
            pair = self._take()
        except OSError:
            self._in_round = 0
            raise
        self._in_round += 1
        if self._in_round >= ACCEPTS_PER_ROUND:
            self._in_round, self._round_over = 0, True
        return pair

    def _take(self):
        self._open_spare()
        try:
            return super().accept()
        except OSError as exc:
            if exc.errno not in _NO_DESCRIPTOR + _NO_RESOURCE:
                raise
            self._note(exc)
            if exc.errno in _NO_RESOURCE or (self._spare is None and not self.make_room()):
                # nothing to close and no spare: asyncio pauses accepting for a second (quietly, see above)
                self._round_over = True
                raise
        if self._spare is None:
            self.evicted += 1
            raise BlockingIOError(errno.EAGAIN, "room is being made")  # its descriptor is free next tick
        room = self.make_room()
        self._close_spare()
        conn, addr = super().accept()  # BlockingIOError if the queue was empty after all: the spare comes back
        if room:
            self.evicted += 1
            return conn, addr
        conn.close()  # every connection is busy with a request: this one is dropped, the queue moves on
        self.dropped += 1
        self._open_spare()
        raise ConnectionAbortedError(errno.ECONNABORTED, "dropped for want of a descriptor")

    def _note(self, exc: OSError) -> None:
        self.refused += 1
        now = time.monotonic()
        if self._logged_at is None or now - self._logged_at >= ACCEPT_LOG_INTERVAL_S:
            since = "" if self._logged_at is None else f" in the last {now - self._logged_at:.0f} s"
            log.warning("accept() refused %d time(s)%s (%s: %s); room made %d time(s) by closing connections "
                        "waiting for their heads, %d new connection(s) dropped", self.refused, since,
                        errno.errorcode.get(exc.errno, exc.errno), exc.strerror, self.evicted, self.dropped)
            self._logged_at = now
            self.refused = self.evicted = self.dropped = 0

    def close(self) -> None:
        self._close_spare()
        super().close()
