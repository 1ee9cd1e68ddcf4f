"""Local station stores with random runs, and their configs, for the store tests."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from station.store import RunStore


def station_config(tmp_path: Path, name: str, central_url: str | None) -> Path:
    cfg = {"station": {"name": name, "store_path": f"{name}.sqlite", "report_dir": "reports"}, "devices": {}}
    if central_url:
        cfg["station"]["store_url"] = central_url
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(cfg))
    return path


def add_run(store: RunStore, run_id: str, serial: str, rng, *, batches: int, per_batch: int = 100,
            status: str | None = "done", model: str = "industrial-3100", state: str = "after") -> None:
    """A run with one step of ``batches`` random sample batches and an RP characteristic."""
    store.create_run(run_id, "iso9283", model=model, serial=serial, overhaul_state=state,
                     config={"station": {"store_url": "postgresql://station@db/plant?password_env=PW"}}, params={})
    att = store.step_started(run_id, 0, "measure")
    for _ in range(batches):
        store.append_samples(run_id, "tracker", 0, att, {c: rng.normal(size=per_batch) for c in ("t", "x", "y", "z")})
    if status is None:
        return
    store.step_ended(run_id, 0, att, "done")
    store.put_characteristics(run_id, [{"pose": "P1", "name": "RP_mm", "value": float(rng.uniform(0.1, 0.9)),
                                        "unit": "mm", "limit": 0.5, "passed": None}])
    store.put_result(run_id, "iso9283", {"n": batches})
    store.set_run_status(run_id, status)


def central_batches(central: RunStore, run_id: str) -> int:
    return central.backend.query("SELECT COUNT(*) FROM sample_batches WHERE run_id=?", (run_id,))[0][0]


def same_samples(local: RunStore, central: RunStore, run_id: str) -> None:
    a = local.samples(run_id, "tracker", finished_only=False)
    b = central.samples(run_id, "tracker", finished_only=False)
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def station_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "app.cli", *args]


def popen(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen(station_cmd(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ), **kw)
