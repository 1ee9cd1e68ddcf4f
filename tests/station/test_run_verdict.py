"""`station run` tells its verdict: first line, --json top level, exit code, the store; --require-iso."""

import json
import sys
from pathlib import Path


from fakes.cells import demo_config
from app.cli import main
from station.store import RunStore
from tests.pace import LOCKSTEP


def test_station_run_exits_with_its_verdict_and_says_it_first(test_seed, tmp_path, capsys):
    seed = test_seed  # the session's seed for this test (printed on failure, --seed replays)
    print(f"cell seed {seed}", file=sys.stderr)
    cfg = tmp_path / "station.json"
    cfg.write_text(json.dumps(demo_config(tmp_path, cycles=2, vap_cycles=2, rate_hz=100.0), default=str))
    out = tmp_path / "r.json"
    code = main(["run", "iso9283", "--config", str(cfg), "--yes", "--quiet", "--require-iso", "--run-id", "v1",
                 "--seed", str(seed), "--time-scale", str(LOCKSTEP), "--json", str(out)])
    doc = json.loads(out.read_text())
    lines = capsys.readouterr().out.splitlines()
    assert doc["status"] == "done"
    # 2 cycles are never ISO 9283 conformant: with --require-iso never a PASS
    assert doc["conformant"] is False and doc["verdict"] in ("FAIL", "NOT DECIDED")
    assert code == doc["exit_code"] == {"FAIL": 1, "NOT DECIDED": 4 if len(doc["reasons"]) == 1 else 3}[doc["verdict"]]
    assert lines[0] == f"{doc['verdict']}: run v1 (iso9283) done"
    assert [ln.strip() for ln in lines[1:1 + len(doc["reasons"])]] == doc["reasons"]
    assert any(r.startswith("not conformant (required)") for r in doc["reasons"])
    assert doc["characteristics"] and doc["results"]["pose"]["iso_conformant"] is False
    with RunStore(tmp_path / "station.sqlite") as store:
        assert store.result("v1", "verdict") == {k: doc[k] for k in ("verdict", "reasons", "conformant", "exit_code", "marginal")}
    report = Path(doc["report"]).read_text()
    assert f">{doc['verdict']}</p>" in report
