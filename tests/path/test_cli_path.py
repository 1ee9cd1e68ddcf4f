"""``station analyze path`` on files: JSON keys, verdicts, exit codes, bad input."""

from __future__ import annotations

import json

import numpy as np

from app.cli import main
from tests.path import simarm


def _write(tmp_path, sim, valid=None):
    valid = np.ones(sim.t.size, bool) if valid is None else valid
    rows = ["t,x,y,z,status"] + [f"{t:.4f},{x:.5f},{y:.5f},{z:.5f},{0 if ok else 1}"
                                 for t, (x, y, z), ok in zip(sim.t, sim.meas, valid)]
    s = tmp_path / "s.csv"
    s.write_text("\n".join(rows) + "\n")
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"paths": [sim.path]}))
    return s, p


def test_analyze_path_writes_the_figures_and_judges_limits(tmp_path, rng):
    sim = simarm.line(rng, n_cycles=4, noise=0.01)
    s, p = _write(tmp_path, sim)
    out = tmp_path / "o.json"
    at = sim.truth["AT_mm"]
    code = main(["analyze", "path", "--stream", str(s), "--path", str(p), "--json", str(out),
                 "--tracker-uncertainty", "sd:10", "--limit", f"AT_mm={at * 3:.4f}", "--limit",
                 f"line.RT_mm={sim.truth['RT_mm'] / 3:.5f}"])
    d = json.loads(out.read_text())
    fig = d["paths"]["line"]
    assert {"AT_mm", "RT_mm", "AV_percent", "RV_percent", "FV_percent"} <= set(fig)
    assert abs(fig["AT_mm"] - at) <= fig["uncertainty"]["AT_mm"]["U_mm"] + 1e-9 or abs(fig["AT_mm"] - at) < 0.02
    outs = {v["characteristic"]: v["outcome"] for v in d["verdicts"]}
    assert outs == {"AT_mm": "PASS", "RT_mm": "FAIL"}
    assert code == 1


def test_bad_path_file_is_exit_2_naming_the_key(tmp_path, rng, capsys):
    sim = simarm.line(rng, n_cycles=2, noise=0.01)
    s, p = _write(tmp_path, sim)
    p.write_text(json.dumps({"paths": [{"name": "l", "kind": "line", "start_mm": [0, 0, 0]}]}))
    assert main(["analyze", "path", "--stream", str(s), "--path", str(p)]) == 2
    assert "end_mm" in capsys.readouterr().err


def test_unknown_limit_is_exit_2(tmp_path, rng, capsys):
    sim = simarm.line(rng, n_cycles=2, noise=0.01)
    s, p = _write(tmp_path, sim)
    assert main(["analyze", "path", "--stream", str(s), "--path", str(p), "--limit", "XX_mm=1"]) == 2
    assert "XX_mm" in capsys.readouterr().err


def test_coarse_stamps_refuse_the_speed_not_the_geometry(tmp_path, rng, capsys):
    sim = simarm.line(rng, n_cycles=3, noise=0.01)
    rows = ["t,x,y,z"] + [f"{np.floor(t * 10) / 10:.1f},{x:.5f},{y:.5f},{z:.5f}" for t, (x, y, z) in zip(sim.t, sim.meas)]
    s = tmp_path / "coarse.csv"
    s.write_text("\n".join(rows) + "\n")
    p = tmp_path / "p.json"
    p.write_text(json.dumps({"paths": [sim.path]}))
    out = tmp_path / "o.json"
    code = main(["analyze", "path", "--stream", str(s), "--path", str(p), "--limit", "AV_percent=50",
                 "--json", str(out)])
    d = json.loads(out.read_text())["paths"]["line"]
    assert code == 3 and "clock" in capsys.readouterr().err
    assert d["AV_percent"] is None and "clock" in d["refused"]["AV_percent"]
    assert d["AT_mm"] is not None and d["RT_mm"] is not None
