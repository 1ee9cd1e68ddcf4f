"""Store-and-forward: a station writes locally first and forwards its runs to the central store.

The local store (SQLite) keeps its crash guarantees; :func:`push` copies what
the central store lacks, run by run:

1. the robot (by model and serial) and the run row, marked ``running`` in the
   centre until everything has arrived, with the station that made it;
2. the sample batches the local store has not recorded as forwarded, in
   chunks; each chunk commits in the centre, then is recorded locally in
   ``forwarded_batches``;
3. the journal, results, characteristics and the run's own status, in one
   transaction; then ``forward_state`` records the status that reached the
   centre;

and then, for every robot and run, what was added after a run had reached
the centre: recorded overhauls (events in a robot's life, keyed by robot and
time) and re-analyses (keyed by run, result and analysis version), each sent
once.

A push is idempotent by (run, stream, step, attempt, batch): a batch that
reached the centre but was not yet recorded locally (the station killed
between the two commits) is found in the centre and not sent again. Pushes
of one run take a per-run advisory lock in the centre, so several processes
pushing at once never interleave a run's batches; different runs go in
parallel. A run id the centre already holds for another station is refused
(:class:`PushConflict`), never merged.

A lost connection raises :class:`~station.store.errors.StoreUnavailable`
(nothing local changes; the next push resumes where this one stopped);
:class:`Forwarder` retries in the background with a growing pause.
"""

from __future__ import annotations

import threading
import time
import zlib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from station.errors import ConfigError
from station.store.errors import StoreError, StoreUnavailable
from station.store.runstore import RunStore
from station.numeric import dumps

FINAL = ("done", "failed", "aborted")
_KEY = ("stream", "step_idx", "attempt", "batch_no")


class PushConflict(StoreError):
    """The central store holds a run of the same id made by another station."""


@dataclass
class RunPush:
    run_id: str
    status: str
    batches_sent: int = 0
    samples_sent: int = 0
    batches_already_there: int = 0
    skipped: bool = False
    error: str | None = None


@dataclass
class PushReport:
    runs: list[RunPush] = field(default_factory=list)
    #: recorded overhauls and re-analysis results the centre did not have
    overhauls_sent: int = 0
    reanalyses_sent: int = 0

    @property
    def batches_sent(self) -> int:
        return sum(r.batches_sent for r in self.runs)

    @property
    def samples_sent(self) -> int:
        return sum(r.samples_sent for r in self.runs)

    @property
    def errors(self) -> list[RunPush]:
        return [r for r in self.runs if r.error]


def push(local: RunStore, central: RunStore, *, station: str, run_ids: Iterable[str] | None = None,
         chunk_batches: int = 200, progress: Callable[[str, int, int], None] | None = None) -> PushReport:
    """Forward every run of ``local`` the centre lacks (or the named ones); returns what was sent.

    Raises StoreUnavailable when the centre drops out (what was committed
    stays committed and recorded). A run refused for a conflict is reported
    in its :class:`RunPush` and the others go on.
    """
    if chunk_batches < 1:
        raise ConfigError(f"chunk_batches must be at least 1, got {chunk_batches}")
    wanted = list(run_ids) if run_ids is not None else _runs_to_push(local)
    report = PushReport()
    for run_id in wanted:
        rec = local.run(run_id)
        item = RunPush(run_id, rec.status)
        report.runs.append(item)
        try:
            _push_run(local, central, rec, rec.station or station, item, chunk_batches, progress)
        except PushConflict as exc:
            item.error = str(exc)
            _record_state(local, run_id, None, str(exc))
    report.overhauls_sent = _push_overhauls(local, central)
    report.reanalyses_sent = _push_reanalyses(local, central)
    return report


def _push_overhauls(local: RunStore, central: RunStore) -> int:
    """Send the recorded overhauls the centre lacks (by robot and time); returns how many."""
    sent = 0
    with central.backend.transaction() as cur:
        for o in local.overhauls():
            cur.execute("INSERT INTO robots(model, serial) VALUES (?, ?) ON CONFLICT DO NOTHING", (o["model"], o["serial"]))
            rid = cur.execute("SELECT robot_id FROM robots WHERE model=? AND serial=?",
                              (o["model"], o["serial"])).fetchone()[0]
            if cur.execute("SELECT 1 FROM overhauls WHERE robot_id=? AND at=?", (rid, o["at"])).fetchone():
                continue
            cur.execute("INSERT INTO overhauls(robot_id, at, what, ticket, station, recorded_at) VALUES (?,?,?,?,?,?)",
                        (rid, o["at"], o["what"], o["ticket"], o["station"], o["recorded_at"]))
            sent += 1
    return sent


def _push_reanalyses(local: RunStore, central: RunStore) -> int:
    """Send the re-analysis results of runs the centre holds that it lacks; returns how many."""
    rows = local.backend.query("SELECT run_id, key, analysis_version, value_json, created_at FROM reanalyses"
                               " ORDER BY run_id, created_at")
    if not rows:
        return 0
    sent = 0
    with central.backend.transaction() as cur:
        for run_id, key, version, value, created_at in rows:
            if not cur.execute("SELECT 1 FROM runs WHERE run_id=?", (run_id,)).fetchone():
                continue  # the run itself has not reached the centre yet: its next push brings both
            if cur.execute("SELECT 1 FROM reanalyses WHERE run_id=? AND key=? AND analysis_version=?",
                           (run_id, key, version)).fetchone():
                continue
            cur.execute("INSERT INTO reanalyses(run_id, key, analysis_version, value_json, created_at)"
                        " VALUES (?,?,?,?,?)", (run_id, key, version, value, created_at))
            sent += 1
    return sent


def forward_status(local: RunStore) -> dict[str, dict]:
    """What of each local run has reached the centre: batches here and forwarded, status forwarded."""
    rows = local.backend.query(
        "SELECT r.run_id, r.status, "
        " (SELECT COUNT(*) FROM sample_batches b WHERE b.run_id=r.run_id),"
        " (SELECT COUNT(*) FROM forwarded_batches f WHERE f.run_id=r.run_id),"
        " s.status_pushed, s.pushed_at, s.last_error"
        " FROM runs r LEFT JOIN forward_state s ON s.run_id=r.run_id ORDER BY r.created_at, r.run_id")
    out = {}
    for run_id, status, n_local, n_fwd, pushed, at, err in rows:
        complete = pushed == status and n_fwd == n_local
        out[run_id] = {"status": status, "batches_local": int(n_local), "batches_forwarded": int(n_fwd),
                       "status_forwarded": pushed, "pushed_at": at, "last_error": err,
                       "in_centre": "complete" if complete else ("partial" if (n_fwd or pushed) else "no")}
    return out


# -- one run -----------------------------------------------------------------

def _runs_to_push(local: RunStore) -> list[str]:
    """Runs not running-free-and-complete in the centre: unfinished, changed status, or batches left."""
    rows = local.backend.query(
        "SELECT r.run_id FROM runs r LEFT JOIN forward_state s ON s.run_id=r.run_id"
        " WHERE s.status_pushed IS NULL OR s.status_pushed <> r.status OR r.status NOT IN ('done','failed','aborted')"
        " OR EXISTS (SELECT 1 FROM sample_batches b WHERE b.run_id=r.run_id AND NOT EXISTS"
        "   (SELECT 1 FROM forwarded_batches f WHERE f.run_id=b.run_id AND f.stream=b.stream"
        "    AND f.step_idx=b.step_idx AND f.attempt=b.attempt AND f.batch_no=b.batch_no))"
        " ORDER BY r.created_at, r.run_id")
    return [r[0] for r in rows]


def _run_lock_key(run_id: str) -> int:
    return zlib.crc32(run_id.encode()) - 2**31


def _lock_run(central: RunStore, cur, run_id: str) -> None:
    if central.dialect == "postgresql":
        cur.execute("SELECT pg_advisory_xact_lock(?, ?)", (0x5748, _run_lock_key(run_id)))


def _push_run(local, central, rec, station, item: RunPush, chunk: int, progress) -> None:
    cb = central.backend
    with cb.transaction() as cur:
        _lock_run(central, cur, rec.run_id)
        row = cur.execute("SELECT station FROM runs WHERE run_id=?", (rec.run_id,)).fetchone()
        if row is not None and row[0] is not None and row[0] != station:
            raise PushConflict(f"run {rec.run_id}: the central store {central.name} already holds a run of this id "
                               f"from station {row[0]!r}; not merged")
        rid = None
        if rec.model and rec.serial:
            cur.execute("INSERT INTO robots(model, serial) VALUES (?, ?) ON CONFLICT DO NOTHING", (rec.model, rec.serial))
            rid = cur.execute("SELECT robot_id FROM robots WHERE model=? AND serial=?", (rec.model, rec.serial)).fetchone()[0]
        if row is None:
            cur.execute(
                "INSERT INTO runs(run_id, robot_id, procedure, overhaul_state, config_json, params_json, status,"
                " created_at, finished_at, station) VALUES (?,?,?,?,?,?,?,?,?,?)",
                (rec.run_id, rid, rec.procedure, rec.overhaul_state, dumps(rec.config), dumps(rec.params),
                 "running", rec.created_at, None, station))
    keys = local.backend.query(
        "SELECT b.stream, b.step_idx, b.attempt, b.batch_no FROM sample_batches b"
        " LEFT JOIN forwarded_batches f ON f.run_id=b.run_id AND f.stream=b.stream AND f.step_idx=b.step_idx"
        "  AND f.attempt=b.attempt AND f.batch_no=b.batch_no"
        " WHERE b.run_id=? AND f.run_id IS NULL ORDER BY b.stream, b.step_idx, b.attempt, b.batch_no", (rec.run_id,))
    for start in range(0, len(keys), chunk):
        part = keys[start:start + chunk]
        rows = [_local_batch(local, rec.run_id, k) for k in part]
        sent, there = _send_batches(central, rec.run_id, rows)
        item.batches_sent += sent
        item.samples_sent += sum(r[5] for r in rows if (r[1], r[2], r[3], r[4]) not in there)
        item.batches_already_there += len(there)
        with local.backend.transaction() as lcur:
            for k in part:
                lcur.execute("INSERT INTO forwarded_batches(run_id, stream, step_idx, attempt, batch_no)"
                             " VALUES (?,?,?,?,?) ON CONFLICT DO NOTHING", (rec.run_id, *k))
        if progress is not None:
            progress(rec.run_id, start + len(part), len(keys))
    rec_now = local.run(rec.run_id)  # the run may have moved on while its batches went
    steps = local.steps(rec.run_id)
    results = local.results(rec.run_id)
    chars = local.characteristics(rec.run_id)
    with cb.transaction() as cur:
        _lock_run(central, cur, rec.run_id)
        for s in steps:
            cur.execute(
                "INSERT INTO steps(run_id, idx, attempt, name, status, started_at, ended_at, output_json, message)"
                " VALUES (?,?,?,?,?,?,?,?,?) ON CONFLICT (run_id, idx, attempt) DO UPDATE SET status=excluded.status,"
                " ended_at=excluded.ended_at, output_json=excluded.output_json, message=excluded.message",
                (rec.run_id, s.idx, s.attempt, s.name, s.status, s.started_at, s.ended_at,
                 None if s.output is None else dumps(s.output), s.message))
        for key, value in results.items():
            cur.execute("INSERT INTO results(run_id, key, value_json) VALUES (?,?,?) ON CONFLICT (run_id, key)"
                        " DO UPDATE SET value_json=excluded.value_json", (rec.run_id, key, dumps(value)))
        for c in chars:
            cur.execute(
                "INSERT INTO characteristics(run_id, pose, name, value, unit, limit_value, passed)"
                " VALUES (?,?,?,?,?,?,?) ON CONFLICT (run_id, pose, name) DO UPDATE SET value=excluded.value,"
                " unit=excluded.unit, limit_value=excluded.limit_value, passed=excluded.passed",
                (rec.run_id, c["pose"], c["name"], c["value"], c["unit"], c["limit"],
                 None if c["passed"] is None else int(c["passed"])))
        cur.execute("UPDATE runs SET status=?, finished_at=?, overhaul_state=? WHERE run_id=?",
                    (rec_now.status, rec_now.finished_at, rec_now.overhaul_state, rec.run_id))
    item.status = rec_now.status
    _record_state(local, rec.run_id, rec_now.status, None)


def _record_state(local: RunStore, run_id: str, status_pushed: str | None, error: str | None) -> None:
    ((n_fwd,),) = local.backend.query("SELECT COUNT(*) FROM forwarded_batches WHERE run_id=?", (run_id,))
    with local.backend.transaction() as cur:
        cur.execute(
            "INSERT INTO forward_state(run_id, status_pushed, batches_pushed, pushed_at, last_error) VALUES (?,?,?,?,?)"
            " ON CONFLICT (run_id) DO UPDATE SET status_pushed=COALESCE(excluded.status_pushed,"
            " forward_state.status_pushed), batches_pushed=excluded.batches_pushed,"
            " pushed_at=excluded.pushed_at, last_error=excluded.last_error",
            (run_id, status_pushed, int(n_fwd), time.time(), error))


def _local_batch(local: RunStore, run_id: str, key: tuple) -> tuple:
    ((n, columns, data, committed_at),) = local.backend.query(
        "SELECT n, columns, data, committed_at FROM sample_batches"
        " WHERE run_id=? AND stream=? AND step_idx=? AND attempt=? AND batch_no=?", (run_id, *key))
    return (run_id, key[0], int(key[1]), int(key[2]), int(key[3]), int(n), columns, bytes(data), float(committed_at))


def _send_batches(central: RunStore, run_id: str, rows: list[tuple]) -> tuple[int, set]:
    """Commit the batches the centre lacks in one transaction; returns (sent, keys already there)."""
    cb = central.backend
    with cb.transaction() as cur:
        _lock_run(central, cur, run_id)
        lo = min(r[4] for r in rows)
        hi = max(r[4] for r in rows)
        there = {tuple(k) for k in cur.execute(
            "SELECT stream, step_idx, attempt, batch_no FROM sample_batches WHERE run_id=? AND batch_no BETWEEN ? AND ?",
            (run_id, lo, hi)).fetchall()}
        there &= {(r[1], r[2], r[3], r[4]) for r in rows}
        todo = [r for r in rows if (r[1], r[2], r[3], r[4]) not in there]
        if central.dialect == "postgresql":
            with cur.raw.copy("COPY sample_batches (run_id, stream, step_idx, attempt, batch_no, n, columns, data,"
                              " committed_at) FROM STDIN (FORMAT BINARY)") as copy:
                copy.set_types(["text", "text", "int4", "int4", "int4", "int4", "text", "bytea", "float8"])
                for r in todo:
                    copy.write_row(r)
        else:
            for r in todo:
                cur.execute("INSERT INTO sample_batches(run_id, stream, step_idx, attempt, batch_no, n, columns, data,"
                            " committed_at) VALUES (?,?,?,?,?,?,?,?,?)", r)
    return len(todo), there


# -- in the background ---------------------------------------------------------

class Forwarder:
    """Pushes a local store to the centre every ``interval_s`` in a thread, until :meth:`stop`.

    Each pass opens what it lacks (its own connections to both stores),
    pushes, and on StoreUnavailable closes the central connection and waits
    ``interval_s`` doubled up to ``max_pause_s`` before trying again. The
    last report and error are kept in :attr:`last_report` / :attr:`last_error`.
    """

    def __init__(self, local_target, central_target, *, station: str, interval_s: float = 5.0,
                 max_pause_s: float = 60.0, chunk_batches: int = 200, connect_timeout_s: float = 5.0,
                 on_pass: Callable[[PushReport | None, BaseException | None], None] | None = None) -> None:
        if interval_s <= 0:
            raise ConfigError(f"interval_s must be positive, got {interval_s}")
        self.local_target, self.central_target = local_target, central_target
        self.station, self.interval_s, self.max_pause_s = station, interval_s, max_pause_s
        self.chunk_batches, self.connect_timeout_s, self.on_pass = chunk_batches, connect_timeout_s, on_pass
        self.last_report: PushReport | None = None
        self.last_error: BaseException | None = None
        self.passes = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "Forwarder":
        self._thread = threading.Thread(target=self._loop, name="store-forwarder")
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 30.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def is_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> "Forwarder":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def run_once(self, local: RunStore, central: RunStore | None) -> RunStore | None:
        """One pass; returns the central store to keep (None after it dropped out)."""
        try:
            if central is None:
                central = RunStore(self.central_target, connect_timeout_s=self.connect_timeout_s)
            self.last_report = push(local, central, station=self.station, chunk_batches=self.chunk_batches)
            self.last_error = None
        except StoreError as exc:  # unreachable, dropped, or refused: the local store goes on
            self.last_error = exc
            if isinstance(exc, StoreUnavailable) and central is not None:
                try:
                    central.close()
                except Exception:
                    pass
                central = None
        self.passes += 1
        if self.on_pass is not None:
            self.on_pass(self.last_report if self.last_error is None else None, self.last_error)
        return central

    def _loop(self) -> None:
        local = RunStore(self.local_target, station=self.station)
        central = None
        pause = self.interval_s
        try:
            while not self._stop.is_set():
                central = self.run_once(local, central)
                pause = self.interval_s if self.last_error is None else min(2 * pause, self.max_pause_s)
                self._stop.wait(pause)
        finally:
            local.close()
            if central is not None:
                central.close()
