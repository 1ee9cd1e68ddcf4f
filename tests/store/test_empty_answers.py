"""A store question without an answer says so, on the station's own store and on the central one."""

from __future__ import annotations

import numpy as np

from app.cli import main
from station.store import RunStore

from .helpers import add_run, station_config


def test_empty_answers_say_so(tmp_path, pg_url, capsys):
    cfg = station_config(tmp_path, "cell", pg_url)
    with RunStore(tmp_path / "cell.sqlite") as store:
        add_run(store, "a1", "SN-A", np.random.default_rng(0), batches=2)
    asked = {
        ("store", "exceeding", "--name", "AP_mm"): "no robot over its AP_mm limit (each robot's latest run)",
        ("store", "history", "--serial", "NOPE", "--name", "RP_mm"): "no values of RP_mm for serial NOPE",
        ("store", "fleet", "over-limits", "--name", "AP_mm"):
            "no robot whose latest run is over its AP_mm limit or not decided against it in this station's store",
        ("store", "fleet", "drifting", "--name", "RP_mm"): "no robot whose RP_mm drifts",
    }
    for argv, said in asked.items():
        assert main([*argv, "--config", str(cfg)]) == 0
        assert said in capsys.readouterr().out, argv
    assert main(["store", "push", "--config", str(cfg)]) == 0
    assert "a1" in capsys.readouterr().out
    assert main(["store", "push", "--config", str(cfg)]) == 0  # everything is there already
    assert "nothing to send" in capsys.readouterr().out
    assert main(["store", "fleet", "drifting", "--name", "RP_mm", "--config", str(cfg), "--central"]) == 0
    assert "drifts (q <= 0.05, at least 5 runs since its overhaul) in the central store" in capsys.readouterr().out
