"""Overhauls are events in a robot's life: since-overhaul figures and drift count from the last one.

A few robots are measured every week or two over simulated months, every
run labelled ``overhaul_state = "after"`` as the README's config does. One
robot drifts slowly after its overhaul; another drifted before its last
overhaul and is steady since; one has no overhaul recorded. Levels, noise,
dates and the drifting robot are drawn at random; the drift is set from the
noise so that its trend test is decisive (t-statistic over 10: its p was
below 1e-10 in 400 draws), and the false-discovery rate is set so that a
steady robot is flagged about once in ten million draws (at 1e-3, one of
the six steady robots' p-values in a CI run fell under it, p = 4.2e-4).
"""

import numpy as np
import pytest

from app.cli import main
from station.fleet.questions import YEAR_S, drifting, robot_history, since_overhaul
from station.fleet.page import fleet_report
from station.store import RunStore, StoreError
from station.store.forward import push
from tests.store.fleetgen import POSES, Fleet, load_fleet
from tests.store.helpers import station_config

Q = 1e-7


def _months(rng, n_robots=6) -> tuple[Fleet, dict]:
    """Runs of ``n_robots`` robots over ~8 months; returns the fleet and what is true of it."""
    fleet = Fleet()
    t0 = 1.75e9
    noise = rng.uniform(0.005, 0.02)
    drifter, before, unrecorded = (f"R-{i}" for i in rng.choice(n_robots, 3, replace=False))
    truth = {"drifter": drifter, "before": before, "unrecorded": unrecorded, "last_overhaul": {}}
    for i in range(n_robots):
        serial, model = f"R-{i}", ("ur5e", "industrial-3100")[i % 2]
        t = t0 + np.cumsum(rng.uniform(6, 12, 26)) * 86400.0
        k_ovh = int(rng.integers(8, 14))  # first run after the last overhaul
        at = float(t[k_ovh - 1] + t[k_ovh]) / 2
        level = rng.uniform(0.05, 0.2)
        span = (t[-1] - t[k_ovh]) / YEAR_S
        # a slope whose rise over the runs since is 20 noise sigmas: the t-statistic is well over 10
        slope = 20 * noise / span
        if serial != unrecorded:
            fleet.overhauls.append({"model": model, "serial": serial, "at": at, "what": "J2 gearbox replaced"})
            truth["last_overhaul"][serial] = at
        if serial == before:  # an older overhaul too: only the last one counts
            fleet.overhauls.append({"model": model, "serial": serial, "at": float(t[2] + t[3]) / 2, "what": "J5 belt"})
        for k in range(t.size):
            value = level
            if serial == drifter and k >= k_ovh:
                value += slope * (t[k] - t[k_ovh]) / YEAR_S
            if serial == before and k < k_ovh:  # worn and getting worse until its overhaul
                value += 0.1 + slope * (t[k] - t[0]) / YEAR_S
            fleet.runs.append({"run_id": f"{serial}-{k:03d}", "serial": serial, "model": model,
                               "station": "cell-7", "created_at": float(t[k]), "overhaul_state": "after",
                               "values": value + rng.normal(0, noise, len(POSES))})
    return fleet, truth


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request, tmp_path):
    if request.param == "sqlite":
        s = RunStore(tmp_path / "s.sqlite")
    else:
        s = RunStore(request.getfixturevalue("pg_url"))
    yield s
    s.close()


def test_since_overhaul_and_drift_count_from_the_recorded_overhaul(store, test_seed):
    seed = test_seed
    fleet, truth = _months(np.random.default_rng(seed))
    load_fleet(store, fleet)
    why = f"(test seed {seed}; --seed replays the session)"
    rows = {r["serial"]: r for r in since_overhaul(store, "RP_mm")}
    by_serial = {}
    for r in fleet.runs:
        by_serial.setdefault(r["serial"], []).append(r)
    for serial, runs in by_serial.items():
        at = truth["last_overhaul"].get(serial)
        since = [r for r in runs if at is None or r["created_at"] >= at]
        row = rows[serial]
        assert row["baseline_run"] == since[0]["run_id"], why
        assert row["runs_since"] == len(since), why
        assert row["change"] == pytest.approx(max(since[-1]["values"]) - max(since[0]["values"]), abs=1e-12), why
        assert row["overhaul_at"] == (pytest.approx(at) if at is not None else None), why
    found = {d["serial"] for d in drifting(store, "RP_mm", q_max=Q)}
    assert found == {truth["drifter"]}, why
    # the robot that wore out before its overhaul would drift if counted over all its runs
    assert rows[truth["before"]]["runs_since"] < len(by_serial[truth["before"]])


def test_history_marks_the_runs_since_the_last_overhaul(store, test_seed):
    seed = test_seed
    fleet, truth = _months(np.random.default_rng(seed))
    load_fleet(store, fleet)
    serial = truth["drifter"]
    h = robot_history(store, serial, "RP_mm", pose="P1")
    at = truth["last_overhaul"][serial]
    assert [x["since_overhaul"] for x in h] == [x["created_at"] >= at for x in h]


def test_an_overhaul_from_the_command_line_reaches_the_fleet_and_the_centre(tmp_path, pg_url, capsys, test_seed):
    seed = test_seed
    fleet, truth = _months(np.random.default_rng(seed))
    recorded = fleet.overhauls
    fleet.overhauls = []  # nothing recorded yet: the plant records them with the command
    from tests.store.pgserver import PASSWORD_ENV

    cfg = station_config(tmp_path, "cell-7", pg_url + f"?password_env={PASSWORD_ENV}")
    local_path = tmp_path / "cell-7.sqlite"
    with RunStore(local_path, station="cell-7") as local:
        load_fleet(local, fleet)
    import time

    for o in recorded:
        when = time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(o["at"]))
        assert main(["store", "overhaul", "--config", str(cfg), "--serial", o["serial"], "--date", when,
                     "--what", o["what"], "--ticket", "WO-1"]) == 0
    out = capsys.readouterr().out
    assert out.count("recorded") == len(recorded)
    assert main(["store", "overhauls", "--config", str(cfg), "--json"]) == 0
    capsys.readouterr()
    with RunStore(local_path) as local:
        found = {d["serial"] for d in drifting(local, "RP_mm", q_max=Q)}
        assert found == {truth["drifter"]}, f"test seed {seed}"
        with RunStore(pg_url, station="cell-7") as central:
            report = push(local, central, station="cell-7")
            assert report.overhauls_sent == len(recorded)
            assert push(local, central, station="cell-7").overhauls_sent == 0  # once
            assert {d["serial"] for d in drifting(central, "RP_mm", q_max=Q)} == {truth["drifter"]}
            # a re-analysis made after its run reached the centre follows it there, once
            run_id = fleet.runs[0]["run_id"]
            local.put_reanalysis(run_id, "iso9283", "0.1.0+test", {"RP_mm": 0.123})
            assert push(local, central, station="cell-7").reanalyses_sent == 1
            assert push(local, central, station="cell-7").reanalyses_sent == 0
            assert central.reanalyses(run_id) == {"0.1.0+test": {"iso9283": {"RP_mm": 0.123}}}
    # dates must be dates
    assert main(["store", "overhaul", "--config", str(cfg), "--serial", "R-0", "--date", "yesterday",
                 "--what", "x"]) == 2
    assert "not YYYY-MM-DD" in capsys.readouterr().err


def test_a_robot_is_its_model_and_serial(tmp_path):
    with RunStore(tmp_path / "s.sqlite") as store:
        fleet = Fleet(runs=[
            {"run_id": f"{m}-{k}", "serial": "SN-1", "model": m, "station": "c", "created_at": 1.7e9 + k * 86400.0,
             "overhaul_state": "after", "values": np.full(len(POSES), v)}
            for m, v in (("ur5e", 0.1), ("ur10e", 0.3)) for k in range(3)])
        load_fleet(store, fleet)
        with pytest.raises(StoreError, match="2 models"):
            store.history("SN-1", "RP_mm")
        with pytest.raises(StoreError, match="2 models"):
            robot_history(store, "SN-1", "RP_mm")
        assert {r["value"] for r in store.history("SN-1", "RP_mm", model="ur10e")} == {0.3}
        rows = since_overhaul(store, "RP_mm")
        assert sorted((r["model"], r["serial"], r["runs_since"]) for r in rows) == \
            [("ur10e", "SN-1", 3), ("ur5e", "SN-1", 3)]
        assert store.history("NOPE", "RP_mm") == []  # no such robot: no history (the command says so)


def test_the_fleet_page_judges_every_robot_against_its_limit(tmp_path, test_seed):
    rng = np.random.default_rng(test_seed)
    fleet, truth = _months(rng)
    with RunStore(tmp_path / "s.sqlite") as store:
        load_fleet(store, fleet)  # every characteristic carries the fleet's limit
        rep = fleet_report(store, "RP_mm")
    assert rep.verdict in ("PASS", "FAIL")
    assert len(rep.rows) >= len({r["serial"] for r in fleet.runs})
    assert all(r["limit"] is not None for r in rep.rows)
