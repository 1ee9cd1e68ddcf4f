"""The two places a store lives: a SQLite file (the station's own) and PostgreSQL (the plant's).

A backend is a connection with four verbs: :meth:`query`, :meth:`execute`,
:meth:`transaction` (a cursor whose statements commit together or not at
all) and :meth:`close`. SQL is written once, with ``?`` placeholders and the
``INSERT ... ON CONFLICT`` forms both engines know; the PostgreSQL backend
turns ``?`` into ``%s``. Arguments are always passed as parameters, never
formatted into the text.

Errors of the engines are translated here: :class:`~station.store.errors.StoreUnavailable`
when the server cannot be reached or drops the connection (the station goes
on locally), :class:`~station.store.errors.StoreError` otherwise; messages
name the store by its redacted URL.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from station.errors import ConfigError
from station.store.errors import StoreError, StoreUnavailable
from station.store_url import PgTarget, parse_pg_url

#: the oldest PostgreSQL server the store's SQL is written for
MIN_SERVER_VERSION = 120000

#: how long opening a SQLite store waits for another connection that holds it (a station process creating
#: it, a run writing to it), s
SQLITE_WAIT_S = 30.0


def _why_not_here(path: Path, exc: BaseException) -> str:
    """Why no store file can live at ``path``: a parent that is a file, or what the system said."""
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        return f"{blocking} is a file, not a folder"
    return exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)


class SqliteBackend:
    dialect = "sqlite"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.name = str(self.path)
        self._lock = threading.RLock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None, timeout=30.0)
        except (OSError, ValueError, sqlite3.OperationalError) as exc:
            raise StoreError(f"store {self.name!r}: cannot open it here ({_why_not_here(self.path, exc)})") from None
        try:
            self._wal()
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path}: not a usable station store ({exc})") from exc
        self.integrity_errors: tuple[type[BaseException], ...] = (sqlite3.IntegrityError,)

    def _wal(self) -> None:
        """Put the file in write-ahead-log mode. SQLite refuses the switch at once, without waiting, while
        another connection holds a write transaction on it (it would deadlock): ask again until that one is
        done, within :data:`SQLITE_WAIT_S`."""
        deadline = time.monotonic() + SQLITE_WAIT_S
        pause = 0.005
        while True:
            try:
                self._db.execute("PRAGMA journal_mode=WAL")
                return
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or time.monotonic() > deadline:
                    raise
            time.sleep(pause)
            pause = min(2 * pause, 0.1)

    def query(self, sql: str, args: tuple = ()) -> list[tuple]:
        with self._lock, _translated(self.name):
            return self._db.execute(sql, args).fetchall()

    def execute(self, sql: str, args: tuple = ()) -> None:
        with self._lock, _translated(self.name):
            self._db.execute(sql, args)

    @contextmanager
    def transaction(self) -> Iterator["_Cursor"]:
        with self._lock, _translated(self.name):
            cur = self._db.cursor()
            cur.execute("BEGIN IMMEDIATE")
            try:
                yield _Cursor(cur, lambda s: s)
            except BaseException:
                cur.execute("ROLLBACK")
                raise
            cur.execute("COMMIT")

    def table_names(self) -> set[str]:
        return {r[0] for r in self.query("SELECT name FROM sqlite_master WHERE type='table'")}

    def lock_schema(self, cur) -> None:
        """BEGIN IMMEDIATE already holds the write lock."""

    def close(self) -> None:
        with self._lock:
            self._db.close()


class PostgresBackend:
    dialect = "postgresql"

    def __init__(self, url: str, *, connect_timeout_s: float | None = None) -> None:
        import psycopg

        self._psycopg = psycopg
        self.target: PgTarget = parse_pg_url(url)
        self.name = self.target.redacted()
        self.path = self.name
        self._lock = threading.RLock()
        kwargs = self.target.connect_kwargs()
        if connect_timeout_s is not None:
            kwargs["connect_timeout"] = str(max(1, int(round(connect_timeout_s))))
        try:
            self._db = psycopg.connect(autocommit=True, **kwargs)
        except psycopg.OperationalError as exc:
            raise StoreUnavailable(f"{self.name}: cannot connect ({_first_line(exc)}); "
                                   "the station goes on with its local store") from exc
        version = self._db.info.server_version
        if version < MIN_SERVER_VERSION:
            self._db.close()
            raise StoreError(f"{self.name}: PostgreSQL server version {version} is older than the "
                             f"{MIN_SERVER_VERSION} this station needs")
        self.integrity_errors = (psycopg.errors.IntegrityError,)

    def query(self, sql: str, args: tuple = ()) -> list[tuple]:
        with self._lock, _translated(self.name, self._psycopg):
            with self._db.cursor() as cur:
                cur.execute(_pg(sql), args)
                return cur.fetchall() if cur.description else []

    def execute(self, sql: str, args: tuple = ()) -> None:
        with self._lock, _translated(self.name, self._psycopg):
            self._db.execute(_pg(sql), args)

    @contextmanager
    def transaction(self) -> Iterator["_Cursor"]:
        with self._lock, _translated(self.name, self._psycopg):
            with self._db.transaction(), self._db.cursor() as cur:
                yield _Cursor(cur, _pg)

    def table_names(self) -> set[str]:
        return {r[0] for r in self.query(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = current_schema()")}

    def lock_schema(self, cur) -> None:
        """Serialise schema creation and migration between processes opening one database at once."""
        cur.execute("SELECT pg_advisory_xact_lock(?)", (_SCHEMA_LOCK,))

    def close(self) -> None:
        with self._lock:
            self._db.close()

    @property
    def raw(self):
        """The psycopg connection (for COPY); hold :attr:`lock` while using it."""
        return self._db

    @property
    def lock(self):
        return self._lock


_SCHEMA_LOCK = 0x5747  # any fixed number: the advisory lock key of schema changes


class _Cursor:
    def __init__(self, cur, translate) -> None:
        self._cur = cur
        self._translate = translate

    def execute(self, sql: str, args: tuple = ()) -> "_Cursor":
        self._cur.execute(self._translate(sql), args)
        return self

    def fetchone(self):
        return self._cur.fetchone()

    def fetchall(self):
        return self._cur.fetchall()

    @property
    def raw(self):
        return self._cur


def _pg(sql: str) -> str:
    return sql.replace("?", "%s")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


@contextmanager
def _translated(name: str, psycopg=None):
    try:
        yield
    except (StoreError, ConfigError):
        raise
    except sqlite3.IntegrityError:
        raise
    except sqlite3.DatabaseError as exc:
        raise StoreError(f"{name}: {exc}") from exc
    except Exception as exc:
        if psycopg is None:
            raise
        if isinstance(exc, psycopg.errors.IntegrityError):
            raise
        if isinstance(exc, (psycopg.OperationalError, psycopg.InterfaceError)):
            raise StoreUnavailable(f"{name}: connection lost ({_first_line(exc)}); "
                                   "what was not committed is still local") from exc
        if isinstance(exc, psycopg.Error):
            raise StoreError(f"{name}: {_first_line(exc)}") from exc
        raise


def open_backend(target, *, connect_timeout_s: float | None = None):
    """A backend for a SQLite path or a ``postgresql://`` URL."""
    from station.store_url import is_postgres_url

    if is_postgres_url(target):
        return PostgresBackend(str(target), connect_timeout_s=connect_timeout_s)
    if isinstance(target, str) and "://" in target and not target.lower().startswith("sqlite://"):
        raise ConfigError(f"store: {target.split('://')[0]}:// is not a store (a SQLite path or postgresql://...)")
    if isinstance(target, str) and target.lower().startswith("sqlite://"):
        target = target[len("sqlite://"):]
    return SqliteBackend(target)
