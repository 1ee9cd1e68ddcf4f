"""Run store: the station's journal, samples and results, in SQLite or PostgreSQL.

One interface, two backends (:mod:`station.store.backends`): a SQLite file
(WAL) is the station's own store; a ``postgresql://`` URL is the plant's
central store that stations forward their runs to
(:mod:`station.store.forward`). The logical schema, its version and the
migrations are in :mod:`station.store.schema`.

What it keeps
-------------
* ``robots``: identity (model, serial), so history across runs is a query.
* ``runs``: one row per procedure run (robot, procedure, overhaul state,
  config and parameters as JSON, status, the station that made it).
* ``steps``: the journal. Every attempt of every step gets a row when it
  starts and is updated when it ends (``done``, ``failed``, ``aborted``).
* ``sample_batches``: raw samples, one row per committed batch, stored as a
  float64 array blob with its column names. A batch is *acknowledged* when
  :meth:`RunStore.append_samples` returns: the transaction has committed (in
  SQLite with ``synchronous=FULL`` in WAL mode), so a killed process (even
  ``kill -9``) or a power cut after that keeps it.
* ``results`` (JSON per key) and ``characteristics`` (one row per number, with
  its unit, limit and verdict) for queries like "every robot whose RP exceeds
  its limit".

Samples of a step attempt that did not finish are kept (they were
acknowledged) but marked by their attempt number; analysis reads the samples
of finished attempts only (:meth:`RunStore.samples`).
"""

from __future__ import annotations

import csv
import json
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.errors import DataError, RunStateError
from station.store.backends import open_backend
from station.store.errors import StoreError, StoreVersionError
from station.store.schema import APPLICATION, BASE, SCHEMA_VERSION, migration, statements
from station.numeric import dumps
#: longest description of an overhaul, characters (a sentence or a paragraph; documents go with the ticket)
MAX_OVERHAUL_TEXT = 2000
#: longest overhaul ticket, characters
MAX_TICKET_TEXT = 200

#: The run state machine, as data: the states a run may go to from each state.
#: ``running -> running`` is a resume after the process that ran it died without
#: journaling its end (``kill -9``); a done run is final.
RUN_TRANSITIONS: dict[str, frozenset[str]] = {
    "running": frozenset({"done", "failed", "aborted", "running"}),
    "failed": frozenset({"running"}),
    "aborted": frozenset({"running"}),
    "done": frozenset(),
}


@dataclass(frozen=True)
class StepRecord:
    idx: int
    attempt: int
    name: str
    status: str
    started_at: float
    ended_at: float | None
    output: dict | None
    message: str | None


@dataclass(frozen=True)
class RunRecord:
    run_id: str
    procedure: str
    model: str | None
    serial: str | None
    overhaul_state: str | None
    config: dict
    params: dict
    status: str
    created_at: float
    finished_at: float | None
    station: str | None = None


class RunStore:
    """A station store: a SQLite path (the default) or a ``postgresql://`` URL.

    Thread-safe (one connection, one lock). ``station`` names the station
    whose runs this store creates (kept in ``runs.station``). Opening a store
    written by an older station upgrades its schema in place; a store newer
    than this code, or a database that is not a station store, is refused
    (:class:`~station.store.errors.StoreVersionError`). An unreachable
    server raises :class:`~station.store.errors.StoreUnavailable`.
    """

    def __init__(self, target: str | Path, *, station: str | None = None,
                 connect_timeout_s: float | None = None) -> None:
        self._b = open_backend(target, connect_timeout_s=connect_timeout_s)
        self.path = self._b.path
        self.name = self._b.name
        self.dialect = self._b.dialect
        self.station = station
        self._lock = threading.RLock()
        try:
            self._open_schema()
        except BaseException:
            self._b.close()
            raise

    # -- schema -----------------------------------------------------------
    def _open_schema(self) -> None:
        tables = self._b.table_names()
        if tables:
            self._check_is_station_store(tables)
        with self._b.transaction() as cur:
            self._b.lock_schema(cur)
            for sql in statements(self.dialect, BASE):
                cur.execute(sql)
            cur.execute("INSERT INTO meta(key, value) VALUES ('schema_version', ?) ON CONFLICT DO NOTHING", ("1",))
        while True:
            with self._b.transaction() as cur:
                self._b.lock_schema(cur)
                version = self._version(cur)
                if version >= SCHEMA_VERSION:
                    break
                for sql in migration(self.dialect, version + 1):
                    cur.execute(sql)
                cur.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(version + 1),))

    def _version(self, cur) -> int:
        row = cur.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        version = int(row[0])
        if version > SCHEMA_VERSION:
            raise StoreVersionError(
                f"{self.name}: store schema version {version} is newer than this station's ({SCHEMA_VERSION}); "
                "update the station software before using this store")
        return version

    def _check_is_station_store(self, tables: set[str]) -> None:
        if "meta" not in tables:
            raise StoreVersionError(f"{self.name}: not a station store (it has tables "
                                    f"{', '.join(sorted(tables)[:5])} but no station meta table)")
        meta = dict(self._b.query("SELECT key, value FROM meta"))
        app = meta.get("application")
        if "schema_version" not in meta or (app is not None and app != APPLICATION):
            raise StoreVersionError(f"{self.name}: not a station store (its meta table says "
                                    f"application={app!r}, schema_version={meta.get('schema_version')!r})")
        try:
            version = int(meta["schema_version"])
        except ValueError:
            raise StoreVersionError(f"{self.name}: not a station store (schema_version "
                                    f"{meta['schema_version']!r})") from None
        if version > SCHEMA_VERSION:
            raise StoreVersionError(
                f"{self.name}: store schema version {version} is newer than this station's ({SCHEMA_VERSION}); "
                "update the station software before using this store")

    def schema_version(self) -> int:
        return int(self._b.query("SELECT value FROM meta WHERE key='schema_version'")[0][0])

    # -- plumbing ---------------------------------------------------------
    @property
    def backend(self):
        """The connection (for :mod:`station.store.forward` and the fleet queries)."""
        return self._b

    def close(self) -> None:
        with self._lock:
            self._b.close()

    def __enter__(self) -> "RunStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _tx(self, stmts: Iterable[tuple[str, tuple]]) -> None:
        with self._lock, self._b.transaction() as cur:
            for sql, args in stmts:
                cur.execute(sql, args)

    def _query(self, sql: str, args: tuple = ()) -> list[tuple]:
        with self._lock:
            return self._b.query(sql, args)

    # -- robots and runs --------------------------------------------------
    def robot_id(self, model: str, serial: str) -> int:
        """Id of the robot (model, serial), created on first use."""
        with self._lock:
            self._b.execute("INSERT INTO robots(model, serial) VALUES (?, ?) ON CONFLICT DO NOTHING", (model, serial))
            ((rid,),) = self._b.query("SELECT robot_id FROM robots WHERE model=? AND serial=?", (model, serial))
        return int(rid)

    def robot_models(self, serial: str) -> list[str]:
        """The models of the robots with this serial (a robot is its model and serial)."""
        return [r[0] for r in self._query("SELECT model FROM robots WHERE serial=? ORDER BY model", (serial,))]

    def resolve_robot(self, serial: str, model: str | None = None) -> tuple[str, str]:
        """``(model, serial)`` of the one robot meant: a robot is keyed by model and serial everywhere; a
        serial alone is enough while one model has it, else StoreError asks for the model."""
        models = self.robot_models(serial)
        if model is not None:
            if model not in models:
                raise StoreError(f"no robot {model} serial {serial!r} in {self.name}"
                                 + (f" (that serial is a {', '.join(models)})" if models else ""))
            return model, serial
        if not models:
            raise StoreError(f"no robot with serial {serial!r} in {self.name}")
        if len(models) > 1:
            raise StoreError(f"serial {serial!r} belongs to robots of {len(models)} models ({', '.join(models)}) "
                             f"in {self.name}: name the model")
        return models[0], serial

    # -- overhauls --------------------------------------------------------
    def record_overhaul(self, model: str, serial: str, at_s: float, what: str, *, ticket: str | None = None,
                        station: str | None = None) -> bool:
        """Record an overhaul of robot (``model``, ``serial``) done at ``at_s`` (epoch s): what was done and
        its work ticket. An overhaul is an event in the robot's life; the since-overhaul figures and the
        drift test count from the last one. Returns False when this robot already has one at ``at_s``."""
        import math

        what = (what or "").strip()
        if not what:
            raise StoreError("an overhaul needs a description of what was done")
        if len(what) > MAX_OVERHAUL_TEXT:
            raise StoreError(f"an overhaul's description is {len(what)} characters; at most {MAX_OVERHAUL_TEXT} "
                             "(say what was done; attach documents to the ticket)")
        if ticket is not None and len(str(ticket)) > MAX_TICKET_TEXT:
            raise StoreError(f"an overhaul's ticket is {len(str(ticket))} characters; at most {MAX_TICKET_TEXT}")
        if not (isinstance(at_s, (int, float)) and math.isfinite(at_s)) or at_s > time.time() + 86400.0:
            raise StoreError(f"overhaul time {at_s!r} is not a time up to now")
        rid = self.robot_id(model, serial)
        with self._lock:
            before = self._b.query("SELECT COUNT(*) FROM overhauls WHERE robot_id=? AND at=?", (rid, float(at_s)))
            self._b.execute("INSERT INTO overhauls(robot_id, at, what, ticket, station, recorded_at)"
                            " VALUES (?,?,?,?,?,?) ON CONFLICT DO NOTHING",
                            (rid, float(at_s), what, ticket, station or self.station, time.time()))
        return before[0][0] == 0

    def overhauls(self, model: str | None = None, serial: str | None = None) -> list[dict]:
        """Recorded overhauls (of one robot, or all), oldest first: model, serial, at, what, ticket,
        station, recorded_at (times in epoch s)."""
        sql = ("SELECT b.model, b.serial, o.at, o.what, o.ticket, o.station, o.recorded_at"
               " FROM overhauls o JOIN robots b ON b.robot_id=o.robot_id")
        where, args = [], []
        if model is not None:
            where.append("b.model=?")
            args.append(model)
        if serial is not None:
            where.append("b.serial=?")
            args.append(serial)
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY b.model, b.serial, o.at"
        keys = ("model", "serial", "at", "what", "ticket", "station", "recorded_at")
        return [dict(zip(keys, r)) for r in self._query(sql, tuple(args))]

    def create_run(
        self,
        run_id: str,
        procedure: str,
        *,
        model: str | None,
        serial: str | None,
        overhaul_state: str | None,
        config: Mapping,
        params: Mapping,
        station: str | None = None,
    ) -> None:
        rid = self.robot_id(model, serial) if model and serial else None
        try:
            self._tx(
                [
                    (
                        "INSERT INTO runs(run_id, robot_id, procedure, overhaul_state, config_json, params_json,"
                        " status, created_at, station) VALUES (?,?,?,?,?,?,?,?,?)",
                        (run_id, rid, procedure, overhaul_state, dumps(config), dumps(params), "running",
                         time.time(), station or self.station),
                    )
                ]
            )
        except self._b.integrity_errors as exc:
            raise StoreError(f"run {run_id!r} already exists in {self.name}") from exc

    def run(self, run_id: str) -> RunRecord:
        """The record of run ``run_id`` (:class:`RunRecord`: ``run_id``, ``procedure``, ``model``, ``serial``,
        ``overhaul_state``, ``config`` and ``params`` (dicts as stored), ``status`` (one of
        :data:`RUN_TRANSITIONS`), ``created_at``/``finished_at`` (s since the epoch; None while not
        finished), ``station``). StoreError if there is none."""
        rows = self._query(
            "SELECT r.run_id, r.procedure, b.model, b.serial, r.overhaul_state, r.config_json, r.params_json,"
            " r.status, r.created_at, r.finished_at, r.station FROM runs r LEFT JOIN robots b USING (robot_id)"
            " WHERE r.run_id=?",
            (run_id,),
        )
        if not rows:
            raise StoreError(f"no run {run_id!r} in {self.name}")
        r = rows[0]
        return RunRecord(r[0], r[1], r[2], r[3], r[4], json.loads(r[5]), json.loads(r[6]), r[7], r[8], r[9], r[10])

    def runs(self) -> list[RunRecord]:
        ids = [r[0] for r in self._query("SELECT run_id FROM runs ORDER BY created_at, run_id")]
        return [self.run(i) for i in ids]

    def set_run_status(self, run_id: str, status: str) -> None:
        """Move a run to ``status``; a move that :data:`RUN_TRANSITIONS` does not allow raises RunStateError."""
        if status not in RUN_TRANSITIONS:
            raise RunStateError(f"run {run_id}: unknown status {status!r} (one of {', '.join(RUN_TRANSITIONS)})")
        with self._lock:
            rows = self._b.query("SELECT status FROM runs WHERE run_id=?", (run_id,))
            if not rows:
                raise StoreError(f"no run {run_id!r} in {self.name}")
            current = rows[0][0]
            if status not in RUN_TRANSITIONS.get(current, frozenset()):
                allowed = ", ".join(sorted(RUN_TRANSITIONS.get(current, ()))) or "nothing: it is final"
                raise RunStateError(f"run {run_id} is {current}; it cannot become {status} (allowed: {allowed})")
            finished = time.time() if status in ("done", "failed") else None
            self._tx([("UPDATE runs SET status=?, finished_at=? WHERE run_id=?", (status, finished, run_id))])

    # -- journal ----------------------------------------------------------
    def step_started(self, run_id: str, idx: int, name: str) -> int:
        """Journal the start of step ``idx``; returns its attempt number (1, 2, ...)."""
        with self._lock:
            ((last,),) = self._b.query(
                "SELECT COALESCE(MAX(attempt), 0) FROM steps WHERE run_id=? AND idx=?", (run_id, idx)
            )
            attempt = int(last) + 1
            self._tx(
                [
                    (
                        "INSERT INTO steps(run_id, idx, attempt, name, status, started_at) VALUES (?,?,?,?,?,?)",
                        (run_id, idx, attempt, name, "running", time.time()),
                    )
                ]
            )
        return attempt

    def step_ended(
        self, run_id: str, idx: int, attempt: int, status: str, output: Mapping | None = None, message: str | None = None
    ) -> None:
        if status not in ("done", "failed", "aborted"):
            raise StoreError(f"step status must be done, failed or aborted, got {status!r}")
        self._tx(
            [
                (
                    "UPDATE steps SET status=?, ended_at=?, output_json=?, message=? WHERE run_id=? AND idx=? AND attempt=?",
                    (status, time.time(), dumps(output) if output is not None else None, message, run_id, idx, attempt),
                )
            ]
        )

    def steps(self, run_id: str) -> list[StepRecord]:
        rows = self._query(
            "SELECT idx, attempt, name, status, started_at, ended_at, output_json, message FROM steps"
            " WHERE run_id=? ORDER BY idx, attempt",
            (run_id,),
        )
        return [
            StepRecord(r[0], r[1], r[2], r[3], r[4], r[5], json.loads(r[6]) if r[6] else None, r[7]) for r in rows
        ]

    def done_steps(self, run_id: str) -> dict[int, StepRecord]:
        """The finished attempt of every finished step, by index."""
        return {s.idx: s for s in self.steps(run_id) if s.status == "done"}

    # -- samples ----------------------------------------------------------
    def append_samples(
        self, run_id: str, stream: str, step_idx: int, attempt: int, columns: Mapping[str, np.ndarray]
    ) -> int:
        """Commit one batch of samples; when this returns they are acknowledged.

        ``columns`` maps column name to a 1-D array; all the same length.
        Returns the number of samples committed.
        """
        names = list(columns)
        if not names:
            raise DataError(f"stream {stream!r}: a batch needs at least one column")
        arrays = [np.asarray(columns[n], dtype=float).ravel() for n in names]
        n = arrays[0].size
        for name, arr in zip(names, arrays):
            if arr.size != n:
                raise DataError(f"stream {stream!r}: column {name!r} has {arr.size} values, expected {n}")
        if n == 0:
            return 0
        block = np.ascontiguousarray(np.column_stack(arrays), dtype="<f8")
        with self._lock:
            ((last,),) = self._b.query(
                "SELECT COALESCE(MAX(batch_no), -1) FROM sample_batches"
                " WHERE run_id=? AND stream=? AND step_idx=? AND attempt=?",
                (run_id, stream, step_idx, attempt),
            )
            self._tx(
                [
                    (
                        "INSERT INTO sample_batches(run_id, stream, step_idx, attempt, batch_no, n, columns, data,"
                        " committed_at) VALUES (?,?,?,?,?,?,?,?,?)",
                        (run_id, stream, step_idx, attempt, int(last) + 1, n, json.dumps(names), block.tobytes(), time.time()),
                    )
                ]
            )
        return n

    def sample_count(self, run_id: str, stream: str | None = None, *, finished_only: bool = False) -> int:
        rows = self._batches(run_id, stream, finished_only=finished_only, with_data=False)
        return int(sum(r[4] for r in rows))

    def _batches(self, run_id, stream, *, finished_only, with_data, steps=None):
        sql = (
            "SELECT b.stream, b.step_idx, b.attempt, b.batch_no, b.n, b.columns"
            + (", b.data" if with_data else "")
            + " FROM sample_batches b"
        )
        where, args = ["b.run_id=?"], [run_id]
        if finished_only:
            sql += " JOIN steps s ON s.run_id=b.run_id AND s.idx=b.step_idx AND s.attempt=b.attempt"
            where.append("s.status='done'")
        if stream is not None:
            where.append("b.stream=?")
            args.append(stream)
        if steps is not None:
            steps = [int(s) for s in steps]
            where.append(f"b.step_idx IN ({','.join('?' * len(steps))})" if steps else "1=0")
            args.extend(steps)
        sql += " WHERE " + " AND ".join(where) + " ORDER BY b.stream, b.step_idx, b.attempt, b.batch_no"
        return self._query(sql, tuple(args))

    def samples(
        self, run_id: str, stream: str, *, finished_only: bool = True, steps: Iterable[int] | None = None
    ) -> dict[str, np.ndarray]:
        """All samples of ``stream`` as columns (plus ``step_idx``), in step order.

        By default only the samples of finished step attempts; pass
        ``finished_only=False`` to see every acknowledged sample.
        """
        rows = self._batches(run_id, stream, finished_only=finished_only, with_data=True, steps=steps)
        if not rows:
            return {}
        names = json.loads(rows[0][5])
        blocks, step_col = [], []
        for r in rows:
            cols = json.loads(r[5])
            if cols != names:
                raise StoreError(f"run {run_id} stream {stream!r}: batch columns {cols} differ from {names}")
            block = np.frombuffer(r[6], dtype="<f8").reshape(r[4], len(cols))
            blocks.append(block)
            step_col.append(np.full(r[4], r[1], dtype=np.int64))
        data = np.vstack(blocks)
        out = {name: data[:, i].copy() for i, name in enumerate(names)}
        out["step_idx"] = np.concatenate(step_col)
        return out

    def streams(self, run_id: str) -> list[str]:
        return [r[0] for r in self._query("SELECT DISTINCT stream FROM sample_batches WHERE run_id=? ORDER BY stream", (run_id,))]

    # -- results ----------------------------------------------------------
    def put_result(self, run_id: str, key: str, value) -> None:
        self._tx([("INSERT INTO results(run_id, key, value_json) VALUES (?,?,?)"
                   " ON CONFLICT (run_id, key) DO UPDATE SET value_json=excluded.value_json", (run_id, key, dumps(value)))])

    def result(self, run_id: str, key: str):
        """The JSON value stored under ``key`` (e.g. ``"iso9283"``: the analysis; ``"verdict"``:
        ``{"verdict", "reasons", "conformant", "exit_code"}``; ``"measurements"``: the plant's judged
        measurements). StoreError if the run has no such result."""
        rows = self._query("SELECT value_json FROM results WHERE run_id=? AND key=?", (run_id, key))
        if not rows:
            raise StoreError(f"run {run_id}: no result {key!r}")
        return json.loads(rows[0][0])

    def results(self, run_id: str) -> dict:
        """Every stored result of the run: ``{key: JSON value}`` (see :meth:`result`); empty when none."""
        return {k: json.loads(v) for k, v in self._query("SELECT key, value_json FROM results WHERE run_id=?", (run_id,))}

    def put_characteristics(self, run_id: str, rows: Iterable[Mapping]) -> None:
        """Rows with pose, name, value, unit, limit (or None), passed (or None)."""
        stmts = []
        for r in rows:
            passed = r.get("passed")
            stmts.append(
                (
                    "INSERT INTO characteristics(run_id, pose, name, value, unit, limit_value, passed)"
                    " VALUES (?,?,?,?,?,?,?) ON CONFLICT (run_id, pose, name) DO UPDATE SET value=excluded.value,"
                    " unit=excluded.unit, limit_value=excluded.limit_value, passed=excluded.passed",
                    (
                        run_id,
                        str(r["pose"]),
                        str(r["name"]),
                        None if r.get("value") is None else float(r["value"]),
                        str(r["unit"]),
                        None if r.get("limit") is None else float(r["limit"]),
                        None if passed is None else int(bool(passed)),
                    ),
                )
            )
        self._tx(stmts)

    def characteristics(self, run_id: str) -> list[dict]:
        """One dict per stored number of the run, by pose then name: ``pose`` (``"P1"``, ``"P2-P4"``,
        ``"run"``), ``name`` (unit in the name: ``"RP_mm"``), ``value`` (None: not computed), ``unit``,
        ``limit`` (None: no limit) and ``passed`` (True, False; None without a limit or not decided)."""
        rows = self._query(
            "SELECT pose, name, value, unit, limit_value, passed FROM characteristics WHERE run_id=? ORDER BY pose, name",
            (run_id,),
        )
        return [
            {"pose": r[0], "name": r[1], "value": r[2], "unit": r[3], "limit": r[4], "passed": None if r[5] is None else bool(r[5])}
            for r in rows
        ]

    # -- re-analyses ------------------------------------------------------
    def put_reanalysis(self, run_id: str, key: str, analysis_version: str, value) -> None:
        """Keep a re-analysis result beside the original (never replacing ``results``)."""
        self._tx([("INSERT INTO reanalyses(run_id, key, analysis_version, value_json, created_at) VALUES (?,?,?,?,?)"
                   " ON CONFLICT (run_id, key, analysis_version) DO UPDATE SET value_json=excluded.value_json,"
                   " created_at=excluded.created_at", (run_id, key, analysis_version, dumps(value), time.time()))])

    def reanalyses(self, run_id: str) -> dict[str, dict]:
        """``{analysis_version: {key: value}}`` of a run, oldest version first."""
        out: dict[str, dict] = {}
        for version, key, value in self._query(
                "SELECT analysis_version, key, value_json FROM reanalyses WHERE run_id=? ORDER BY created_at, key",
                (run_id,)):
            out.setdefault(version, {})[key] = json.loads(value)
        return out

    # -- history ----------------------------------------------------------
    def history(self, serial: str, name: str, pose: str | None = None, *, model: str | None = None) -> list[dict]:
        """One robot's values of characteristic ``name`` (or a plant measurement) across its finished runs, oldest
        first.

        The robot is (``model``, ``serial``); the model may be left out while
        one model has that serial (:meth:`resolve_robot`). Rows: ``run_id``,
        ``created_at`` (epoch s), ``overhaul_state`` (the run's label),
        ``pose``, ``value``, ``limit``, ``passed`` (None without a limit).
        """
        if not self.robot_models(serial):
            return []  # no robot of that serial: nothing to show (the command says so)
        model, serial = self.resolve_robot(serial, model)
        sql = (
            "SELECT r.run_id, r.created_at, r.overhaul_state, c.pose, c.value, c.limit_value, c.passed"
            " FROM characteristics c JOIN runs r USING (run_id) JOIN robots b USING (robot_id)"
            " WHERE b.serial=? AND b.model=? AND c.name=? AND r.status='done'"
        )
        args: list = [serial, model, name]
        if pose is not None:
            sql += " AND c.pose=?"
            args.append(pose)
        sql += " ORDER BY r.created_at, r.run_id, c.pose"
        return [
            {"run_id": r[0], "created_at": r[1], "overhaul_state": r[2], "pose": r[3], "value": r[4], "limit": r[5],
             "passed": None if r[6] is None else bool(r[6])}
            for r in self._query(sql, tuple(args))
        ]

    def robots_exceeding(self, name: str, *, latest_only: bool = True) -> list[dict]:
        """Robots with a value of ``name`` over its limit (in their latest finished run by default)."""
        sql = (
            "SELECT b.model, b.serial, r.run_id, r.created_at, c.pose, c.value, c.limit_value"
            " FROM characteristics c JOIN runs r USING (run_id) JOIN robots b USING (robot_id)"
            " WHERE c.name=? AND c.limit_value IS NOT NULL AND c.value > c.limit_value AND r.status='done'"
        )
        if latest_only:
            sql += (
                " AND r.created_at = (SELECT MAX(r2.created_at) FROM runs r2 WHERE r2.robot_id=r.robot_id"
                " AND r2.status='done' AND r2.run_id IN (SELECT run_id FROM characteristics WHERE name=?))"
            )
            args: tuple = (name, name)
        else:
            args = (name,)
        sql += " ORDER BY b.serial, r.created_at, c.pose"
        return [
            {"model": r[0], "serial": r[1], "run_id": r[2], "created_at": r[3], "pose": r[4], "value": r[5], "limit": r[6]}
            for r in self._query(sql, args)
        ]

    # -- export -----------------------------------------------------------
    def export(self, run_id: str, out_dir: str | Path, fmt: str = "csv") -> list[Path]:
        """Write every stream, the journal and the characteristics of a run as CSV or Parquet."""
        if fmt not in ("csv", "parquet"):
            raise StoreError(f"export format must be 'csv' or 'parquet', got {fmt!r}")
        self.run(run_id)  # raises for an unknown run
        from station.readers.out_files import output_dir

        out = output_dir(out_dir, "--out")
        tables: dict[str, dict[str, list | np.ndarray]] = {}
        for stream in self.streams(run_id):
            tables[f"samples_{stream}"] = self.samples(run_id, stream, finished_only=False)
        steps = self.steps(run_id)
        tables["steps"] = {
            "idx": [s.idx for s in steps], "attempt": [s.attempt for s in steps], "name": [s.name for s in steps],
            "status": [s.status for s in steps], "started_at": [s.started_at for s in steps],
            "ended_at": [s.ended_at for s in steps],
        }
        chars = self.characteristics(run_id)
        tables["characteristics"] = {k: [c[k] for c in chars] for k in ("pose", "name", "value", "unit", "limit", "passed")}
        written = []
        for name, cols in tables.items():
            path = out / f"{name}.{fmt}"
            if fmt == "csv":
                _write_csv(path, cols)
            else:
                import pyarrow as pa
                import pyarrow.parquet as pq

                from station.readers.out_files import output_file

                with output_file(path, "--out", binary=True) as fh:
                    pq.write_table(pa.table({k: list(v) if not isinstance(v, np.ndarray) else v
                                             for k, v in cols.items()}), fh)
            written.append(path)
        return written


def _write_csv(path: Path, cols: Mapping[str, Iterable]) -> None:
    names = list(cols)
    columns = [list(cols[n]) for n in names]
    from station.readers.out_files import output_file

    with output_file(path, "--out", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for row in zip(*columns):
            w.writerow(["" if v is None else (repr(float(v)) if isinstance(v, (float, np.floating)) else v) for v in row])


