"""Who may act on the page: access token on every request, CSRF token and Origin on every POST, Host check.

* Every request needs the access token printed at start, on every address,
  loopback included (any local process could otherwise read the page and
  start runs; with ``--arm`` that moves a robot): once in the URL
  (``?token=...``), then a strict same-site cookie of this port, as notebook
  servers do on localhost.
* Every page carries the server's CSRF token; a POST without it (or with a
  foreign ``Origin``) is refused: a site in the operator's browser cannot
  read the token, so it cannot steer the station. The Origin is checked
  before the body is read, and the body is bounded (:mod:`app.web.app`).
* On loopback, the ``Host`` header must name the bound address (or
  ``localhost``) and port (a page on another site that resolves its name to
  127.0.0.1 is refused).
* The page never listens on every interface at once: decided by the address
  the socket binds (``0``, ``0x0`` and the IPv4-mapped IPv6 form are all the wildcard),
  not by its spelling.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from urllib.parse import urlsplit

ACCESS_COOKIE = "station_access"


def _address(host: str):
    """The IP address of a numeric host (IPv4-mapped IPv6 as its IPv4), or None."""
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return None
    mapped = getattr(ip, "ipv4_mapped", None)
    return mapped if mapped is not None else ip


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    ip = _address(host)
    return bool(ip is not None and ip.is_loopback)


def bind_addresses(host: str) -> list[str]:
    """The numeric addresses a socket bound to ``host`` may take (as the C library reads the spelling:
    ``0``, ``0.0``, ``0x0`` are the IPv4 wildcard); empty when it names none."""
    import socket

    if host in ("", "*"):
        return [str(ipaddress.IPv4Address(0))]  # the wildcard, as the socket would bind it
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError, ValueError):
        return []
    return sorted({info[4][0] for info in infos})


def listen_problem(host: str) -> str | None:
    """Why the page must not listen on ``host`` (None if it may): never on every interface at once.

    Decided by the addresses the spelling resolves to (and, once bound, by the
    socket's own address: :class:`app.web.server.WebServer`).
    """
    addrs = bind_addresses(host)
    if not addrs:
        return f"--host {host!r} names no address this machine can listen on"
    for a in addrs:
        ip = _address(a)
        if ip is None or ip.is_unspecified:
            return (f"--host {host!r} would listen on every interface ({a}); give the one address the plant "
                    "network reaches the station by (e.g. its LAN address)")
    return None


def _same(a: str | None, b: str | None) -> bool:
    return bool(a) and bool(b) and hmac.compare_digest(str(a).encode(), str(b).encode())


class Guard:
    """The tokens of one server and the checks made with them (``port`` set once bound)."""

    def __init__(self, host: str, port: int = 0) -> None:
        #: the bound address (numeric), as the socket reports it
        self.host = host
        self.port = int(port)
        self.loopback = is_loopback(host)
        self.csrf_token = secrets.token_urlsafe(32)
        #: on every address, loopback included: any local process could otherwise steer the station
        self.access_token = secrets.token_urlsafe(24)

    @property
    def cookie_name(self) -> str:
        """The access cookie of this port (cookies are shared between the ports of one host)."""
        return f"{ACCESS_COOKIE}_{self.port}"

    def host_ok(self, host_header: str | None) -> bool:
        """On loopback only our own address or the loopback names, with our port, are accepted as ``Host``."""
        if not self.loopback:
            return True
        p = self.port
        own = f"[{self.host}]" if ":" in self.host else self.host
        allowed = {f"{own}:{p}", f"127.0.0.1:{p}", f"localhost:{p}", f"[::1]:{p}"}
        return (host_header or "") in allowed

    def access_ok(self, cookie: str | None) -> bool:
        return self.access_token is None or _same(cookie, self.access_token)

    def access_from_query(self, token: str | None) -> bool:
        return self.access_token is not None and _same(token, self.access_token)

    def origin_problem(self, host_header: str | None, origin: str | None) -> str | None:
        """Why a POST is refused by its headers alone (checked before its body is read), or None."""
        if origin and origin != "null":
            if urlsplit(origin).netloc != (host_header or ""):
                return f"cross-site request refused (Origin {origin[:100]})"
        elif origin == "null":
            return "cross-site request refused (Origin null)"
        return None

    def post_problem(self, host_header: str | None, origin: str | None, token: str | None) -> str | None:
        """Why a POST is refused, or None when it may act."""
        problem = self.origin_problem(host_header, origin)
        if problem:
            return problem
        if not _same(token, self.csrf_token):
            return "missing or wrong CSRF token: reload the page and try again"
        return None
