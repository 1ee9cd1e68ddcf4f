"""`station simulate arm|trailer|hold` write files the analyses read, and the analyses find the truth beside.

Seeds are drawn each run and printed; bounds come from the figures' own uncertainties.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from tests.calibration.judge import assert_calibrated


@pytest.fixture
def seed(request, test_seed):
    """The test's seed from the session's (printed on failure; --seed replays)."""
    print(f"{request.node.name}: seed {test_seed}")
    return test_seed


def test_simulated_trailer_gives_its_link_lengths(tmp_path, seed, capsys):
    assert main(["simulate", "trailer", "--out", str(tmp_path), "--seed", str(seed)]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert main(["calibrate", "trailer", "--data", str(tmp_path / "trailer.csv"), "--json",
                 str(tmp_path / "cal.json")]) == 0
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert cal["method"] == "dynamic"
    for k in ("L1", "L2"):
        assert abs(cal[f"{k}_m"] - truth[f"{k}_m"]) < 5 * cal[f"{k}_sigma_m"] + 1e-3, (k, cal, truth)


def test_simulated_arm_is_calibrated_down_to_its_noise(tmp_path, seed, capsys):
    assert main(["simulate", "arm", "--out", str(tmp_path), "--seed", str(seed)]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert main(["calibrate", "arm", "--robot", truth["robot"], "--data", str(tmp_path / "arm.csv"), "--json",
                 str(tmp_path / "cal.json")]) == 0
    doc = json.loads((tmp_path / "cal.json").read_text())
    test = doc["test"]
    # geometric errors of mm before; after, what is left is noise and stopping scatter (a few hundredths); an arm
    # drawn near its nominal geometry (soak seed 173538517: 0.67 mm before, 0.086 after) is judged on that floor
    assert_calibrated(doc, 0.1)
    assert test["mean_abs_after_mm"] < 10 * truth["noise_mm"]
    raw = np.array(truth["true_points_mm"])
    assert raw.shape == (truth["n_poses"], 3)


def test_simulated_hold_gives_its_drift_and_noise(tmp_path, seed, capsys):
    """A simulated hold (the tracker's white + wander reading noise) gives back its drift, and `--noise-out`
    its reading noise: white, wander and time constant, within what the hold's length tells (about
    duration / (2 tau) independent wander values per axis)."""
    duration = 120.0
    assert main(["simulate", "hold", "--out", str(tmp_path), "--seed", str(seed), "--duration", str(duration),
                 "--rate", "333.333"]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert main(["analyze", "hold", "--stream", str(tmp_path / "stream.csv"), "--json", str(tmp_path / "h.json"),
                 "--noise-out", str(tmp_path / "noise.json")]) == 0
    d = json.loads((tmp_path / "h.json").read_text())
    sd = np.array(d["drift_sd_mm_per_min"])
    assert np.all(np.abs(np.array(d["drift_mm_per_min"]) - truth["drift_mm_per_min"]) < 5 * sd)
    nz = truth["tracker_noise"]
    k_eff = 3 * duration / (2 * nz["wander_tau_s"])
    tol = 6 / np.sqrt(2 * k_eff)
    assert np.all(np.abs(np.array(d["noise_mm"]) / truth["noise_mm"] - 1) < 2 * tol)
    fit = json.loads((tmp_path / "noise.json").read_text())
    assert fit == d["tracker_noise"] | {"source": fit["source"]}
    assert abs(fit["white_um"] / nz["white_um"] - 1) < 0.1
    assert abs(fit["wander_um"] / nz["wander_um"] - 1) < tol
    assert abs(fit["wander_tau_s"] / nz["wander_tau_s"] - 1) < 2 * tol
    assert fit["latency_s"] is None


def test_the_trailer_csv_and_an_arm_model_come_through_a_pipe_or_standard_input(tmp_path, seed, capsys, monkeypatch):
    """`-` and pipes for the trailer CSV, the arm's model file and a UR calibration file: each read once."""
    import io
    import os
    import threading

    assert main(["simulate", "trailer", "--out", str(tmp_path), "--seed", str(seed)]) == 0
    data = (tmp_path / "trailer.csv").read_bytes()
    assert main(["calibrate", "trailer", "--data", str(tmp_path / "trailer.csv"), "--json", str(tmp_path / "a.json")]) == 0
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(data)))
    assert main(["calibrate", "trailer", "--data", "-", "--json", str(tmp_path / "b.json")]) == 0
    a, b = (json.loads((tmp_path / f"{k}.json").read_text()) for k in "ab")
    assert a["L1_m"] == b["L1_m"] and a["L2_m"] == b["L2_m"]
    # an arm model through a named pipe (as <(cat cal.json) gives it), then a UR calibration on standard input
    assert main(["simulate", "arm", "--out", str(tmp_path), "--seed", str(seed)]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert main(["calibrate", "arm", "--robot", truth["robot"], "--data", str(tmp_path / "arm.csv"),
                 "--json", str(tmp_path / "cal.json")]) == 0
    fifo = tmp_path / "model.fifo"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_bytes((tmp_path / "cal.json").read_bytes()))
    writer.start()
    assert main(["calibrate", "arm", "--robot", str(fifo), "--data", str(tmp_path / "arm.csv"),
                 "--json", str(tmp_path / "again.json")]) == 0
    writer.join(timeout=10)
    again = json.loads((tmp_path / "again.json").read_text())["test"]
    assert again["mean_abs_before_mm"] < json.loads((tmp_path / "cal.json").read_text())["test"]["mean_abs_before_mm"]
    from station.models.arm_model_file import read_ur_calibration, ur_deltas, write_ur_calibration
    from station.models.robots import get_robot

    dh = get_robot("ur5e").dh_nominal
    moved = dh.copy()
    moved[:6] += np.random.default_rng(seed).normal(0, 1e-3, (6, dh.shape[1])) * (dh[:6] != 0)
    conf = tmp_path / "calibration.conf"
    write_ur_calibration(conf, ur_deltas(moved, dh))
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(conf.read_bytes())))
    np.testing.assert_array_equal(read_ur_calibration("-", dh), read_ur_calibration(conf, dh))
