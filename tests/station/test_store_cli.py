import json

from app.cli import main
from station.store import RunStore


def _cfg(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({
        "station": {"name": "t", "store_path": "s.sqlite"},
        "devices": {"c": {"url": "fake://controller"}},
        "robots": {"r1": {"model": "industrial-3100", "serial": "SN-A", "controller": "c",
                          "workspace": {"min_mm": [-900, 800, 500], "max_mm": [900, 2600, 2300]}}},
    }))
    return p


def test_history_exceeding_and_export_from_the_command_line(tmp_path, capsys):
    cfg = _cfg(tmp_path)
    store = RunStore(tmp_path / "s.sqlite")
    for run_id, state, rp in (("a1", "before", 0.8), ("a2", "after", 0.2)):
        store.create_run(run_id, "iso9283", model="industrial-3100", serial="SN-A", overhaul_state=state,
                         config={}, params={})
        store.put_characteristics(run_id, [{"pose": "P1", "name": "RP_mm", "value": rp, "unit": "mm",
                                            "limit": 0.5, "passed": rp <= 0.5}])
        store.set_run_status(run_id, "done")
    store.close()
    assert main(["store", "history", "--config", str(cfg), "--serial", "SN-A", "--name", "RP_mm", "--json"]) == 0
    hist = json.loads(capsys.readouterr().out)
    assert [(h["overhaul_state"], h["value"]) for h in hist] == [("before", 0.8), ("after", 0.2)]
    # latest run of SN-A is within the limit: nothing exceeds; over all runs the 'before' run does
    assert main(["store", "exceeding", "--config", str(cfg), "--name", "RP_mm"]) == 0
    assert main(["store", "exceeding", "--config", str(cfg), "--name", "RP_mm", "--all-runs"]) == 1
    assert "SN-A" in capsys.readouterr().out
    assert main(["store", "export", "a1", "--config", str(cfg), "--out", str(tmp_path / "x")]) == 0
    assert (tmp_path / "x" / "characteristics.csv").read_text().count("RP_mm") == 1
    assert main(["store", "export", "zz", "--config", str(cfg), "--out", str(tmp_path / "x")]) == 2
