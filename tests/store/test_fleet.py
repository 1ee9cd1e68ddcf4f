"""Fleet questions: history across stations, change since overhaul, over limits now, drift by a trend test."""

import copy
import json

import numpy as np
import pytest

from app.cli import main
from station.fleet.questions import drifting, over_limits_now, robot_history, since_overhaul
from station.fleet.trend import benjamini_hochberg, trends
from station.store import RunStore
from tests.store.fleetgen import LIMIT_MM, load_fleet, make_fleet, worst
from tests.store.helpers import station_config


@pytest.fixture
def fleet_stores(rng, tmp_path, pg_url):
    fleet = make_fleet(rng, n_robots=60, runs_per_robot=14)
    stores = [RunStore(tmp_path / "fleet.sqlite"), RunStore(pg_url)]
    for s in stores:
        load_fleet(s, fleet)
    yield fleet, stores
    for s in stores:
        s.close()


def test_drifting_robots_are_found_by_the_trend_not_by_the_level(fleet_stores, tmp_path):
    fleet, stores = fleet_stores
    assert fleet.drifting and fleet.high  # the draw has both kinds
    for store in stores:
        found = {d["serial"] for d in drifting(store, "RP_mm", q_max=0.01)}
        assert fleet.drifting <= found, f"missed {sorted(fleet.drifting - found)}"
        assert len(found - fleet.drifting) <= 2, f"false flags {sorted(found - fleet.drifting)}"
    # over the limit but steady is not drifting: a high robot is flagged only as any steady one is, by its
    # scatter; brought down to the others' level, every robot's test and the answer are the same
    lowered = copy.deepcopy(fleet)
    for r in lowered.runs:
        if r["serial"] in fleet.high:
            r["values"] = r["values"] - 0.5
    low_store = RunStore(tmp_path / "lowered.sqlite")
    load_fleet(low_store, lowered)
    try:
        before = {r["serial"]: r["p_increase"] for r in since_overhaul(stores[0], "RP_mm")}
        after = {r["serial"]: r["p_increase"] for r in since_overhaul(low_store, "RP_mm")}
        assert after.keys() == before.keys()
        np.testing.assert_allclose([after[k] for k in sorted(before)], [before[k] for k in sorted(before)],
                                   rtol=1e-9, atol=1e-15)
        assert [d["serial"] for d in drifting(low_store, "RP_mm", q_max=0.01)] == \
               [d["serial"] for d in drifting(stores[0], "RP_mm", q_max=0.01)]
        assert all(worst(r) > LIMIT_MM for r in fleet.runs if r["serial"] in fleet.high)  # they were high
    finally:
        low_store.close()
    # per model: only that model's robots
    one = {d["serial"] for d in drifting(stores[0], "RP_mm", model="rb5-850", q_max=0.01)}
    assert one and all(int(s[3:]) % 2 == 1 for s in one)


def test_change_since_overhaul_and_over_limits_now_match_the_fleet(fleet_stores):
    fleet, stores = fleet_stores
    by_serial = {}
    for r in fleet.runs:
        by_serial.setdefault(r["serial"], []).append(r)
    overhaul_at = {o["serial"]: o["at"] for o in fleet.overhauls}
    expect_over = {s for s, rr in by_serial.items() if worst(rr[-1]) > LIMIT_MM}
    answers = []
    for store in stores:
        rows = {r["serial"]: r for r in since_overhaul(store, "RP_mm")}
        for s, rr in by_serial.items():
            base = [r for r in rr if r["created_at"] >= overhaul_at[s]][0]
            assert rows[s]["baseline_run"] == base["run_id"]
            assert rows[s]["change"] == pytest.approx(worst(rr[-1]) - worst(base), abs=1e-12)
            assert rows[s]["runs_since"] == len(rr) - rr.index(base)
        over = over_limits_now(store, "RP_mm")
        assert {o["serial"] for o in over} == expect_over
        assert all(o["value"] > LIMIT_MM for o in over)
        answers.append((sorted((k, v["change"], v["p_increase"]) for k, v in rows.items()), over))
    a, b = answers
    assert [x[:2] for x in a[0]] == [x[:2] for x in b[0]]
    np.testing.assert_allclose([x[2] for x in a[0]], [x[2] for x in b[0]], rtol=1e-9)
    assert [(o["serial"], o["pose"]) for o in a[1]] == [(o["serial"], o["pose"]) for o in b[1]]


def test_history_of_one_robot_across_stations_and_overhauls(fleet_stores):
    fleet, stores = fleet_stores
    serial = fleet.runs[0]["serial"]
    mine = [r for r in fleet.runs if r["serial"] == serial]
    for store in stores:
        h = robot_history(store, serial, "RP_mm", pose="P3")
        assert [(x["run_id"], x["station"], x["overhaul_state"]) for x in h] == \
               [(r["run_id"], r["station"], r["overhaul_state"]) for r in mine]
        np.testing.assert_allclose([x["value"] for x in h], [r["values"][2] for r in mine])


def test_trend_test_against_scipy_and_false_discovery_control(rng):
    from scipy import stats

    g = np.repeat(np.arange(200), 12)
    t = np.tile(np.linspace(0, 2, 12), 200) + rng.uniform(-0.05, 0.05, g.size)
    slope_true = np.where(np.arange(200) < 40, 0.5, 0.0)  # 1 noise sigma per 0.2 time units: t-statistic ~ 20
    y = slope_true[g] * t + rng.normal(0, 0.1, g.size)
    tr = trends(g, t, y)
    for k in rng.choice(200, 5, replace=False):
        ref = stats.linregress(t[g == k], y[g == k])
        assert tr.slope[k] == pytest.approx(ref.slope, rel=1e-9)
        assert tr.se[k] == pytest.approx(ref.stderr, rel=1e-9)
        p1 = ref.pvalue / 2 if ref.slope > 0 else 1 - ref.pvalue / 2
        assert tr.p[k] == pytest.approx(p1, rel=1e-6, abs=1e-12)
    # p-values of the null robots are uniform: the count under 0.2 is Binomial(160, 0.2), within its 1e-6 tails
    # (the bounds 16..48 were 3.2 sigma: session seed 2286241855 drew exactly 48)
    lo, hi = stats.binom.ppf([1e-6, 1 - 1e-6], 160, 0.2)
    assert lo <= (tr.p[40:] < 0.2).sum() <= hi
    # false-discovery proportion over 20 fleets: BH at q = 0.05 keeps it near q * 160/200 = 0.04
    # (sd of the mean ~0.007); flagging raw p <= 0.05 would give ~8/48 = 0.17
    fdp = []
    for _ in range(20):
        y = slope_true[g] * t + rng.normal(0, 0.1, g.size)
        flagged = benjamini_hochberg(trends(g, t, y).p) <= 0.05
        assert flagged[:40].all()
        fdp.append(flagged[40:].sum() / flagged.sum())
    assert np.mean(fdp) < 0.08, fdp


def test_fleet_from_the_command_line_and_the_page(fleet_stores, tmp_path, capsys):
    fleet, stores = fleet_stores
    url = stores[1].name
    cfg = station_config(tmp_path, "office", None)
    with pytest.raises(SystemExit):
        main(["store", "fleet", "drifting"])
    assert main(["store", "fleet", "drifting", "--config", str(cfg), "--name", "RP_mm", "--central"]) == 2  # no URL
    assert "store_url is not set" in capsys.readouterr().err
    pg_url = [s for s in stores if s.dialect == "postgresql"][0]
    cfg = station_config(tmp_path, "office", _url_of(pg_url))
    assert main(["store", "fleet", "drifting", "--config", str(cfg), "--name", "RP_mm", "--q", "0.01", "--json", "--central"]) == 1
    rows = json.loads(capsys.readouterr().out)
    assert fleet.drifting <= {r["serial"] for r in rows}
    assert main(["store", "fleet", "over-limits", "--config", str(cfg), "--name", "RP_mm", "--central"]) == 1
    capsys.readouterr()
    assert main(["store", "fleet", "history", "--config", str(cfg), "--serial", "SN-00000", "--name", "RP_mm", "--central"]) == 0
    assert capsys.readouterr().out.count("SN-00000-") == 14 * 5
    assert main(["store", "fleet", "drifting", "--config", str(cfg), "--name", "RP_mm", "--q", "2", "--central"]) == 2
    capsys.readouterr()
    page = tmp_path / "fleet.html"
    assert main(["store", "fleet", "page", "--config", str(cfg), "--name", "RP_mm", "--out", str(page), "--central"]) == 0
    text = page.read_text()
    for s in sorted(fleet.drifting)[:3]:
        assert s in text
    assert text.count("<svg") >= min(len(fleet.drifting), 30)
    assert url in text and "password" not in text.lower()


def _url_of(store) -> str:
    from tests.store.pgserver import PASSWORD_ENV

    return store.name + f"?password_env={PASSWORD_ENV}"
