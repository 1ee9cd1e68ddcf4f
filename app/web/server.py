"""uvicorn on a socket bound here (port 0 allowed), in the foreground or in a thread.

:class:`WebServer` owns the store it reads, the hub that drives runs and the
uvicorn server; ``close()`` stops serving, aborts a run still going (it stays
resumable, like any interrupted run) and joins every thread.
"""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import uvicorn

from station.errors import ConfigError
from station.store import RunStore
from app.web.app import create_app
from app.web.live import RunHub
from app.web.security import Guard


class WebServer:
    """One station's page, bound to ``host:port`` (``port=0``: any free port, see ``url``)."""

    def __init__(self, cfg, config_dir: Path, *, host: str = "127.0.0.1", port: int = 8700, arm: bool = False,
                 time_scale: float = 20.0, plan_overrides: dict | None = None) -> None:
        if not 0 <= int(port) <= 65535:
            raise ConfigError(f"port must be 0..65535, got {port}")
        self.guard = Guard(host)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, int(port)))
        except OSError as exc:
            self.sock.close()
            raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from exc
        self.port = self.guard.port = self.sock.getsockname()[1]
        self.host = host
        self.store = RunStore(cfg.station.store_file(config_dir))
        self.hub = RunHub(cfg, config_dir, arm=arm, time_scale=time_scale, plan_overrides=plan_overrides)
        app = create_app(self.hub, self.store, self.guard)
        self.server = uvicorn.Server(uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=2,
                                                    lifespan="off"))
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        base = f"http://{host}:{self.port}/"
        return base + (f"?token={self.guard.access_token}" if self.guard.access_token else "")

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
