"""`station simulate iso9283`: files, columns, and 3 x 5 stops in the stream."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from app.cli import main
from fakes.sim.iso_run import simulate_iso9283


def _stops_in_stream(t, xyz, valid, speed_mm_s=5.0, min_s=0.3):
    """Runs where the displacement over 0.1 s stays under ``speed_mm_s`` for ``min_s`` or more."""
    rate = 1.0 / np.median(np.diff(t))
    w = max(int(round(0.1 * rate)), 1)
    disp = np.linalg.norm(xyz[w:] - xyz[:-w], axis=1) / (t[w:] - t[:-w])
    both = valid[w:] & valid[:-w]
    still = np.where(both, disp < speed_mm_s, True)  # a beam break does not split a stop
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    runs = edges.reshape(-1, 2)
    keep = (t[runs[:, 1] - 1 + w] - t[runs[:, 0]]) >= min_s
    return runs[keep]


def test_simulate_writes_stream_poses_truth(tmp_path):
    out = tmp_path / "run"
    summary = simulate_iso9283(out, cycles=3, dwell_s=0.5, rate_hz=250.0, seed=3, wait_s=1.0,
                               beam_breaks=[(0.2, 0.5)])
    with open(out / "stream.csv") as fh:
        header = next(csv.reader(fh))
    assert header == ["t", "x", "y", "z", "status"]
    data = np.genfromtxt(out / "stream.csv", delimiter=",", names=True)
    assert data.size == summary["n_samples"]
    t = data["t"]
    xyz = np.column_stack([data["x"], data["y"], data["z"]])
    valid = data["status"] == 0
    np.testing.assert_allclose(np.diff(t), 1 / 250.0, rtol=1e-3)  # every sample, on the device grid
    assert (~valid).sum() == summary["n_invalid"] == pytest.approx(0.3 * 250, abs=1)
    assert np.isnan(xyz[~valid]).all() and np.isfinite(xyz[valid]).all()

    with open(out / "poses.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["name", "x", "y", "z"]
    assert [r[0] for r in rows[1:]] == ["P1", "P2", "P3", "P4", "P5"]
    cmd = np.array([[float(v) for v in r[1:]] for r in rows[1:]])

    truth = json.loads((out / "truth.json").read_text())
    T = np.array(truth["base_T_tracker"])
    base = np.array([truth["commanded"][n]["base_mm"] for n in ("P1", "P2", "P3", "P4", "P5")])
    np.testing.assert_allclose(base, [[0, 1700, 1400], [-500, 2200, 1900], [500, 2200, 1900],
                                      [500, 1200, 900], [-500, 1200, 900]])
    np.testing.assert_allclose((T[:3, :3] @ cmd.T).T + T[:3, 3], base, atol=1e-3)
    assert len(truth["stops"]) == 15
    assert [s["pose"] for s in truth["stops"][:5]] == ["P2", "P3", "P4", "P5", "P1"]
    assert truth["world"]["effects"]["geometric"]["enabled"] is True

    # the stream shows the initial wait plus 3 x 5 stops, in order, near their poses
    runs = _stops_in_stream(t, xyz, valid)
    assert len(runs) == 1 + 15
    order = ["P1"] + ["P2", "P3", "P4", "P5", "P1"] * 3
    names = ["P1", "P2", "P3", "P4", "P5"]
    for (a, b), name, stop in zip(runs, order, [None] + truth["stops"]):
        seg = xyz[a:b][valid[a:b]]
        mean = seg.mean(axis=0)
        assert np.linalg.norm(mean - cmd[names.index(name)]) < 10.0  # AP of a few mm
        if stop is not None:
            # the true attained position agrees with the stream within the tracker noise
            assert np.linalg.norm(np.median(seg[-20:], axis=0) - np.array(stop["true_tracker_mm"])) < 0.1


def test_cli_simulate(tmp_path, capsys):
    out = tmp_path / "cli"
    rc = main(["simulate", "iso9283", "--out", str(out), "--cycles", "1", "--rate", "100", "--seed", "4",
               "--wait", "0.5"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "stream.csv" in text and "samples" in text and "5 stops" in text
    assert (out / "stream.csv").exists() and (out / "poses.csv").exists() and (out / "truth.json").exists()


@pytest.mark.parametrize("argv, message", [
    (["--rate", "5"], "--rate"),
    (["--cycles", "0"], "--cycles"),
    (["--dwell", "-1"], "--dwell"),
    (["--robot", "nachi"], "unknown robot"),
    (["--beam-break", "3"], "--beam-break"),
])
def test_cli_refuses_bad_options(tmp_path, capsys, argv, message):
    rc = main(["simulate", "iso9283", "--out", str(tmp_path / "bad")] + argv)
    assert rc == 2
    assert message in capsys.readouterr().err
