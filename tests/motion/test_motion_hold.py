"""``station diagnose motion --hold H``: a held-pose record's fitted wander decides whether the tracker can be the
cause of a drift (the ``tracker_drift`` candidate is tested only when its wander over an approach window is
visible to the held-out test)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from app.cli import main
from station.analysis.motion.diagnose import RELEVANCE, hold_drift
from station.analysis.motion.windows import cut_windows

from .motion_stream import draw, make_stream


@pytest.fixture
def windows(rng):
    s = make_stream(draw(rng, cycles=2))
    return cut_windows(s.t_s, s.xyz_mm, s.poses_mm, s.names)


def test_hold_wander_sets_the_drift_test(windows, rng):
    w = windows
    span = np.array([np.nanmax(r) - np.nanmin(r) for r in w.t_s])
    wander, tau = rng.uniform(2e-3, 3e-3), rng.uniform(0.5, 5.0)
    h = hold_drift(w, {"white_mm": 6e-4, "wander_mm": wander, "wander_tau_s": tau, "source": "h.csv"})
    # eq. (N2): the wander's part of the semivariogram over the window's span, as a difference's sd
    D = float(np.median(span))
    assert h["window_s"] == pytest.approx(D)
    assert h["expected_drift_mm"] == pytest.approx(wander * math.sqrt(2 * (1 - math.exp(-D / tau))))
    assert h["reason"] == ""  # micrometres of wander against a stream's ~1 um noise: visible
    # a tracker that does not wander (or wanders below what the test sees) is not the cause of a drift
    for quiet in ({"white_mm": 6e-4, "wander_mm": 0.0, "wander_tau_s": None},
                  {"white_mm": 6e-4, "wander_mm": 0.5 * RELEVANCE * w.noise_mm, "wander_tau_s": 0.1}):
        h = hold_drift(w, quiet)
        assert h["expected_drift_mm"] < RELEVANCE * w.noise_mm
        assert "not the tracker's" in h["reason"]


def _hold_csv(path, rng, wander_mm):
    """A held pose at 1000/3 Hz for 60 s: white noise and a Gauss-Markov wander (time constant 2 s)."""
    n, dt = 20000, 0.003
    phi = math.exp(-dt / 2.0)
    e = rng.normal(0.0, wander_mm * math.sqrt(1 - phi * phi), (n, 3))
    g = np.zeros((n, 3))
    for k in range(1, n):
        g[k] = phi * g[k - 1] + e[k]
    xyz = np.array([900.0, -200.0, 400.0]) + g + rng.normal(0.0, 6e-4, (n, 3))
    t = np.arange(n) * dt
    path.write_text("t,x,y,z\n" + "".join(f"{a:.6f},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}\n" for a, p in zip(t, xyz)))
    return path


@pytest.mark.timeout(900)  # one diagnosis: slow on a shared machine
def test_a_quiet_tracker_is_not_the_drift(tmp_path, rng):
    from .real_arm import draw as draw_arm, make, write_export, write_poses

    ra = make(draw_arm(rng))
    stream, poses = write_export(tmp_path / "lab.txt", ra), write_poses(tmp_path / "poses.csv", ra)
    hold = _hold_csv(tmp_path / "hold.csv", rng, 0.0)
    out = tmp_path / "d.json"
    assert main(["diagnose", "motion", "--stream", str(stream), "--poses", str(poses), "--rate-hz", "333.333333",
                 "--hold", str(hold), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["hold"]["wander_mm"] == 0.0 and doc["hold"]["white_mm"] == pytest.approx(6e-4, rel=0.1)
    assert "not the tracker's" in doc["not_testable"]["tracker_drift"]
    assert "tracker_drift" not in [s["effect"] for s in doc["steps"]]
    assert all(ct["candidate"] != "tracker_drift" for ct in doc["remaining_structure"])  # never tested


def test_hold_on_a_failed_clock_is_refused(tmp_path, rng, capsys):
    """A hold whose stamps fail their check gives no wander time constant: refused before the diagnosis."""
    from tests.iso9283.ur_lookalike import LabLookalike, pc_stamps, write_lab_export

    n = 6000
    xyz = np.array([900.0, -200.0, 400.0]) + rng.normal(0.0, 6e-4, (n, 3))
    hold = write_lab_export(tmp_path / "hold.txt", LabLookalike(xyz, xyz[:2], pc_stamps(rng, n), 0.0,
                                                                np.array([]), 0))
    poses = tmp_path / "poses.csv"
    poses.write_text("name,x,y,z\nP1,0,0,0\nP2,100,0,0\n")
    assert main(["diagnose", "motion", "--stream", str(hold), "--poses", str(poses), "--hold", str(hold)]) == 2
    assert "--hold" in capsys.readouterr().err
