"""Poses in the robot base frame with a registration (`--register`) or a known frame (`--frame`).

The stream is drawn in the base frame and carried into a tracker frame by a random rigid transform.
With the frame the figures equal those of the base-frame stream; with a registration, those of the
stream carried back by an independent fit (scipy's Kabsch) of the same pairs.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.poses import TABLE1_CORNERS_MM, TABLE2_POSES_MM
from app.cli import main

from .labfiles import random_rotation, write_frame, write_poses, write_registration, write_stops, write_stream_csv
from .synth import NAMES5, iso_stream, random_offsets

CMD = np.array(TABLE2_POSES_MM)
SERVO = dict(wn_hz=10.0, zeta=0.8)
#: these lab programs start at rest at their first pose and count that rest as its stop (the command's
#: `--initial-rest count`; the library's `initial_rest_stop`)
COUNT = dict(initial_rest_stop=True)


def run(capsys, *argv):
    rc = main(["analyze", "iso9283", "--initial-rest", "count", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.fixture
def cell(rng, tmp_path):
    R = random_rotation(rng)
    t = rng.uniform(-4000, 4000, 3)
    s = iso_stream(rng, n_cycles=3, rate_hz=100.0, offsets_mm=random_offsets(rng), scatter_mm=0.02, noise_mm=0.005,
                   **SERVO)
    trk = s.xyz @ R.T + t
    S = write_stream_csv(tmp_path / "S.csv", s.t, trk)
    P = write_poses(tmp_path / "P_base.csv", NAMES5, CMD)
    return dict(R=R, t=t, s=s, S=S, P=P, trk=np.round(trk, 6))


def test_frame_file_gives_the_base_frame_figures(tmp_path, cell, capsys):
    F = write_frame(tmp_path / "frame.json", cell["R"], cell["t"], rms_mm=0.1, method="best-fit")
    rc, out, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--frame", F, "--json", tmp_path / "r.json")
    assert rc == 0, err
    assert "frame:" in out and "method best-fit, rms 0.100 mm" in out
    d = json.loads((tmp_path / "r.json").read_text())
    base = (cell["trk"] - cell["t"]) @ cell["R"]
    ref = analyze_iso9283(cell["s"].t, base, CMD, names=NAMES5, extraction=COUNT)
    for n in NAMES5:
        assert d["poses"][n]["AP_mm"] == pytest.approx(ref.poses[n].accuracy.AP_mm, abs=1e-6)
        assert d["poses"][n]["RP_mm"] == pytest.approx(ref.poses[n].repeatability.RP_mm, abs=1e-6)
    assert d["registration"]["source"] == "frame"


def test_registration_pairs_fit_printed_and_used(tmp_path, cell, rng, capsys):
    base_pts = np.array(TABLE1_CORNERS_MM)[rng.permutation(8)[: int(rng.integers(3, 9))]]
    noise = 0.005
    trk_pts = base_pts @ cell["R"].T + cell["t"] + rng.normal(0, noise, base_pts.shape)
    names = [f"C{k}" for k in range(len(base_pts))]
    Rg = write_registration(tmp_path / "reg.csv", names, base_pts, trk_pts)
    rc, out, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--register", Rg,
                       "--json", tmp_path / "r.json")
    assert rc == 0, err
    # independent fit of the same pairs (as written: 6 decimals)
    bw, tw = np.round(base_pts, 6), np.round(trk_pts, 6)
    rot, _ = Rotation.align_vectors(tw - tw.mean(axis=0), bw - bw.mean(axis=0))
    Rf = rot.as_matrix()
    tf = tw.mean(axis=0) - Rf @ bw.mean(axis=0)
    res = np.linalg.norm(bw @ Rf.T + tf - tw, axis=1)
    assert f"fit rms {np.sqrt(np.mean(res ** 2)):.4f} mm" in out
    for nm, r in zip(names, res):
        assert f"{nm:<12} residual {r:.4f} mm" in out
    d = json.loads((tmp_path / "r.json").read_text())
    ref = analyze_iso9283(cell["s"].t, (cell["trk"] - tf) @ Rf, CMD, names=NAMES5, extraction=COUNT)
    for n in NAMES5:
        assert d["poses"][n]["AP_mm"] == pytest.approx(ref.poses[n].accuracy.AP_mm, abs=1e-6)
        assert d["poses"][n]["RP_mm"] == pytest.approx(ref.poses[n].repeatability.RP_mm, abs=1e-6)
    assert d["registration"]["rms_mm"] == pytest.approx(np.sqrt(np.mean(res ** 2)), abs=1e-9)


def test_a_wrong_frame_is_not_decided_and_bad_registrations_exit_2(tmp_path, cell, rng, capsys):
    # base-frame poses against the tracker-frame stream: every stop metres from every pose
    rc, out, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--limit-mm", "0.5",
                       "--json", tmp_path / "r.json")
    assert rc == 3
    assert "lie farther than" in err and "are the poses in another frame? give --frame or --register" in err
    assert "overall: not decided" in out and "NOT ISO 9283 conformant" in out
    assert json.loads((tmp_path / "r.json").read_text())["exit"]["code"] == 3
    base_pts = np.array(TABLE1_CORNERS_MM)
    trk_pts = base_pts @ cell["R"].T + cell["t"] + rng.normal(0, 0.005, base_pts.shape)
    names = [f"C{k}" for k in range(8)]
    two = write_registration(tmp_path / "two.csv", names[:2], base_pts[:2], trk_pts[:2])
    rc, _, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--register", two,
                     "--json", tmp_path / "x.json")
    assert rc == 2 and "two.csv: a registration needs at least 3 point pairs" in err
    assert not (tmp_path / "x.json").exists()
    i, j = rng.choice(8, 2, replace=False)  # two pairs swapped: the fit cannot match them
    sw = trk_pts.copy()
    sw[[i, j]] = sw[[j, i]]
    bad = write_registration(tmp_path / "swap.csv", names, base_pts, sw)
    rc, out, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--register", bad,
                       "--json", tmp_path / "x.json")
    assert rc == 2 and "is far above what the points' noise explains" in err and "residual" in out
    assert not (tmp_path / "x.json").exists()
    # the same registration is accepted when told the error to allow
    rms = float(out.split("fit rms ")[1].split(" mm")[0])
    rc, _, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--register", bad,
                     "--register-max-rms-mm", rms * 1.01)
    assert rc in (0, 3), err  # accepted; the frame is wrong, so the stops may not match
    notrot = write_frame(tmp_path / "bad.json", 2 * cell["R"], cell["t"])
    rc, _, err = run(capsys, "--stream", cell["S"], "--poses", cell["P"], "--frame", notrot)
    assert rc == 2 and "R is not a rotation" in err


def test_stop_list_in_the_tracker_frame_with_base_frame_poses(tmp_path, rng, capsys):
    R, t = random_rotation(rng), rng.uniform(-3000, 3000, 3)
    n = 5
    pose = [nm for _ in range(n) for nm in NAMES5]
    cycle = np.repeat(np.arange(n), 5)
    base = np.array([CMD[NAMES5.index(p)] for p in pose]) + rng.normal(0, 0.03, (len(pose), 3))
    S = write_stops(tmp_path / "s.csv", pose, cycle, (base @ R.T + t)[:, None, :])
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    F = write_frame(tmp_path / "f.json", R, t)
    rc, _, err = run(capsys, "--stops", S, "--poses", P, "--frame", F, "--json", tmp_path / "r.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "r.json").read_text())
    for p, nm in enumerate(NAMES5):
        att = base[np.array(pose) == nm]
        assert d["poses"][nm]["AP_mm"] == pytest.approx(np.linalg.norm(att.mean(axis=0) - CMD[p]), abs=1e-5)
    rc, _, err = run(capsys, "--stops", S, "--poses", P)
    assert rc == 3 and "25 stop(s) lie farther than 25 mm from their commanded pose" in err
