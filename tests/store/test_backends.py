"""One interface, two backends: same answers, schema versions, migrations, refusals."""

import sqlite3
import threading
import time

import numpy as np
import psycopg
import pytest

from station.store import SCHEMA_VERSION, RunStore, StoreError, StoreUnavailable, StoreVersionError
from station.store import backends
from station.store_url import parse_pg_url

# the schema the first stations wrote (version 1), verbatim: their files must open and upgrade in place
V1_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE robots (robot_id INTEGER PRIMARY KEY, model TEXT NOT NULL, serial TEXT NOT NULL, UNIQUE (model, serial));
CREATE TABLE runs (run_id TEXT PRIMARY KEY, robot_id INTEGER REFERENCES robots(robot_id), procedure TEXT NOT NULL,
    overhaul_state TEXT, config_json TEXT NOT NULL, params_json TEXT NOT NULL, status TEXT NOT NULL,
    created_at REAL NOT NULL, finished_at REAL);
CREATE TABLE steps (run_id TEXT NOT NULL REFERENCES runs(run_id), idx INTEGER NOT NULL, attempt INTEGER NOT NULL,
    name TEXT NOT NULL, status TEXT NOT NULL, started_at REAL NOT NULL, ended_at REAL, output_json TEXT, message TEXT,
    PRIMARY KEY (run_id, idx, attempt));
CREATE TABLE sample_batches (run_id TEXT NOT NULL, stream TEXT NOT NULL, step_idx INTEGER NOT NULL,
    attempt INTEGER NOT NULL, batch_no INTEGER NOT NULL, n INTEGER NOT NULL, columns TEXT NOT NULL, data BLOB NOT NULL,
    committed_at REAL NOT NULL, PRIMARY KEY (run_id, stream, step_idx, attempt, batch_no));
CREATE TABLE results (run_id TEXT NOT NULL REFERENCES runs(run_id), key TEXT NOT NULL, value_json TEXT NOT NULL,
    PRIMARY KEY (run_id, key));
CREATE TABLE characteristics (run_id TEXT NOT NULL REFERENCES runs(run_id), pose TEXT NOT NULL, name TEXT NOT NULL,
    value REAL, unit TEXT NOT NULL, limit_value REAL, passed INTEGER, PRIMARY KEY (run_id, pose, name));
CREATE INDEX characteristics_by_name ON characteristics (name, pose);
INSERT INTO meta VALUES ('schema_version', '1');
"""


def fill(store: RunStore, rng, n_robots: int = 6, n_runs: int = 4) -> dict:
    """Random runs of random robots, some over their limit, one failed; returns the samples written."""
    written = {}
    for i in range(n_robots):
        for k in range(n_runs):
            run_id = f"SN-{i}-{k}"
            store.create_run(run_id, "iso9283", model="industrial-3100" if i % 2 else "rb5-850", serial=f"SN-{i}",
                             overhaul_state="before" if k == 0 else "after", config={"k": k}, params={"i": i})
            att = store.step_started(run_id, 0, "measure")
            cols = {"t": np.sort(rng.uniform(0, 10, 50)), "x": rng.normal(size=50) * 1e3}
            store.append_samples(run_id, "tracker", 0, att, cols)
            store.step_ended(run_id, 0, att, "done", {"n": 50})
            written[run_id] = cols
            rp = rng.uniform(0.1, 0.8, 2)
            if (i, k) in ((0, n_runs - 1), (1, 0)):  # over the limit for sure: robot 0 now, robot 1 once before
                rp[0] = 0.5 + 0.5 * rp[0]
            store.put_characteristics(run_id, [
                {"pose": p, "name": "RP_mm", "value": float(v), "unit": "mm", "limit": 0.5,
                 "passed": None} for p, v in zip(("P1", "P2"), rp)])
            store.put_result(run_id, "iso9283", {"RP_mm": rng.uniform()})
            store.set_run_status(run_id, "failed" if (i, k) == (2, 3) else "done")
    return written


def answers(store: RunStore) -> dict:
    out = {"runs": [(r.run_id, r.procedure, r.model, r.serial, r.overhaul_state, r.config, r.params, r.status)
                    for r in store.runs()]}
    out["history"] = [(h["run_id"], h["pose"], h["value"], h["passed"]) for s in range(6)
                      for h in store.history(f"SN-{s}", "RP_mm")]
    out["exceeding"] = [(o["serial"], o["run_id"], o["pose"], o["value"]) for o in store.robots_exceeding("RP_mm")]
    out["exceeding_all"] = [(o["serial"], o["run_id"], o["pose"]) for o in store.robots_exceeding("RP_mm", latest_only=False)]
    out["results"] = {r.run_id: store.results(r.run_id) for r in store.runs()}
    out["steps"] = [(s.idx, s.attempt, s.name, s.status, s.output) for s in store.steps("SN-1-1")]
    return out


def test_both_backends_give_the_same_answers_on_the_same_data(rng, tmp_path, pg_url):
    seed = int(rng.integers(2**63))
    lite, pg = RunStore(tmp_path / "s.sqlite"), RunStore(pg_url)
    written = fill(lite, np.random.default_rng(seed))
    fill(pg, np.random.default_rng(seed))
    a, b = answers(lite), answers(pg)
    assert a == b, f"seed {seed}"
    assert a["exceeding"] and len(a["exceeding_all"]) > len(a["exceeding"])  # the query had something to find
    for run_id, cols in written.items():
        got = pg.samples(run_id, "tracker")
        np.testing.assert_array_equal(got["t"], cols["t"])
        np.testing.assert_array_equal(got["x"], cols["x"])
    # the exports are the same files
    lite.export("SN-3-2", tmp_path / "a")
    pg.export("SN-3-2", tmp_path / "b")
    for f in ("samples_tracker.csv", "characteristics.csv"):
        assert (tmp_path / "a" / f).read_text() == (tmp_path / "b" / f).read_text()
    lite.close(), pg.close()


def test_a_store_of_the_previous_schema_upgrades_in_place(rng, tmp_path):
    path = tmp_path / "old.sqlite"
    db = sqlite3.connect(path)
    db.executescript(V1_SCHEMA)
    data = rng.normal(size=(30, 2))
    db.execute("INSERT INTO robots VALUES (1, 'rb5-850', 'SN-OLD')")
    db.execute("INSERT INTO runs VALUES ('old-1', 1, 'iso9283', 'after', '{}', '{}', 'done', 1.0e9, 1.0e9)")
    db.execute("INSERT INTO steps VALUES ('old-1', 0, 1, 'measure', 'done', 1.0e9, 1.0e9, NULL, NULL)")
    db.execute("INSERT INTO sample_batches VALUES ('old-1', 'tracker', 0, 1, 0, 30, '[\"t\", \"x\"]', ?, 1.0e9)",
               (data.astype("<f8").tobytes(),))
    value = float(rng.uniform(0.6, 0.9))
    db.execute("INSERT INTO characteristics VALUES ('old-1', 'P1', 'RP_mm', ?, 'mm', 0.5, 0)", (value,))
    db.commit()
    db.close()
    store = RunStore(path, station="cell-7")
    assert store.schema_version() == SCHEMA_VERSION == 3
    assert store.run("old-1").station is None and store.run("old-1").serial == "SN-OLD"
    np.testing.assert_array_equal(store.samples("old-1", "tracker")["x"], data[:, 1])
    assert [o["value"] for o in store.robots_exceeding("RP_mm")] == [value]
    store.create_run("new-1", "iso9283", model="rb5-850", serial="SN-OLD", overhaul_state="in-service",
                     config={}, params={})
    assert store.run("new-1").station == "cell-7"
    store.close()
    assert RunStore(path).schema_version() == SCHEMA_VERSION  # opening again changes nothing


def _set_version(path, version):
    db = sqlite3.connect(path)
    db.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(version),))
    db.commit()
    db.close()


def test_a_store_another_connection_is_writing_opens_once_that_write_is_done(rng, tmp_path):
    """Two station processes open a new store at once (a soak run: the web hub's run and the page's reader):
    while one holds a write transaction, SQLite refuses the other's switch to WAL at once, without waiting.
    The store waits for the write instead of calling the file unusable."""
    path = tmp_path / "s.sqlite"
    other = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False)
    other.execute("BEGIN IMMEDIATE")  # the other process has just begun to make the new store
    hold_s = float(rng.uniform(0.05, 0.3))
    timer = threading.Timer(hold_s, lambda: other.execute("COMMIT"))
    timer.start()
    try:
        t0 = time.monotonic()
        with RunStore(path) as store:
            assert store.runs() == []
        assert time.monotonic() - t0 >= hold_s - 0.01  # it did wait for the other's write
    finally:
        timer.join()
        other.close()
    assert sqlite3.connect(str(path)).execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_a_store_newer_than_the_code_is_refused(tmp_path, pg_url):
    RunStore(tmp_path / "s.sqlite").close()
    _set_version(tmp_path / "s.sqlite", SCHEMA_VERSION + 1)
    with pytest.raises(StoreVersionError, match=f"schema version {SCHEMA_VERSION + 1} is newer than this station's"):
        RunStore(tmp_path / "s.sqlite")
    store = RunStore(pg_url)
    store.backend.execute("UPDATE meta SET value='7' WHERE key='schema_version'")
    store.close()
    with pytest.raises(StoreVersionError, match="schema version 7 is newer"):
        RunStore(pg_url)


def test_a_database_that_is_not_a_station_store_is_refused(tmp_path, pg_url):
    db = sqlite3.connect(tmp_path / "other.sqlite")
    db.execute("CREATE TABLE invoices (id INTEGER)")
    db.commit()
    db.close()
    with pytest.raises(StoreVersionError, match="not a station store.*invoices"):
        RunStore(tmp_path / "other.sqlite")
    with psycopg.connect(**parse_pg_url(pg_url).connect_kwargs(), autocommit=True) as conn:
        conn.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        conn.execute("INSERT INTO meta VALUES ('application', 'someone-else')")
    with pytest.raises(StoreVersionError, match="not a station store.*someone-else"):
        RunStore(pg_url)


def test_wrong_password_and_unreachable_server_are_clear_and_name_no_secret(pg_server, monkeypatch, tmp_path):
    monkeypatch.setenv("WRONG_PW", "not-the-password-xyzzy")
    url = f"postgresql://station@127.0.0.1:{pg_server.port}/postgres?password_env=WRONG_PW"
    with pytest.raises(StoreUnavailable, match="password authentication failed") as info:
        RunStore(url)
    assert "xyzzy" not in str(info.value) and "password_env" not in str(info.value)
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(StoreUnavailable, match=f"127.0.0.1:{port}/postgres: cannot connect"):
        RunStore(f"postgresql://station@127.0.0.1:{port}/postgres", connect_timeout_s=2)
    pwfile = tmp_path / "pw"
    pwfile.write_text(pg_server.password + "\n")
    url = pg_server.create_db().split("?")[0] + f"?password_file={pwfile}"
    RunStore(url).close()  # the password from a file works as well


def test_a_server_older_than_the_schema_needs_is_refused(pg_url, monkeypatch):
    monkeypatch.setattr(backends, "MIN_SERVER_VERSION", 10 ** 7)
    with pytest.raises(StoreError, match="older than the 10000000 this station needs"):
        RunStore(pg_url)


@pytest.mark.parametrize("url, msg", [
    ("postgresql://station:secret@h/db", "password in the URL is refused"),
    ("postgresql://station@h/db?password=secret", "password in the URL is refused"),
    ("postgresql://station@h/", "must name one database"),
    ("postgresql://station@h/db?password_env=A&password_file=B", "not both"),
    ("postgresql://station@h/db?sslmodes=require", "unknown parameter 'sslmodes'"),
])
def test_bad_store_urls_are_refused_by_the_config(url, msg):
    from station.config import config_from_dict
    from station.errors import ConfigError

    with pytest.raises(ConfigError, match=f"station.store_url: .*{msg}") as info:
        config_from_dict({"station": {"name": "a", "store_url": url}, "devices": {}})
    assert "secret" not in str(info.value)
