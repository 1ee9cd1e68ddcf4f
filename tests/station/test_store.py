import csv
import sqlite3

import numpy as np
import pyarrow.parquet as pq
import pytest

from station.errors import DataError
from station.store import RunStore, StoreError


def _run(store, run_id, serial, state, rp_values, limit=0.5, status="done"):
    store.create_run(run_id, "iso9283", model="industrial-3100", serial=serial, overhaul_state=state, config={}, params={})
    store.put_characteristics(
        run_id,
        [{"pose": p, "name": "RP_mm", "value": v, "unit": "mm", "limit": limit, "passed": v <= limit}
         for p, v in rp_values.items()],
    )
    store.set_run_status(run_id, status)


def test_history_before_and_after_overhaul_and_exceeding_query(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _run(store, "a1", "SN-A", "before", {"P1": 0.71, "P2": 0.40})
    _run(store, "a2", "SN-A", "after", {"P1": 0.21, "P2": 0.18})
    _run(store, "b1", "SN-B", "after", {"P1": 0.62, "P2": 0.30})
    _run(store, "c1", "SN-C", "after", {"P1": 0.90}, status="failed")  # unfinished runs do not count
    hist = store.history("SN-A", "RP_mm", pose="P1")
    assert [(h["overhaul_state"], h["value"]) for h in hist] == [("before", 0.71), ("after", 0.21)]
    over = store.robots_exceeding("RP_mm")
    assert [(o["serial"], o["pose"]) for o in over] == [("SN-B", "P1")]
    over_all = store.robots_exceeding("RP_mm", latest_only=False)
    assert {(o["serial"], o["run_id"]) for o in over_all} == {("SN-A", "a1"), ("SN-B", "b1")}


def test_samples_round_trip_and_bad_batches_refused(rng, tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    store.create_run("r", "p", model=None, serial=None, overhaul_state=None, config={}, params={})
    t = np.sort(rng.uniform(0, 10, 257))
    xyz = rng.normal(size=(257, 3)) * 1000
    att = store.step_started("r", 0, "s")
    store.append_samples("r", "tracker", 0, att, {"t": t[:100], "x": xyz[:100, 0], "y": xyz[:100, 1], "z": xyz[:100, 2]})
    store.append_samples("r", "tracker", 0, att, {"t": t[100:], "x": xyz[100:, 0], "y": xyz[100:, 1], "z": xyz[100:, 2]})
    assert store.samples("r", "tracker") == {}  # step not done yet
    store.step_ended("r", 0, att, "done", {"ok": True})
    got = store.samples("r", "tracker")
    np.testing.assert_array_equal(got["t"], t)
    np.testing.assert_array_equal(np.column_stack([got["x"], got["y"], got["z"]]), xyz)
    with pytest.raises(DataError, match="column 'x' has 3 values, expected 4"):
        store.append_samples("r", "tracker", 0, att, {"t": np.zeros(4), "x": np.zeros(3)})
    with pytest.raises(StoreError, match="no run 'nope'"):
        store.run("nope")
    with pytest.raises(StoreError, match="already exists"):
        store.create_run("r", "p", model=None, serial=None, overhaul_state=None, config={}, params={})


def test_export_csv_and_parquet(tmp_path):
    store = RunStore(tmp_path / "s.sqlite")
    _run(store, "a1", "SN-A", "before", {"P1": 0.3})
    att = store.step_started("a1", 0, "measure")
    store.append_samples("a1", "tracker", 0, att, {"t": [0.0, 0.001], "x": [1.5, 2.5], "y": [0, 0], "z": [3, 4]})
    store.step_ended("a1", 0, att, "done")
    paths = store.export("a1", tmp_path / "csv", "csv")
    rows = list(csv.DictReader(open(tmp_path / "csv" / "samples_tracker.csv")))
    assert [float(r["x"]) for r in rows] == [1.5, 2.5]
    assert {p.name for p in paths} == {"samples_tracker.csv", "steps.csv", "characteristics.csv"}
    store.export("a1", tmp_path / "pq", "parquet")
    table = pq.read_table(tmp_path / "pq" / "samples_tracker.parquet")
    assert table.column("z").to_pylist() == [3.0, 4.0]
    with pytest.raises(StoreError, match="format"):
        store.export("a1", tmp_path / "x", "xlsx")


def test_store_file_is_in_wal_mode(tmp_path):
    RunStore(tmp_path / "s.sqlite").close()
    db = sqlite3.connect(tmp_path / "s.sqlite")
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_not_a_database_refused(tmp_path):
    bad = tmp_path / "bad.sqlite"
    bad.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StoreError, match="not a usable station store"):
        RunStore(bad)


def test_run_state_machine_is_enforced_from_its_table(tmp_path):
    from station.errors import RunStateError
    from station.store import RUN_TRANSITIONS

    store = RunStore(tmp_path / "s.sqlite")
    # every (from, to) pair of states: allowed exactly when the table says so
    for i, (src, allowed) in enumerate(RUN_TRANSITIONS.items()):
        for dst in RUN_TRANSITIONS:
            run_id = f"r{i}-{dst}"
            store.create_run(run_id, "p", model=None, serial=None, overhaul_state=None, config={}, params={})
            path = {"running": [], "failed": ["failed"], "aborted": ["aborted"], "done": ["done"]}[src]
            for s in path:
                store.set_run_status(run_id, s)
            assert store.run(run_id).status == src
            if dst in allowed:
                store.set_run_status(run_id, dst)
                assert store.run(run_id).status == dst
            else:
                with pytest.raises(RunStateError, match=f"is {src}; it cannot become {dst}"):
                    store.set_run_status(run_id, dst)
                assert store.run(run_id).status == src
    with pytest.raises(RunStateError, match="unknown status 'finished'"):
        store.set_run_status("r0-done", "finished")
    with pytest.raises(StoreError, match="no run"):
        store.set_run_status("nope", "done")
