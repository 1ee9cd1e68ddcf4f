"""station diagnose motion at the command line, the motion model file, and its use by station simulate iso9283."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from app.cli import main
from station.errors import ConfigError
from station.models.motion_effects import KIND, approach_offsets_mm, check_motion_model
from tests.iso9283.ur_lookalike import lab_lookalike, write_lab_export


def _model(**effects) -> dict:
    return {"kind": KIND, "version": 1, "servo": {"frequency_hz": 12.0, "damping": 0.7, "jerk_time_s": 0.0},
            "deceleration_mm_s2": 1500.0, "effects": effects}


def test_model_file_is_range_checked():
    m = check_motion_model(_model(creep={"amplitude_mm": 0.03, "tau_s": 0.15}))
    assert m.effects["creep"]["tau_s"] == 0.15
    bad = _model()
    bad["servo"]["frequency_hz"] = 1e6
    with pytest.raises(ConfigError, match=r"servo\.frequency_hz"):
        check_motion_model(bad)
    with pytest.raises(ConfigError, match=r"effects\.creep\.tau_s"):
        check_motion_model(_model(creep={"amplitude_mm": 0.03, "tau_s": -1.0}))
    with pytest.raises(ConfigError, match="unknown effect"):
        check_motion_model(_model(backlash={"x": 1.0}))
    with pytest.raises(ConfigError, match="kind"):
        check_motion_model({"servo": {}})


def test_offsets_follow_the_travel(rng):
    A, tau = rng.uniform(0.01, 0.05), rng.uniform(0.05, 0.3)
    p0, p1 = rng.uniform(-500, 500, 3), rng.uniform(-500, 500, 3)
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    m = check_motion_model(_model(creep={"amplitude_mm": A, "tau_s": tau}))
    t_end = 3.0
    t = np.array([0.5, 1.5, t_end + tau, t_end + 20 * tau])
    off = approach_offsets_mm(t, [{"t_start_s": 1.0, "t_end_s": t_end, "from_mm": p0, "to_mm": p1}], m)
    assert np.allclose(off[0], 0.0)  # before the move
    assert off[1] @ u == pytest.approx(-A)  # short while moving
    assert off[2] @ u == pytest.approx(-A * math.exp(-1.0))
    assert np.allclose(np.cross(off, u), 0.0, atol=1e-12)  # along the travel only
    assert abs(off[3] @ u) < 1e-6 * A
    # a mode: its steady deflection while decelerating is gain x deceleration, and it rings out after the end
    # (a long deceleration, 2 s at 150 mm/s^2: the ring of its onset has died out before its end)
    g = rng.uniform(1e-5, 1e-4)
    mm = _model(structural_mode={"frequency_hz": 10.0, "damping": 0.08, "gain_s2": g})
    mm["deceleration_mm_s2"] = 150.0
    mm = check_motion_model(mm)
    p1 = p0 + 2000.0 * u
    v = 300.0
    T = 2000.0 / v + v / 150.0
    tt = np.array([t_end - 0.2, t_end + 60.0])
    off = approach_offsets_mm(tt, [{"t_start_s": t_end - T, "t_end_s": t_end, "from_mm": p0, "to_mm": p1}], mm)
    assert off[0] @ u == pytest.approx(g * 150.0, rel=0.01)
    assert abs(off[1] @ u) < 1e-6 * g * 150.0


@pytest.fixture
def lab(tmp_path, rng):
    la = lab_lookalike(rng)
    stream = write_lab_export(tmp_path / "lab.txt", la)
    poses = tmp_path / "poses.csv"
    poses.write_text("name,x,y,z\n" + "".join(f"{n},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n"
                                               for n, p in zip(("P1", "P2"), la.poses_mm)))
    return stream, poses


@pytest.mark.timeout(900)  # two diagnoses and a simulation: slow on a shared machine
def test_time_figures_only_on_a_checked_clock(tmp_path, lab, capsys):
    stream, poses = lab
    out, model = tmp_path / "d.json", tmp_path / "m.json"
    # 1 s PC stamps, 66-444 samples a stamp: the clock fails, no time figure, no model (exit 2), the JSON kept
    rc = main(["diagnose", "motion", "--stream", str(stream), "--poses", str(poses), "--json", str(out),
               "--model-out", str(model)])
    assert rc == 2
    assert "not written" in capsys.readouterr().err and not model.exists()
    doc = json.loads(out.read_text())
    assert doc["time_refused"]
    for p in doc["poses"]:
        for kind in ("measured", "simulated", "extended"):
            assert p[kind]["PST_s"] is None and p[kind]["MPT_s"] is None and p[kind]["time_to_band_s"] is None
    for key in ("steps", "simulation_heldout_rms", "final_heldout_rms", "gain", "noise_floor", "not_testable"):
        assert key in doc
    # the program's wait lets the dwells give the rate (1000/3 Hz): time figures stated, the model written
    prog = tmp_path / "prog.toml"
    prog.write_text('robot = "ur5e"\ndwell_s = 2.0\norder = ["P2", "P1"]\n[move]\ntype = "joint"\nspeed = 60\n'
                    'acceleration = 80\n[poses.P1]\njoints_deg = [-81.25, -100, 100, -90, -90, 0]\n'
                    '[poses.P2]\njoints_deg = [81.25, -100, 100, -90, -90, 0]\n')
    rc = main(["diagnose", "motion", "--stream", str(stream), "--poses", str(poses), "--program", str(prog),
               "--json", str(out), "--model-out", str(model)])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["time_refused"] is None
    assert doc["rate_hz"] == pytest.approx(1000.0 / 3.0, rel=1e-3)
    # a move of the look-alike takes 3.3-3.6 s (UR's 60 deg/s, 80 deg/s^2 over 140-170 deg): MPT from leaving
    assert all(3.0 < p["measured"]["MPT_s"] < 4.2 for p in doc["poses"])
    assert doc["steps"] == []  # nothing hidden in the look-alike
    written = json.loads(model.read_text())
    check_motion_model(written)
    assert written["basis"] == "named" and written["effects"] == doc["extended_model"]["effects"]
    rc = main(["simulate", "iso9283", "--out", str(tmp_path / "sim"), "--robot", "ur5e", "--cycles", "1",
               "--dwell", "0.5", "--rate", "100", "--motion-model", str(model)])
    assert rc == 0 and (tmp_path / "sim" / "stream.csv").exists()


def test_bad_input_exit_2(tmp_path, lab, capsys):
    stream, poses = lab
    far = tmp_path / "far.csv"
    far.write_text("name,x,y,z\nP1,0,0,0\nP2,1,1,1\n")
    assert main(["diagnose", "motion", "--stream", str(stream), "--poses", str(far), "--rate-hz", "333.3333"]) == 2
    assert "poses file" in capsys.readouterr().err
    prog = tmp_path / "prog.json"
    prog.write_text('{"dwell": 2.0}')
    assert main(["diagnose", "motion", "--stream", str(stream), "--poses", str(poses), "--program", str(prog)]) == 2
    assert "dwell" in (err := capsys.readouterr().err) and "is not a key of a program" in err
    bad = tmp_path / "m.json"
    bad.write_text(json.dumps(_model(creep={"amplitude_mm": 40.0, "tau_s": 0.1})))
    assert main(["simulate", "iso9283", "--out", str(tmp_path / "s"), "--motion-model", str(bad)]) == 2
    assert "effects.creep.amplitude_mm" in capsys.readouterr().err
