"""The tracker noise file: written by `analyze hold --noise-out`, read by `simulate ... --tracker-noise` and by
`analyze iso9283 --tracker-noise` (issue 42 item 2)."""

from __future__ import annotations

import json
import math

import pytest

from app.cli import main


def test_a_fitted_noise_drives_the_simulation_and_the_budget(tmp_path, capsys, rng):
    """A hold drawn with a random noise is fitted; the fit, given to the ISO run, is the simulated tracker's
    noise (truth), and given to the analysis it is the budget's reading noise with the MPE systematic."""
    drawn = {"white_um": float(rng.uniform(0.3, 2.0)), "wander_um": float(rng.uniform(1.0, 4.0)),
             "wander_tau_s": float(rng.uniform(0.3, 1.5)), "latency_s": 0.0, "source": "test"}
    (tmp_path / "drawn.json").write_text(json.dumps(drawn))
    seed = str(int(rng.integers(0, 2**31)))
    assert main(["simulate", "hold", "--out", str(tmp_path / "h"), "--duration", "120", "--rate", "250",
                 "--seed", seed, "--tracker-noise", str(tmp_path / "drawn.json")]) == 0
    truth = json.loads((tmp_path / "h" / "truth.json").read_text())
    assert {k: truth["tracker_noise"][k] for k in ("white_um", "wander_um", "wander_tau_s")} == \
        pytest.approx({k: drawn[k] for k in ("white_um", "wander_um", "wander_tau_s")}, abs=1e-6)
    assert main(["analyze", "hold", "--stream", str(tmp_path / "h" / "stream.csv"), "--noise-out",
                 str(tmp_path / "fit.json")]) == 0
    fit = json.loads((tmp_path / "fit.json").read_text())
    assert "tracker noise: white" in capsys.readouterr().out
    k_eff = 3 * 120 / (2 * drawn["wander_tau_s"])
    assert abs(fit["wander_um"] / drawn["wander_um"] - 1) < 6 / math.sqrt(2 * k_eff)
    out = tmp_path / "iso"
    assert main(["simulate", "iso9283", "--robot", "ur5e", "--out", str(out), "--cycles", "4", "--rate", "200",
                 "--wait", "1", "--seed", seed, "--tracker-noise", str(tmp_path / "fit.json")]) == 0
    noise = json.loads((out / "truth.json").read_text())["world"]["tracker"]["noise"]
    assert noise["white_um"] == pytest.approx(fit["white_um"]) and noise["wander_um"] == pytest.approx(fit["wander_um"])
    assert noise["wander_tau_s"] == pytest.approx(fit["wander_tau_s"])
    assert main(["analyze", "iso9283", "--stream", str(out / "stream.csv"), "--poses", str(out / "poses.csv"),
                 "--order", "P2,P3,P4,P5,P1", "--tracker-noise", str(tmp_path / "fit.json"), "--mc-trials", "2000",
                 "--json", str(out / "r.json")]) == 0
    text = capsys.readouterr().out
    assert "systematic, reading noise" in text
    inst = json.loads((out / "r.json").read_text())["uncertainty"]["budget"]["instrument"]
    assert inst["reading_noise_um"] == pytest.approx(math.hypot(fit["white_um"], fit["wander_um"]))
    assert inst["accuracy_read_as"].startswith("a systematic error")


@pytest.mark.parametrize("content, needle", [
    ("{", "not JSON"),
    ('{"white_um": 1, "bogus": 2}', "unknown key 'bogus'"),
    ('{"wander_um": 1, "wander_tau_s": 1}', "white_um is missing"),
    ('{"white_um": -1}', "`white_um` must be"),
    ('{"white_um": 1, "wander_um": 2}', "`wander_tau_s` is needed"),
    ('{"white_um": 1, "wander_um": 2, "wander_tau_s": 0}', "`wander_tau_s` must be"),
    ('{"schema": "station.tracker_noise/9", "white_um": 1}', "schema must be"),
    ('[1, 2]', "must be a JSON object"),
])
def test_a_bad_noise_file_is_refused_naming_the_key(tmp_path, capsys, content, needle):
    f = tmp_path / "n.json"
    f.write_text(content)
    for cmd in (["simulate", "hold"], ["simulate", "iso9283"]):
        out = tmp_path / "out"
        assert main([*cmd, "--out", str(out), "--tracker-noise", str(f)]) == 2
        err = capsys.readouterr().err
        assert needle in err and f"--tracker-noise {f}" in err, err
        assert not out.exists()
