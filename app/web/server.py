"""uvicorn on a socket bound here (port 0 allowed), in the foreground or in a thread.

:class:`WebServer` owns the store it reads, the hub that drives runs and the
uvicorn server; ``close()`` stops serving, aborts a run still going (it stays
resumable, like any interrupted run) and joins every thread.
"""

from __future__ import annotations

import asyncio
import os
import re
import resource
import socket
import threading
import time
from pathlib import Path

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from station.errors import ConfigError
from station.store import RunStore
from app.web.app import create_app
from app.web.listener import ReservingListener, quiet_accept_errors, raise_file_limit
from app.web.live import RunHub
from app.web.security import Guard, listen_problem

#: an idle keep-alive connection is closed after this many seconds
KEEP_ALIVE_S = 5.0
#: a request's head (request line and headers) must arrive within this many seconds of the connection opening
#: (or of the previous response); slow and idle connections are closed
HEAD_TIMEOUT_S = 10.0
#: largest request head, bytes, however it arrives (in one write or trickled)
MAX_HEAD_BYTES = 16 * 1024
#: the blank line that ends a request head (h11 takes a bare LF too)
_HEAD_END = re.compile(rb"\n\r?\n")
#: connections over the cap the server tolerates for the moment an evicted one takes to close, before it
#: answers 503
EVICTION_SLACK = 16


#: descriptors kept for the rest of the station (store, logs, devices, the page's own files), not for connections
FD_HEADROOM = 64
#: the connection cap never goes below this
MIN_CONNECTIONS = 16


def max_connections() -> int:
    """Connections served at once: what the process's file limit leaves (FD_HEADROOM kept for the store,
    logs, devices), at most 4096."""
    import resource

    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    soft = 4096 + FD_HEADROOM if soft == resource.RLIM_INFINITY else soft
    return max(MIN_CONNECTIONS, min(4096, soft - FD_HEADROOM))


def head_too_large(buffer: bytes) -> bool:
    """Whether the request head at the start of ``buffer`` is (or, unfinished, already is) over MAX_HEAD_BYTES."""
    end = _HEAD_END.search(buffer, 0, MAX_HEAD_BYTES + 2)
    return end is None and len(buffer) > MAX_HEAD_BYTES or end is not None and end.end() > MAX_HEAD_BYTES


def evict_waiting(connections, keep: int) -> int:
    """Close the connections that have waited longest for their request head until at most ``keep`` stay open
    (those busy with a request stay whatever their number); how many stay open."""
    live = [c for c in connections if not c.transport.is_closing()]
    waiting = sorted((c for c in live if getattr(c, "_head_timer", None) is not None), key=lambda c: c._head_since)
    excess = max(0, len(live) - keep)
    for c in waiting[:excess]:
        c.transport.close()
    return len(live) - min(excess, len(waiting))


#: a connection cap lowered for a full file table is looked at again at most this often, s
CAP_LOOK_S = 1.0
#: ... and raised each time by at most this fraction of itself (at least one connection), while the descriptors
#: beyond FD_HEADROOM allow: back to :func:`max_connections` in steps, so a table that fills again is found
#: before it is full
CAP_RAISE_FRACTION = 0.25


def connection_cap(server_state) -> int:
    """The connections served at once now: :func:`max_connections`, lowered once the file table was full."""
    return getattr(server_state, "connection_cap", None) or max_connections()


def free_descriptors() -> int | None:
    """Descriptors this process may still open (its soft limit less those open); None where it cannot tell."""
    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    try:
        used = len(os.listdir("/proc/self/fd")) - 1  # less the one listdir itself held
    except OSError:
        return None
    return (4096 + FD_HEADROOM if soft == resource.RLIM_INFINITY else soft) - used


def relax_cap(server_state, *, now: float | None = None, free=free_descriptors) -> int:
    """The connection cap, raised again where :func:`make_room` lowered it and descriptors are free now: at most
    every :data:`CAP_LOOK_S`, by at most :data:`CAP_RAISE_FRACTION` of itself and by no more than the free
    descriptors beyond FD_HEADROOM; back at :func:`max_connections` it is no longer lowered. ``free``: the
    count of free descriptors (a callable; None: unknown, nothing raised)."""
    cap = getattr(server_state, "connection_cap", None)
    if cap is None:
        return max_connections()
    now = time.monotonic() if now is None else now
    if now - getattr(server_state, "cap_looked_at", -CAP_LOOK_S) < CAP_LOOK_S:
        return cap
    server_state.cap_looked_at = now
    n_free = free()
    spare = -1 if n_free is None else n_free - FD_HEADROOM
    if spare <= 0:
        return cap
    top = max_connections()
    new = min(top, cap + min(spare, max(1, int(cap * CAP_RAISE_FRACTION))))
    server_state.connection_cap = None if new >= top else new
    return new


def make_room(server_state) -> bool:
    """The file table is full: lower the connection cap to leave FD_HEADROOM descriptors to the rest of the
    station (the store, reports, the page's own files) and close waiting connections down to it; whether a new
    connection fits."""
    live = sum(not c.transport.is_closing() for c in server_state.connections)
    server_state.connection_cap = min(connection_cap(server_state), max(MIN_CONNECTIONS, live - FD_HEADROOM))
    server_state.cap_looked_at = time.monotonic()  # raised again (relax_cap) no sooner than CAP_LOOK_S from now
    return evict_waiting(server_state.connections, server_state.connection_cap - 1) < server_state.connection_cap


class _Server(uvicorn.Server):
    """uvicorn's server; a refused accept is logged by the listener alone (once per interval)."""

    async def startup(self, sockets=None) -> None:
        asyncio.get_running_loop().set_exception_handler(quiet_accept_errors)
        await super().startup(sockets)


class BoundedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline for each request head and a cap on connections.

    A connection that has not sent a whole request head within
    :data:`HEAD_TIMEOUT_S` (after opening, or after its last response) is
    closed, however slowly it trickles bytes. Beyond :func:`max_connections`
    the oldest connection still waiting for its head makes room for the new
    one, so a flood of partial requests cannot lock the page out.
    """

    def connection_made(self, transport) -> None:
        super().connection_made(transport)
        self._head_timer = None
        self._arm_head_timer()
        cap = relax_cap(self.server_state)
        if len(self.connections) > cap:
            evict_waiting(self.connections, cap)

    def _arm_head_timer(self) -> None:
        self._cancel_head_timer()
        self._head_since = self.loop.time()
        self._head_timer = self.loop.call_later(HEAD_TIMEOUT_S, self._head_timeout)

    def _cancel_head_timer(self) -> None:
        if getattr(self, "_head_timer", None) is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_timeout(self) -> None:
        self._head_timer = None
        if not self.transport.is_closing():
            self.transport.close()

    def handle_events(self) -> None:
        # h11 bounds only a head that is still incomplete: one that arrives whole in one write passes its
        # limit, so the head waiting in the buffer is measured here before h11 parses it
        if self.conn.their_state is h11.IDLE and head_too_large(self.conn.trailing_data[0]):
            self._refuse_head()
            return
        super().handle_events()

    def _refuse_head(self) -> None:
        self._cancel_head_timer()
        body = f"request head over {MAX_HEAD_BYTES} bytes".encode()
        self.transport.write(b"HTTP/1.1 431 Request Header Fields Too Large\r\n"
                             b"content-type: text/plain; charset=utf-8\r\nconnection: close\r\n"
                             b"content-length: %d\r\n\r\n" % len(body) + body)
        self.transport.close()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self._head_timer is not None and self.conn.their_state is not h11.IDLE:
            self._cancel_head_timer()  # the head is in: the app's own limits take over

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing() and self.conn.their_state is h11.IDLE:
            self._arm_head_timer()

    def connection_lost(self, exc) -> None:
        self._cancel_head_timer()
        super().connection_lost(exc)


class WebServer:
    """One station's page, bound to ``host:port`` (``port=0``: any free port, see ``url``)."""

    def __init__(self, cfg, config_dir: Path, *, host: str = "127.0.0.1", port: int = 8700, arm: bool = False,
                 time_scale: float = 20.0, plan_overrides: dict | None = None) -> None:
        if not 0 <= int(port) <= 65535:
            raise ConfigError(f"port must be 0..65535, got {port}")
        problem = listen_problem(host)
        if problem:
            raise ConfigError(problem)
        raise_file_limit()  # before the connection cap is read from it
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = ReservingListener(family)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, int(port)))
        except (OSError, OverflowError, UnicodeError) as exc:
            self.sock.close()
            raise ConfigError(f"cannot listen on {host}:{port}: {getattr(exc, 'strerror', None) or exc}") from exc
        # decided by the address the socket is bound to, not by how --host spelt it
        bound, self.port = self.sock.getsockname()[:2]
        problem = listen_problem(bound)
        if problem:
            self.sock.close()
            raise ConfigError(problem)
        self.host = bound
        self.guard = Guard(bound, self.port)
        self.store = RunStore(cfg.station.store_file(config_dir))
        self.hub = RunHub(cfg, config_dir, arm=arm, time_scale=time_scale, plan_overrides=plan_overrides)
        app = create_app(self.hub, self.store, self.guard)
        self.server = _Server(uvicorn.Config(
            app, log_level="warning", timeout_graceful_shutdown=2, lifespan="off", http=BoundedH11Protocol,
            loop="asyncio", timeout_keep_alive=KEEP_ALIVE_S, limit_concurrency=max_connections() + EVICTION_SLACK,
            h11_max_incomplete_event_size=MAX_HEAD_BYTES))
        self.sock.make_room = lambda: make_room(self.server.server_state)
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        base = f"http://{host}:{self.port}/"
        return base + f"?token={self.guard.access_token}"

    def serve_forever(self) -> None:
        """Serve in this thread until Ctrl-C (uvicorn's own signal handling), then close."""
        try:
            self.server.run(sockets=[self.sock])
        finally:
            self.close()

    def start(self) -> "WebServer":
        """Serve in a thread (tests, benchmarks); returns once accepting."""
        self._thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, name="web server")
        self._thread.start()
        while not self.server.started:
            if not self._thread.is_alive():
                raise RuntimeError("web server thread died while starting")
            self._thread.join(0.02)
        return self

    def close(self) -> None:
        self.server.should_exit = True
        if self._thread is not None:
            self._thread.join(10)
            self._thread = None
        self.hub.close()
        self.store.close()
        self.sock.close()

    def __enter__(self) -> "WebServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
