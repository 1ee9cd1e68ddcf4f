"""A simulated fleet with hidden drift, for the fleet tests and bench/bench_store.py.

Each robot has a level drawn at random; before its overhaul it is worn
(level + ``wear_mm``); from the run after the overhaul on, a drifting robot's
RP grows by ``slope_mm_per_year``. The overhaul is recorded as an event
(between the last worn run and the first run after it); each run's
``overhaul_state`` label is the one its station's config gave, which says
nothing reliable about when the overhaul was. Runs are a couple of weeks apart, made at
stations drawn at random. Five poses per run, each level + N(0, noise_mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.fleet.questions import YEAR_S

POSES = ("P1", "P2", "P3", "P4", "P5")
LIMIT_MM = 0.5


@dataclass
class Fleet:
    runs: list[dict] = field(default_factory=list)
    drifting: set[str] = field(default_factory=set)
    high: set[str] = field(default_factory=set)
    #: recorded overhauls: model, serial, at (epoch s), what
    overhauls: list[dict] = field(default_factory=list)


def make_fleet(rng, n_robots: int, runs_per_robot: int, *, models=("industrial-3100", "rb5-850"),
               stations=("cell-1", "cell-2", "cell-3"), drift_share: float = 0.2, high_share: float = 0.1,
               noise_mm: float = 0.02, wear_mm: float = 0.3, t0: float = 1.7e9) -> Fleet:
    fleet = Fleet()
    # each model's robots get their shares of drifting and high ones, at least one of each, in a random order
    # (drawn independently per robot, 60 robots had none high in about 1 draw of 550: CI seed 1716006017)
    kind = np.empty(n_robots, dtype=object)
    for m in range(len(models)):
        idx = np.arange(m, n_robots, len(models))
        n_d = max(1, round(drift_share * idx.size))
        n_h = max(1, round(high_share * idx.size))
        kind[idx] = rng.permutation(np.array(["drift"] * n_d + ["high"] * n_h + ["steady"] * (idx.size - n_d - n_h),
                                             dtype=object))
    for i in range(n_robots):
        serial = f"SN-{i:05d}"
        model = models[i % len(models)]
        drifts = kind[i] == "drift"
        high = kind[i] == "high"
        level = 0.6 + rng.uniform(0, 0.1) if high else rng.uniform(0.1, 0.3)
        slope = rng.uniform(0.4, 0.8) if drifts else 0.0
        if drifts:
            fleet.drifting.add(serial)
        if high:
            fleet.high.add(serial)
        overhaul = int(rng.integers(1, max(2, runs_per_robot // 3)))  # index of the first run after overhaul
        t = t0 + np.cumsum(rng.uniform(10, 18, runs_per_robot)) * 86400.0
        fleet.overhauls.append({"model": model, "serial": serial, "at": float(t[overhaul - 1] + t[overhaul]) / 2,
                                "what": "gearboxes J2, J3 replaced"})
        for k in range(runs_per_robot):
            # the label as the README's config gives it: the same on every run
            state = "after"
            if k < overhaul:
                base = level + wear_mm
            else:
                base = level + slope * (t[k] - t[overhaul]) / YEAR_S
            values = base + rng.normal(0, noise_mm, len(POSES))
            fleet.runs.append({"run_id": f"{serial}-{k:03d}", "serial": serial, "model": model,
                               "station": stations[int(rng.integers(len(stations)))], "created_at": float(t[k]),
                               "overhaul_state": state, "values": values})
    return fleet


def load_fleet(store, fleet: Fleet) -> None:
    """Bulk-load the fleet's finished runs and RP characteristics (COPY on PostgreSQL)."""
    robot_ids = {}
    for r in fleet.runs:
        if (r["model"], r["serial"]) not in robot_ids:
            robot_ids[(r["model"], r["serial"])] = store.robot_id(r["model"], r["serial"])
    runs = [(r["run_id"], robot_ids[(r["model"], r["serial"])], "iso9283", r["overhaul_state"], "{}", "{}", "done", r["created_at"],
             r["created_at"] + 3600.0, r["station"]) for r in fleet.runs]
    chars = [(r["run_id"], p, "RP_mm", float(v), "mm", LIMIT_MM, int(v <= LIMIT_MM))
             for r in fleet.runs for p, v in zip(POSES, r["values"])]
    run_cols = "run_id, robot_id, procedure, overhaul_state, config_json, params_json, status, created_at, finished_at, station"
    char_cols = "run_id, pose, name, value, unit, limit_value, passed"
    for o in fleet.overhauls:
        store.record_overhaul(o["model"], o["serial"], o["at"], o["what"])
    with store.backend.transaction() as cur:
        if store.dialect == "postgresql":
            for table, cols, rows in (("runs", run_cols, runs), ("characteristics", char_cols, chars)):
                with cur.raw.copy(f"COPY {table} ({cols}) FROM STDIN") as copy:
                    for row in rows:
                        copy.write_row(row)
            cur.execute("ANALYZE runs")
            cur.execute("ANALYZE characteristics")
        else:
            cur.raw.executemany(f"INSERT INTO runs ({run_cols}) VALUES ({','.join('?' * 10)})", runs)
            cur.raw.executemany(f"INSERT INTO characteristics ({char_cols}) VALUES ({','.join('?' * 7)})", chars)


def worst(run: dict) -> float:
    return float(np.max(run["values"]))


__all__ = ["Fleet", "make_fleet", "load_fleet", "worst", "LIMIT_MM", "POSES"]
