"""uvicorn on a socket bound here (port 0 allowed), in the foreground or in a thread.

:class:`WebServer` owns the store it reads, the hub that drives runs and the
uvicorn server; ``close()`` stops serving, aborts a run still going (it stays
resumable, like any interrupted run) and joins every thread.
"""

from __future__ import annotations

import re
import socket
import threading
from pathlib import Path

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from station.errors import ConfigError
from station.store import RunStore
from app.web.app import create_app
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


def max_connections() -> int:
    """Connections served at once: what the process's file limit leaves (64 kept for the store, logs,
    devices), at most 4096."""
    import resource

    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    soft = 4096 + 64 if soft == resource.RLIM_INFINITY else soft
    return max(16, min(4096, soft - 64))


def head_too_large(buffer: bytes) -> bool:
    """Whether the request head at the start of ``buffer`` is (or, unfinished, already is) over MAX_HEAD_BYTES."""
    end = _HEAD_END.search(buffer, 0, MAX_HEAD_BYTES + 2)
    return end is None and len(buffer) > MAX_HEAD_BYTES or end is not None and end.end() > MAX_HEAD_BYTES


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
        if len(self.connections) > max_connections():
            waiting = [c for c in self.connections if getattr(c, "_head_timer", None) is not None]
            victim = min(waiting, key=lambda c: c._head_since)
            victim.transport.close()

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
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
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
        self.server = uvicorn.Server(uvicorn.Config(
            app, log_level="warning", timeout_graceful_shutdown=2, lifespan="off", http=BoundedH11Protocol,
            timeout_keep_alive=KEEP_ALIVE_S, limit_concurrency=max_connections(),
            h11_max_incomplete_event_size=MAX_HEAD_BYTES))
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
