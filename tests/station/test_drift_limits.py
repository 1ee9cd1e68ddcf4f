"""The drift programme's orientation rows (dAPa/b/c, dRPa/b/c, a 6-DoF target's) have limit keys in a robot's
limits like its position drift (dap_limit_mm): read and checked with the config (a bad value or unit named),
given to the drift programme's plan (not to the pose test's), and refused before anything moves on a tracker
that measures positions only."""

from __future__ import annotations

import pytest

from app.assemble import RunRequest, run_procedure
from station import characteristics as table
from station.config import config_from_dict
from station.errors import ConfigError, PreflightError
from station.store import RunStore
from tests.pace import LOCKSTEP

ANGLE_KEYS = [f"d{kind}{ax}_deg" for kind in ("AP", "RP") for ax in "abc"]


def _config(tmp_path, limits: dict) -> dict:
    from fakes.cells import demo_config

    d = demo_config(tmp_path, cycles=3, vap_cycles=2, rate_hz=100.0)
    d["robots"]["r1"]["limits"] = {"rp_limit_mm": 0.5, **limits}
    d["iso9283_drift"] = {"span_s": 600.0, "interval_s": 300.0, "cycles_per_visit": 2}
    return d


def test_every_drift_row_has_a_limit_key_carrying_its_unit():
    keys = table.config_limit_keys("drift")
    assert {keys[f"d{k.lower()}{a}_limit_deg"] for k in ("AP", "RP") for a in "abc"} == set(ANGLE_KEYS)
    assert keys["dap_limit_mm"] == "dAP_mm" and keys["drp_limit_mm"] == "dRP_mm"
    assert set(keys.values()) == {c.key for c in table.characteristics("drift")}
    assert set(table.robot_limit_keys()) == set(table.config_limit_keys()) | set(keys)


def test_orientation_drift_limits_are_read_with_the_config_and_given_to_the_drift_programme_only(tmp_path, rng):
    limits = {f"d{k.lower()}{a}_limit_deg": float(rng.uniform(0.001, 0.5)) for k in ("AP", "RP") for a in "abc"}
    cfg = config_from_dict(_config(tmp_path, {**limits, "dap_limit_mm": 0.05}))
    lim = cfg.robots["r1"].limits
    assert lim.dapa_limit_deg == limits["dapa_limit_deg"] and lim.drpc_limit_deg == limits["drpc_limit_deg"]
    drift = lim.by_characteristic("drift")
    assert drift == {"dAP_mm": 0.05, **{table.config_limit_keys("drift")[k]: v for k, v in limits.items()}}
    assert not set(ANGLE_KEYS) & set(lim.by_characteristic())  # the pose test's limits: none of them
    assert config_from_dict(_config(tmp_path, {})).robots["r1"].limits.dapb_limit_deg is None


@pytest.mark.parametrize("key, value, word", [
    ("dapa_limit_deg", -0.1, "robots.r1.limits.dapa_limit_deg"),
    ("drpc_limit_deg", 0.0, "robots.r1.limits.drpc_limit_deg"),
    ("dapb_limit_deg", "0.1 deg", "robots.r1.limits.dapb_limit_deg"),
    ("dapa_limit_mm", 0.1, "robots.r1.limits.dapa_limit_mm"),  # an angle's limit in the wrong unit: unknown
    ("drpd_limit_deg", 0.1, "robots.r1.limits.drpd_limit_deg"),
])
def test_a_bad_orientation_drift_limit_is_refused_naming_it(tmp_path, key, value, word):
    with pytest.raises(ConfigError, match=word.replace(".", r"\.")):
        config_from_dict(_config(tmp_path, {key: value}))


def test_orientation_drift_limits_on_a_position_only_tracker_are_refused_before_anything_moves(tmp_path, rng):
    key = str(rng.choice(ANGLE_KEYS))
    limit_key = next(k for k, v in table.config_limit_keys("drift").items() if v == key)
    cfg = config_from_dict(_config(tmp_path, {limit_key: 0.05}))
    with pytest.raises(PreflightError, match=f"limits {key}: orientation limits need a 6-DoF tracker"):
        run_procedure(RunRequest(cfg, "iso9283-drift", run_id="x", yes=True, quiet=True, time_scale=LOCKSTEP,
                                 config_dir=tmp_path))
    with RunStore(cfg.station.store_file(tmp_path)) as store:
        assert "x" not in [r.run_id for r in store.runs()]
