"""A characteristic added to the table as one row reaches the config, the CLI, the JSON, the report and the store.

The row (the spread of a pose's attained positions: the largest distance between two of them) is added for the
test only (:func:`station.characteristics.added`); no other file names it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.assemble import RunRequest, run_procedure
from app.cli import main
from procedures.iso9283 import plan_from_config, summary
from station import characteristics as table
from station.config import config_from_dict
from station.errors import ConfigError
from station.store import RunStore
from tests.person import person_typing_yes


def _spread(pr):
    a = np.asarray(pr.attained_mm, dtype=float)
    if a.shape[0] < 2:
        return None
    return float(np.max(np.linalg.norm(a[:, None, :] - a[None, :, :], axis=2)))


SPREAD = table.Characteristic("SPREAD_mm", "mm", "pose", "spread_limit_mm", "Spread of the attained positions",
                              _spread, "fewer than 2 attained poses", stated=True, plotted=True)


def _attained(pose_json) -> np.ndarray:
    att = pose_json["attained"]
    return np.column_stack([att["x_mm"], att["y_mm"], att["z_mm"]])


def _spread_of(points) -> float:
    return float(max(np.linalg.norm(p - q) for p in points for q in points))


def test_a_row_added_to_the_table_appears_in_config_run_store_report_and_json(fake_cell, tmp_path):
    limits = {"rp_limit_mm": 0.5, "spread_limit_mm": 0.001}  # 1 um: every spread of real stops is larger
    doc = fake_cell.config_dict(store_path=str(tmp_path / "s.sqlite"), report_dir=str(tmp_path / "reports"),
                                iso9283={"cycles": 3, "vap_cycles": 2}, limits=limits)
    with pytest.raises(ConfigError, match="spread_limit_mm: unknown limit"):
        config_from_dict(doc)  # not a limit before the row exists
    with table.added(SPREAD):
        cfg = config_from_dict(doc)
        assert plan_from_config(cfg).limits == {"RP_mm": 0.5, "SPREAD_mm": 0.001}
        code = run_procedure(RunRequest(cfg, "iso9283", arm=True, operator=person_typing_yes(), quiet=True, run_id="t1",
                                        config_dir=tmp_path, json_out=str(tmp_path / "out.json")))
        assert code.status == "done"
        out = json.loads((tmp_path / "out.json").read_text())
        store = RunStore(tmp_path / "s.sqlite")
        rows = {r["pose"]: r for r in store.characteristics("t1") if r["name"] == "SPREAD_mm"}
        poses = out["results"]["pose"]["poses"]
        assert set(rows) == set(poses) == {"P1", "P2", "P3", "P4", "P5"}
        for name, pose in poses.items():
            truth = _spread_of(_attained(pose))  # from the JSON's attained positions, not the row's formula
            # the JSON rounds the figure and the attained positions each to 1e-6 mm: two roundings apart
            assert pose["SPREAD_mm"] == pytest.approx(truth, abs=2e-6)
            assert rows[name]["value"] == pytest.approx(truth, abs=2e-6)
            assert rows[name]["unit"] == "mm" and rows[name]["limit"] == 0.001 and rows[name]["passed"] is False
        spread_verdicts = [v for v in out["results"]["pose"]["verdicts"] if v["characteristic"] == "SPREAD_mm"]
        assert len(spread_verdicts) == 5 and not any(v["passed"] for v in spread_verdicts)
        assert out["verdict"] == "FAIL" and code.exit_code == 1
        # the store's history of the robot, the console's columns, the report's rows and figure
        assert "SPREAD_mm" in table.history_names()
        assert len(store.history("SIM-0001", "SPREAD_mm")) == 5
        lines = summary(store, "t1")
        assert "SPREAD mm" in lines[0]
        report = open(next(s.output["report"] for s in store.steps("t1") if s.name == "report")).read()
        assert "SPREAD_mm" in report and "Spread of the attained positions per pose" in report
        store.close()
    assert table.get("SPREAD_mm") is None  # the block's end takes the row away again


def test_a_row_added_to_the_table_is_a_limit_of_the_cli_and_a_key_of_its_json(tmp_path, test_seed, capsys):
    assert main(["simulate", "iso9283", "--out", str(tmp_path), "--cycles", "4", "--seed", str(test_seed % 2**32),
                 "--rate", "200"]) == 0
    args = ["analyze", "iso9283", "--stream", str(tmp_path / "stream.csv"), "--poses", str(tmp_path / "poses.csv"),
            "--limit", "SPREAD_mm=0.001", "--json", str(tmp_path / "r.json")]
    assert main(args) == 2  # not a limit before the row exists
    assert "unknown limit 'SPREAD_mm'" in capsys.readouterr().err
    with table.added(SPREAD):
        assert main(args) == 1  # every spread is above 1 um: FAIL
        res = json.loads((tmp_path / "r.json").read_text())
        out = capsys.readouterr().out
    header = next(line for line in out.splitlines() if line.startswith("pose "))
    assert "SPREAD_mm" in header.split()  # a column of the console's pose table
    p1 = next(line for line in out.splitlines() if line.startswith("P1 ")).split()
    assert float(p1[header.split().index("SPREAD_mm")]) == pytest.approx(res["poses"]["P1"]["SPREAD_mm"], abs=1e-3)
    for name, pose in res["poses"].items():
        assert pose["SPREAD_mm"] == pytest.approx(_spread_of(_attained(pose)), abs=1e-6)
    verdicts = [v for v in res["verdicts"] if v["characteristic"] == "SPREAD_mm"]
    assert {v["subject"] for v in verdicts} == set(res["poses"]) and not any(v["passed"] for v in verdicts)
    assert res["limits"] == {"SPREAD_mm": 0.001}
