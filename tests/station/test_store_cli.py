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


def test_store_runs_lists_each_runs_verdict_in_aligned_columns(tmp_path, capsys):
    """`station store runs`: a header, each run's stored verdict (a NOT DECIDED run does not read 'done'
    alone), columns that hold an arm-calibration's name, and no central-store column without a centre."""
    cfg = _cfg(tmp_path)
    store = RunStore(tmp_path / "s.sqlite")
    cases = (("r-pass", "iso9283", "PASS"), ("r-nd", "iso9283", "NOT DECIDED"), ("r-cal", "arm-calibration", "FAIL"),
             ("r-open", "trailer", None))
    for run_id, proc, verdict in cases:
        store.create_run(run_id, proc, model="industrial-3100", serial="SN-A", overhaul_state="after", config={},
                         params={})
        if verdict is not None:
            store.put_result(run_id, "verdict", {"verdict": verdict, "reasons": [], "conformant": None,
                                                 "exit_code": 0})
            store.set_run_status(run_id, "done")
    store.close()
    assert main(["store", "runs", "--config", str(cfg)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:6] == ["run", "procedure", "serial", "overhaul", "status", "verdict"]
    col = lines[0].index("verdict")
    shown = {ln.split()[0]: ln[col:].split("  ")[0].strip() for ln in lines[1:]}
    assert shown == {"r-pass": "PASS", "r-nd": "NOT DECIDED", "r-cal": "FAIL", "r-open": "-"}
    assert "centre" not in "\n".join(lines)  # no central store configured
