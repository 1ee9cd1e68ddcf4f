"""`station simulate arm|trailer|hold` write files the analyses read, and the analyses find the truth beside.

Seeds are drawn each run and printed; bounds come from the figures' own uncertainties.
"""

from __future__ import annotations

import json
import secrets

import numpy as np
import pytest

from app.cli import main


@pytest.fixture
def seed(request):
    s = secrets.randbits(31)
    print(f"{request.node.name}: seed {s}")
    return s


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
    test = json.loads((tmp_path / "cal.json").read_text())["test"]
    # geometric errors of mm before; after, what is left is noise and stopping scatter (a few hundredths)
    assert test["mean_abs_before_mm"] > 10 * test["mean_abs_after_mm"]
    assert test["mean_abs_after_mm"] < 10 * truth["noise_mm"]
    raw = np.array(truth["true_points_mm"])
    assert raw.shape == (truth["n_poses"], 3)


def test_simulated_hold_gives_its_drift_and_noise(tmp_path, seed, capsys):
    assert main(["simulate", "hold", "--out", str(tmp_path), "--seed", str(seed)]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert main(["analyze", "hold", "--stream", str(tmp_path / "stream.csv"), "--json", str(tmp_path / "h.json")]) == 0
    d = json.loads((tmp_path / "h.json").read_text())
    sd = np.array(d["drift_sd_mm_per_min"])
    assert np.all(np.abs(np.array(d["drift_mm_per_min"]) - truth["drift_mm_per_min"]) < 5 * sd)
    n = 6001
    assert np.all(np.abs(np.array(d["noise_mm"]) / truth["noise_mm"] - 1) < 5 / np.sqrt(2 * n))
