"""The store's logical schema, its version and the migrations between versions.

One schema for both backends, written once with three dialect words
(``{PK}`` an auto-numbered integer key, ``{BLOB}`` bytes, ``{REAL}`` a
float64). Version 1 is the schema of the first stations (SQLite files
written by them open and upgrade in place); every later version is a list of
statements in :data:`MIGRATIONS`. A store is always built the same way:
version 1, then each migration in order, each in its own transaction with
the version bump, so a fresh store and an upgraded one are the same.

Version 2 adds:

* ``runs.station``: which station made a run (runs of many stations meet
  in a central store);
* ``forwarded_batches`` and ``forward_state``: what of a local run has
  reached the central store (store-and-forward, idempotent by run, stream,
  step, attempt and batch);
* ``reanalyses``: results of re-running the analysis on archived samples,
  kept beside the originals under the analysis version;
* ``runs_by_robot``: index for the fleet queries;
* ``meta.application``: what marks a database as a station store.

Version 3 adds ``overhauls``: an overhaul is an event in a robot's life
(when, what was done, the work ticket, where it was recorded), not a
property of each run; since-overhaul figures and drift are computed from
these events (:mod:`station.fleet.questions`). Runs keep their ``overhaul_state``
label as it was configured.
"""

from __future__ import annotations

SCHEMA_VERSION = 3
APPLICATION = "robot-metrology-station"

DIALECTS = {
    "sqlite": {"PK": "INTEGER PRIMARY KEY", "BLOB": "BLOB", "REAL": "REAL"},
    "postgresql": {"PK": "BIGSERIAL PRIMARY KEY", "BLOB": "BYTEA", "REAL": "DOUBLE PRECISION"},
}

#: version 1, as the first stations wrote it (SQLite text identical once the dialect words are filled in)
BASE = [
    "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    """CREATE TABLE IF NOT EXISTS robots (
    robot_id {PK},
    model TEXT NOT NULL,
    serial TEXT NOT NULL,
    UNIQUE (model, serial)
)""",
    """CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    robot_id INTEGER REFERENCES robots(robot_id),
    procedure TEXT NOT NULL,
    overhaul_state TEXT,
    config_json TEXT NOT NULL,
    params_json TEXT NOT NULL,
    status TEXT NOT NULL,
    created_at {REAL} NOT NULL,
    finished_at {REAL}
)""",
    """CREATE TABLE IF NOT EXISTS steps (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    idx INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    name TEXT NOT NULL,
    status TEXT NOT NULL,
    started_at {REAL} NOT NULL,
    ended_at {REAL},
    output_json TEXT,
    message TEXT,
    PRIMARY KEY (run_id, idx, attempt)
)""",
    """CREATE TABLE IF NOT EXISTS sample_batches (
    run_id TEXT NOT NULL,
    stream TEXT NOT NULL,
    step_idx INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    batch_no INTEGER NOT NULL,
    n INTEGER NOT NULL,
    columns TEXT NOT NULL,
    data {BLOB} NOT NULL,
    committed_at {REAL} NOT NULL,
    PRIMARY KEY (run_id, stream, step_idx, attempt, batch_no)
)""",
    """CREATE TABLE IF NOT EXISTS results (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    key TEXT NOT NULL,
    value_json TEXT NOT NULL,
    PRIMARY KEY (run_id, key)
)""",
    """CREATE TABLE IF NOT EXISTS characteristics (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    pose TEXT NOT NULL,
    name TEXT NOT NULL,
    value {REAL},
    unit TEXT NOT NULL,
    limit_value {REAL},
    passed INTEGER,
    PRIMARY KEY (run_id, pose, name)
)""",
    "CREATE INDEX IF NOT EXISTS characteristics_by_name ON characteristics (name, pose)",
]

#: statements that take a store from version ``v - 1`` to ``v``; per dialect where they differ
MIGRATIONS: dict[int, dict[str, list[str]]] = {
    2: {
        "common": [
            "ALTER TABLE runs ADD COLUMN station TEXT",
            """CREATE TABLE IF NOT EXISTS forwarded_batches (
    run_id TEXT NOT NULL,
    stream TEXT NOT NULL,
    step_idx INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    batch_no INTEGER NOT NULL,
    PRIMARY KEY (run_id, stream, step_idx, attempt, batch_no)
)""",
            """CREATE TABLE IF NOT EXISTS forward_state (
    run_id TEXT PRIMARY KEY,
    status_pushed TEXT,
    batches_pushed INTEGER NOT NULL DEFAULT 0,
    pushed_at {REAL},
    last_error TEXT
)""",
            """CREATE TABLE IF NOT EXISTS reanalyses (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    key TEXT NOT NULL,
    analysis_version TEXT NOT NULL,
    value_json TEXT NOT NULL,
    created_at {REAL} NOT NULL,
    PRIMARY KEY (run_id, key, analysis_version)
)""",
            "CREATE INDEX IF NOT EXISTS runs_by_robot ON runs (robot_id, created_at)",
            "INSERT INTO meta(key, value) VALUES ('application', '" + APPLICATION + "') ON CONFLICT DO NOTHING",
        ],
        # raw float samples do not compress: store them out of line, uncompressed
        "postgresql": ["ALTER TABLE sample_batches ALTER COLUMN data SET STORAGE EXTERNAL"],
    },
    3: {
        "common": [
            """CREATE TABLE IF NOT EXISTS overhauls (
    robot_id INTEGER NOT NULL REFERENCES robots(robot_id),
    at {REAL} NOT NULL,
    what TEXT NOT NULL,
    ticket TEXT,
    station TEXT,
    recorded_at {REAL} NOT NULL,
    PRIMARY KEY (robot_id, at)
)""",
        ],
    },
}


def statements(dialect: str, texts: list[str]) -> list[str]:
    words = DIALECTS[dialect]
    return [t.format(**words) for t in texts]


def migration(dialect: str, version: int) -> list[str]:
    step = MIGRATIONS[version]
    return statements(dialect, step.get("common", []) + step.get(dialect, []))
