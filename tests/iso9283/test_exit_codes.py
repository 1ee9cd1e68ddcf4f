"""Exit codes a pipeline can trust: 0 only when every asked limit was decided and passed.

1 a limit failed, 2 bad input, 3 not decided (a limit not computed, a pose without an attained pose, a
stop far from every pose), 4 not ISO conformant under --require-iso; the reasons on stderr.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from station.analysis.iso9283.poses import TABLE2_POSES_MM
from app.cli import main

from .labfiles import write_poses, write_stream_csv
from .synth import NAMES5, Programme, iso_cycle_programme, iso_stream, random_offsets, render

CMD = np.array(TABLE2_POSES_MM)
SERVO = dict(wn_hz=10.0, zeta=0.8)


def run(capsys, *argv):
    rc = main(["analyze", "iso9283", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.fixture
def files(rng, tmp_path):
    s = iso_stream(rng, n_cycles=3, rate_hz=100.0, offsets_mm=random_offsets(rng), scatter_mm=0.02, noise_mm=0.005,
                   **SERVO)
    return s, write_stream_csv(tmp_path / "S.csv", s.t, s.xyz), write_poses(tmp_path / "P.csv", NAMES5, CMD)


def test_pass_fail_undecided_and_require_iso(tmp_path, files, capsys):
    s, S, P = files
    rc, out, err = run(capsys, "--stream", S, "--poses", P, "--limit-mm", "5", "--json", tmp_path / "a.json")
    assert rc == 0 and err == ""
    # the console says the run is not ISO conformant even when the limits pass
    assert "overall: PASS on the limits asked; NOT ISO 9283 conformant" in out
    assert "ISO 9283 conformant: no: fewer than 30 cycles" in out
    rc, out, err = run(capsys, "--stream", S, "--poses", P, "--limit-mm", "5", "--require-iso")
    assert rc == 4 and "station: exit 4: not ISO 9283 conformant (--require-iso): fewer than 30 cycles" in err
    rc, out, err = run(capsys, "--stream", S, "--poses", P, "--limit-mm", "1e-4", "--band", "own")
    assert rc == 1 and "station: exit 1: RP_mm P1 = " in err and "exceeds the limit 0.0001" in err
    # one approach direction: vAP cannot be decided; AT without linear paths is not computed
    rc, out, err = run(capsys, "--stream", S, "--poses", P, "--limit", "vAP_mm=1", "--limit", "AT_mm=1",
                       "--json", tmp_path / "u.json")
    assert rc == 3
    assert "vAP_mm P1 not decided (1 approach direction(s), 3 needed)" in err
    assert "limit(s) given for characteristics this analysis did not compute: AT_mm" in err
    assert json.loads((tmp_path / "u.json").read_text())["exit"]["code"] == 3
    # a failed limit wins over an undecided one
    rc, _, err = run(capsys, "--stream", S, "--poses", P, "--limit", "vAP_mm=1", "--limit-mm", "1e-4", "--band", "own")
    assert rc == 1 and "not decided" in err and "exceeds the limit" in err


def test_a_stop_far_from_every_pose_is_not_decided_unless_expected(tmp_path, rng, capsys):
    prog = iso_cycle_programme(rng, n_cycles=3, scatter_mm=0.02, dwell_s=0.5)
    k = int(rng.integers(3, prog.pose.size - 3))
    via = 0.5 * (prog.target_mm[k - 1] + prog.target_mm[k]) + rng.normal(0, 30, 3)
    ins = lambda a, v: np.insert(a, k, v, axis=0)  # noqa: E731
    prog2 = Programme(ins(prog.target_mm, via), ins(prog.dwell_s, 0.5), ins(prog.pose, -1), ins(prog.cycle, -1),
                      ins(prog.direction, -1))
    s = render(rng, prog2, start_mm=CMD[0], rate_hz=100.0, noise_mm=0.005, **SERVO)
    S = write_stream_csv(tmp_path / "S.csv", s.t, s.xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "--stream", S, "--poses", P, "--limit-mm", "5")
    d_near = np.linalg.norm(CMD - via, axis=1).min()
    assert rc == 3 and "1 stop(s) lie farther than 25 mm from every commanded pose" in err
    assert abs(float(err.split("mm from every commanded pose (row ")[1].split()[1]) - d_near) < 0.5
    assert "--allow-other-stops" in err
    assert "left out:" in out and "farther than the assignment tolerance 25 mm" in out
    rc, _, err = run(capsys, "--stream", S, "--poses", P, "--limit-mm", "5", "--allow-other-stops")
    assert rc == 0, err
    # with an AP limit the tolerance follows it: 4 (AP + RP)
    rc, out, _ = run(capsys, "--stream", S, "--poses", P, "--limit-mm", "0.5", "--limit", "AP_mm=2",
                     "--allow-other-stops")
    assert "assignment tolerance 10 mm" in out


def test_a_held_stream_is_refused_with_a_pointer_to_hold(tmp_path, rng, capsys):
    t = np.arange(2000) / 100.0
    xyz = CMD[0] + rng.normal(0, 0.005, (t.size, 3))
    S = write_stream_csv(tmp_path / "H.csv", t, xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, _, err = run(capsys, "--stream", S, "--poses", P)
    assert rc == 2 and "no move found" in err and "station analyze hold" in err
