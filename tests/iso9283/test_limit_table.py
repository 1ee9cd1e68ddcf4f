"""Every limit `station analyze iso9283 --limit` accepts can be set in a station config and reaches the verdict.

One long synthetic run carries every characteristic of the table (orientation, drift, a linear path, an
overshooting servo) and a multi-directional run carries vAP (of the position and the orientation). For each limit key of the table: the config's
``robots.r1.limits.<limit_key>`` set at half the largest measured figure gives the characteristic in the plan's
limits and a FAIL verdict; set at twice it, a PASS.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from app.commands.analyze_inputs import parse_limits
from procedures.iso9283 import plan_from_config
from station import characteristics as table
from station.analysis.iso9283.characteristics import analyze_iso9283, check_limits
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.config import config_from_dict
from station.errors import ConfigError
from station.verdict import Outcome
from tests.seeding import seed_for

from .synth import NAMES5, iso_cycle_programme, multidirection_programme, render

CMD = np.array(TABLE2_POSES_MM)
RATE = 200.0
SERVO = dict(wn_hz=12.0, zeta=0.6)  # overshoots: POS > 0


def _config(limits: dict) -> dict:
    return {
        "station": {"name": "cell", "store_path": "s.sqlite"},
        "devices": {"tracker": {"url": "emscon://127.0.0.1:700"}, "ctrl": {"url": "modbus+ftp://127.0.0.1"}},
        "robots": {"r1": {"model": "industrial-3100", "serial": "SN-1", "controller": "ctrl",
                          "workspace": {"min_mm": [-800.0, 900.0, 600.0], "max_mm": [800.0, 2500.0, 2200.0]},
                          "limits": limits}},
    }


@pytest.fixture(scope="module")
def runs(request):
    """``analyse(limits) -> (single-direction result, multi-directional result)`` of two drawn runs."""
    rng = np.random.default_rng(seed_for(request))
    abc_cmd = rng.uniform(-1, 1, (5, 3))
    prog = iso_cycle_programme(rng, n_cycles=20, scatter_mm=0.03, abc_commanded_rad=abc_cmd,
                               abc_offset_rad=rng.normal(0, 2e-3, (5, 3)), abc_scatter_rad=2e-4, dwell_s=0.5,
                               offsets_mm=rng.normal(0, 1.0, (5, 3)))
    s = render(rng, prog, start_mm=CMD[0], start_abc_rad=abc_cmd[0], rate_hz=RATE, noise_mm=0.005,
               abc_noise_rad=5e-5, **SERVO)
    mp = multidirection_programme(rng, commanded=CMD, pose=0, dir_offsets_mm=rng.normal(0, 0.4, (3, 3)), n_each=5,
                                  scatter_mm=0.02)
    # the tool's orientation too: an offset per approach direction (orientation vAP) and a scatter
    d = mp.direction
    mp = replace(mp, target_abc_rad=abc_cmd[0] + np.where(d[:, None] >= 0, rng.normal(0, 2e-3, (3, 3))[d], 0.0)
                 + rng.normal(0.0, 2e-4, (d.size, 3)))
    sv = render(rng, mp, start_mm=CMD[0] - [0, 0, 150.0], start_abc_rad=abc_cmd[0], rate_hz=RATE, noise_mm=0.005,
                abc_noise_rad=5e-5, speed_mm_s=500.0, **SERVO)

    def analyse(limits):
        one = {k: v for k, v in limits.items() if not table.get(k).several_approaches}
        several = {k: v for k, v in limits.items() if table.get(k).several_approaches}
        main = analyze_iso9283(s.t, s.xyz, CMD, names=NAMES5, orientation_rad=s.abc,
                               commanded_orientation_rad=abc_cmd, drift_block=10, linear_paths=[("P2", "P3")],
                               n_planes=5, band_mm=0.05, limits=one)
        vap = analyze_iso9283(sv.t, sv.xyz, CMD[[0]], names=[NAMES5[0]], orientation_rad=sv.abc,
                              commanded_orientation_rad=abc_cmd[[0]], limits=several)
        return main, vap

    return analyse


def _largest(c, main, vap) -> float:
    res = vap if c.several_approaches else main
    values = [abs(v) for _, subject in table.subjects(res, c.level) if (v := c.value(subject)) is not None]
    assert values, f"the drawn run gives no {c.key}"
    return max(values)


def test_the_config_knows_every_limit_the_cli_knows():
    cli = set(check_limits(parse_limits([f"{k}=1" for k in table.limit_levels()])))
    assert cli == set(table.limit_levels()) == set(table.config_limit_keys().values())
    assert len(cli) >= 18  # AP RP POS PST vAP dAP dRP APa..RPc AD RD MPT AT RT


@pytest.mark.parametrize("key", list(table.limit_levels()))
def test_each_limit_from_the_config_reaches_the_verdict(runs, key):
    c = table.get(key)
    measured = _largest(c, *runs({}))
    assert measured > 0 and math.isfinite(measured), (key, measured)
    for factor, expected in ((0.5, Outcome.FAIL), (2.0, Outcome.PASS)):
        limit = factor * measured
        cfg = config_from_dict(_config({c.limit_key: limit}))
        plan = plan_from_config(cfg)
        assert plan.limits == {key: pytest.approx(limit)}
        main, vap = runs(plan.limits)
        judged = vap if c.several_approaches else main
        mine = [v for v in judged.verdicts if v.characteristic == key]
        assert mine and all(v.limit == pytest.approx(limit) for v in mine), (key, judged.verdicts)
        assert judged.outcome is expected, (key, factor, [(v.subject, v.value, v.outcome) for v in mine])
        assert {v.characteristic for v in main.verdicts + vap.verdicts} == {key}


def test_a_limit_the_table_lacks_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"robots\.r1\.limits\.ap_limit_um: unknown limit"):
        config_from_dict(_config({"ap_limit_um": 5.0}))
    with pytest.raises(ConfigError, match=r"robots\.r1\.limits\.rpa_limit_deg"):
        config_from_dict(_config({"rpa_limit_deg": -1.0}))


def test_every_figure_of_the_station_is_a_row_of_the_one_table():
    """The path test's, the compliance test's and the fleet's figures are rows of the same table (programme
    path, compliance, fleet): the analyses read their names and units there, and none of them leaks into the
    pose test's limits (a station config's robots.<r>.limits, --limit of analyze iso9283)."""
    from station.analysis.iso9283 import compliance, exchangeability
    from station.analysis.path import figures as path_figures

    path_keys = {c.key for c in table.characteristics("path")}
    assert path_keys == {"AT_mm", "RT_mm", "CR_mm", "CO_mm", "AV_percent", "RV_percent", "FV_percent",
                         "WS_percent", "WF_percent"}
    assert set(path_figures.NAMES) == path_keys
    assert compliance.COMPLIANCE is table.get("compliance_mm_per_N", "compliance")
    assert compliance.COMPLIANCE.unit == "mm/N" and compliance.COMPLIANCE.level == "direction"
    assert exchangeability.EXCHANGEABILITY is table.get("exchangeability_mm", "fleet")
    pose = table.limit_levels()
    assert not ({"CR_mm", "AV_percent", "compliance_mm_per_N", "exchangeability_mm"} & set(pose))
    assert table.get("CR_mm") is None and table.get("CR_mm", "path") is not None
    assert table.unit_of("WS_percent") == "%" and table.unit_of("compliance_mm_per_N") == "mm/N"
    assert "compliance_mm_per_N" in table.history_names()
