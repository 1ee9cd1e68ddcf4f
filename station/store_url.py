"""Where a store lives: a SQLite path or a ``postgresql://`` URL, and its password.

A store URL never carries a password. The password of a PostgreSQL store
comes from the environment variable named by ``?password_env=VAR`` or from
the file named by ``?password_file=PATH`` (first line), or from libpq's own
``PGPASSWORD``/``~/.pgpass``. :func:`redacted` is the form that may appear in
messages, run records and logs.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qsl, urlsplit

from station.errors import ConfigError

PG_SCHEMES = ("postgresql", "postgres")
#: query parameters a store URL may carry (ours, then libpq's that are safe to pass on)
_OURS = ("password_env", "password_file")
#: a user or database name as the store accepts it
_NAME = re.compile(r"[A-Za-z0-9_.\-]{1,63}")
_LIBPQ = ("connect_timeout", "sslmode", "application_name", "sslrootcert", "target_session_attrs")


def is_postgres_url(target) -> bool:
    return isinstance(target, str) and urlsplit(target).scheme.lower() in PG_SCHEMES


@dataclass(frozen=True)
class PgTarget:
    """A parsed ``postgresql://user@host:port/db?...`` store URL (no password in it)."""

    user: str | None
    host: str
    port: int
    dbname: str
    password_env: str | None
    password_file: str | None
    options: tuple[tuple[str, str], ...]

    def redacted(self) -> str:
        user = f"{self.user}@" if self.user else ""
        return f"postgresql://{user}{self.host}:{self.port}/{self.dbname}"

    def password(self) -> str | None:
        """The password named by the URL, read now; None lets libpq look (PGPASSWORD, ~/.pgpass)."""
        if self.password_env:
            value = os.environ.get(self.password_env)
            if value is None:
                raise ConfigError(f"store_url: password_env names {self.password_env!r}, which is not set")
            return value
        if self.password_file:
            try:
                return Path(self.password_file).read_text().splitlines()[0].strip()
            except (OSError, IndexError) as exc:
                raise ConfigError(f"store_url: cannot read password_file {self.password_file!r}") from exc
        return None

    def connect_kwargs(self) -> dict:
        kw = {"host": self.host, "port": self.port, "dbname": self.dbname, **dict(self.options)}
        if self.user:
            kw["user"] = self.user
        pw = self.password()
        if pw is not None:
            kw["password"] = pw
        kw.setdefault("connect_timeout", "5")
        kw.setdefault("application_name", "station")
        return kw


def parse_pg_url(url: str) -> PgTarget:
    """Parse and check a PostgreSQL store URL; ConfigError names what is wrong."""
    parts = urlsplit(url)
    if parts.scheme.lower() not in PG_SCHEMES:
        raise ConfigError(f"store_url: scheme must be postgresql://, got {parts.scheme or 'none'!r}")
    if parts.password is not None:
        raise ConfigError("store_url: a password in the URL is refused (it would end up in records and logs); "
                          "name it with ?password_env=VAR or ?password_file=PATH")
    if not parts.hostname:
        raise ConfigError("store_url: no host (postgresql://user@host:port/db)")
    # a user or database name is a plain identifier: a percent-escape or a colon hides a secret
    # (``station%3Asecret@``, ``/db%3Asecret``) that would be stored and shown with the URL
    if parts.username is not None and not _NAME.fullmatch(parts.username):
        raise ConfigError("store_url: the user name must be letters, digits, '_', '.' or '-' (no escapes, no "
                          "':'; a password goes in ?password_env=VAR or ?password_file=PATH)")
    dbname = parts.path.lstrip("/")
    if not dbname or "/" in dbname:
        raise ConfigError("store_url: the path must name one database (postgresql://user@host:port/db)")
    if not _NAME.fullmatch(dbname):
        raise ConfigError("store_url: the database name must be letters, digits, '_', '.' or '-' (no escapes, "
                          "no ':')")
    try:
        port = parts.port or 5432
    except ValueError as exc:
        raise ConfigError(f"store_url: bad port ({exc})") from None
    query = parse_qsl(parts.query, keep_blank_values=True)
    options, ours = [], {}
    for key, value in query:
        if key in _OURS:
            ours[key] = value
        elif key in _LIBPQ:
            options.append((key, value))
        elif key.strip().lower() in ("password", "pass", "passwd", "pwd"):
            raise ConfigError("store_url: a password in the URL is refused; use ?password_env=VAR or ?password_file=PATH")
        else:
            raise ConfigError(f"store_url: unknown parameter {key!r} (allowed: {', '.join(_OURS + _LIBPQ)})")
    if len(ours) > 1:
        raise ConfigError("store_url: give password_env or password_file, not both")
    return PgTarget(parts.username, parts.hostname, port, dbname, ours.get("password_env"), ours.get("password_file"),
                    tuple(options))


def redacted(target) -> str:
    """A store's name fit for messages: the path, or the URL without credentials or parameters."""
    if is_postgres_url(target):
        try:
            return parse_pg_url(target).redacted()
        except ConfigError:
            parts = urlsplit(target)
            db = parts.path.lstrip("/")
            return f"postgresql://{parts.hostname or '?'}/" + (db if _NAME.fullmatch(db) else "***")
    return str(target)
