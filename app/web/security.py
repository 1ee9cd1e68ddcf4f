"""Who may act on the page: CSRF token on every POST, access token off loopback, Host check.

* Every page carries the server's CSRF token; a POST without it (or with a
  foreign ``Origin``) is refused: a site in the operator's browser cannot
  read the token, so it cannot steer the station.
* On loopback, the ``Host`` header must name the loopback address and port
  (a page on another site that resolves its name to 127.0.0.1 is refused).
* On any other address every request needs the access token printed at
  start: once in the URL (``?token=...``), then a strict same-site cookie.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from urllib.parse import urlsplit

ACCESS_COOKIE = "station_access"


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def listen_problem(host: str) -> str | None:
    """Why the page must not listen on ``host`` (None if it may): never on every interface at once."""
    try:
        wildcard = ipaddress.ip_address(host).is_unspecified
    except ValueError:
        wildcard = host in ("", "*")
    if wildcard:
        return (f"--host {host!r} would listen on every interface; give the one address the plant network "
                f"reaches the station by (e.g. its LAN address)")
    return None


def _same(a: str | None, b: str | None) -> bool:
    return bool(a) and bool(b) and hmac.compare_digest(str(a).encode(), str(b).encode())


class Guard:
    """The tokens of one server and the checks made with them (``port`` set once bound)."""

    def __init__(self, host: str, port: int = 0) -> None:
        self.host = host
        self.port = int(port)
        self.loopback = is_loopback(host)
        self.csrf_token = secrets.token_urlsafe(32)
        #: None on loopback: nobody else can reach the server
        self.access_token = None if self.loopback else secrets.token_urlsafe(24)

    def host_ok(self, host_header: str | None) -> bool:
        """On loopback only the loopback names with our port are accepted as ``Host``."""
        if not self.loopback:
            return True
        allowed = {f"127.0.0.1:{self.port}", f"localhost:{self.port}", f"[::1]:{self.port}"}
        return (host_header or "") in allowed

    def access_ok(self, cookie: str | None) -> bool:
        return self.access_token is None or _same(cookie, self.access_token)

    def access_from_query(self, token: str | None) -> bool:
        return self.access_token is not None and _same(token, self.access_token)

    def post_problem(self, host_header: str | None, origin: str | None, token: str | None) -> str | None:
        """Why a POST is refused, or None when it may act."""
        if origin and origin != "null":
            if urlsplit(origin).netloc != (host_header or ""):
                return f"cross-site request refused (Origin {origin})"
        elif origin == "null":
            return "cross-site request refused (Origin null)"
        if not _same(token, self.csrf_token):
            return "missing or wrong CSRF token: reload the page and try again"
        return None
