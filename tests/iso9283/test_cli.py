"""`station analyze iso9283`: files in, table and JSON out, malformed files refused by line and column."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from app.cli import main

from .synth import NAMES5, iso_stream, random_offsets


def write_poses(path, names=NAMES5, poses=TABLE2_POSES_MM):
    path.write_text("name,x,y,z\n" + "".join(f"{n},{p[0]},{p[1]},{p[2]}\n" for n, p in zip(names, poses)))
    return path


def write_stream(path, t, xyz, status=None):
    cols = [t, xyz[:, 0], xyz[:, 1], xyz[:, 2]]
    with open(path, "w") as f:
        f.write("t,x,y,z" + (",status" if status is not None else "") + "\n")
        for i in range(t.size):  # test data writer
            row = ",".join("" if np.isnan(c[i]) else f"{c[i]:.6f}" for c in cols)
            f.write(row + (f",{status[i]}" if status is not None else "") + "\n")
    return path


@pytest.fixture
def stream(rng):
    return iso_stream(rng, n_cycles=4, rate_hz=100.0, offsets_mm=random_offsets(rng), scatter_mm=0.03,
                      noise_mm=0.01, wn_hz=8.0, zeta=0.6, beam_breaks=[(rng.uniform(3.0, 8.0), 0.3)],
                      breaks_as_status=True)


def test_files_in_table_and_json_out(tmp_path, stream, capsys):
    s = stream
    status = np.where(s.valid, "ok", "beam_broken")
    S = write_stream(tmp_path / "S.csv", s.t, s.xyz, status)
    P = write_poses(tmp_path / "P.csv")
    out = tmp_path / "r.json"
    rc = main(["analyze", "iso9283", "--stream", str(S), "--poses", str(P), "--limit-mm", "0.5", "--json", str(out),
               "--order", "P2,P3,P4,P5,P1"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "pose" in text and "AP_mm" in text and all(f"\n{n} " in text for n in NAMES5)
    assert "PASS RP_mm" in text and "overall: PASS" in text
    d = json.loads(out.read_text())
    xyz = np.round(s.xyz, 6)
    ref = analyze_iso9283(np.round(s.t, 6), np.where(s.valid[:, None], xyz, 0.0), TABLE2_POSES_MM, names=NAMES5,
                          valid=s.valid, order=["P2", "P3", "P4", "P5", "P1"], band_mm=0.5, limits={"RP_mm": 0.5},
                          extraction=dict(initial_rest_stop=False))  # as the command (--initial-rest skip)
    for n in NAMES5:
        assert d["poses"][n]["RP_mm"] == pytest.approx(ref.poses[n].repeatability.RP_mm, abs=1e-6)
        assert d["poses"][n]["AP_mm"] == pytest.approx(ref.poses[n].accuracy.AP_mm, abs=1e-6)
        assert d["poses"][n]["band_source"] == "limit" and d["poses"][n]["band_mm"] == 0.5
        # P1 also stands still before the first move: left out by default (the seed's method)
        assert d["poses"][n]["n_cycles"] == 4
        # attained rows are data rows of the file: its line is row + 2
        rows = d["poses"][n]["attained"]["row"]
        assert np.allclose(xyz[rows, 0], d["poses"][n]["attained"]["x_mm"], atol=1e-6)
    assert d["stream"]["n_invalid"] == int((~s.valid).sum()) > 0
    assert d["extraction"]["order"] == ["P2", "P3", "P4", "P5", "P1"]
    assert d["passed"] is True


def test_failing_verdict_gives_exit_code_1(tmp_path, stream, capsys):
    s = stream
    S = write_stream(tmp_path / "S.csv", s.t, s.xyz, np.where(s.valid, 0, 1))
    P = write_poses(tmp_path / "P.csv")
    rc = main(["analyze", "iso9283", "--stream", str(S), "--poses", str(P), "--limit-mm", "0.001", "--band", "own",
               "--limit", "AP_mm=100"])
    text = capsys.readouterr().out
    assert rc == 1 and "FAIL RP_mm" in text and "PASS AP_mm" in text and "overall: FAIL" in text
    assert "own_RP" in text


def _run_err(capsys, *argv):
    rc = main(["analyze", "iso9283", *argv])
    return rc, capsys.readouterr().err


def test_malformed_files_are_refused_naming_line_and_column(tmp_path, stream, capsys):
    s = stream
    P = write_poses(tmp_path / "P.csv")
    good = write_stream(tmp_path / "S.csv", s.t[s.valid][:300], s.xyz[s.valid][:300])
    lines = good.read_text().splitlines()

    def variant(name, k, new):
        ls = list(lines)
        ls[k] = new
        p = tmp_path / name
        p.write_text("\n".join(ls) + "\n")
        return str(p)

    cases = [
        (variant("nan.csv", 57, "5.6,nan,1,2"), "line 58, column 'x'"),
        (variant("empty.csv", 40, "3.9,,1,2"), "line 41, column 'x'"),
        (variant("text.csv", 12, "1.1,2,abc,3"), "line 13, column 'y': 'abc' is not a number"),
        (variant("fields.csv", 99, "9.8,1,2"), "line 100: 3 fields, the header has 4"),
        (variant("header.csv", 0, "t,x,y"), "line 1: missing column(s) z"),
        (variant("dup.csv", 200, lines[199]), "line 201, column 't'"),
        (variant("unsorted.csv", 150, lines[150].replace(lines[150].split(",")[0], "0.5", 1)), "line 151, column 't'"),
    ]
    for path, msg in cases:
        rc, err = _run_err(capsys, "--stream", path, "--poses", str(P))
        assert rc == 2 and path in err and msg in err, (path, err)
    (tmp_path / "void.csv").write_text("")
    rc, err = _run_err(capsys, "--stream", str(tmp_path / "void.csv"), "--poses", str(P))
    assert rc == 2 and "empty file" in err
    rc, err = _run_err(capsys, "--stream", str(tmp_path / "nope.csv"), "--poses", str(P))
    assert rc == 2 and "cannot read" in err
    bad_p = tmp_path / "badp.csv"
    bad_p.write_text("name,x,y,z\nP1,0,1700,1400\nP1,1,2,3\n")
    rc, err = _run_err(capsys, "--stream", str(good), "--poses", str(bad_p))
    assert rc == 2 and "line 3, column 'name': duplicate pose 'P1'" in err
    bad_p.write_text("name,x,y,z\nP1,0,17x0,1400\n")
    rc, err = _run_err(capsys, "--stream", str(good), "--poses", str(bad_p))
    assert rc == 2 and "line 2, column 'y'" in err
    rc, err = _run_err(capsys, "--stream", str(good), "--poses", str(P), "--order", "P1,P7")
    assert rc == 2 and "P7" in err
    rc, err = _run_err(capsys, "--stream", str(good), "--poses", str(P), "--limit", "RP_mm")
    assert rc == 2 and "KEY=VALUE" in err
    rc, err = _run_err(capsys, "--stream", str(good), "--poses", str(P), "--limit", "XX_mm=1")
    assert rc == 2 and "unknown limit 'XX_mm'" in err


def test_console_script(tmp_path, stream):
    s = stream
    S = write_stream(tmp_path / "S.csv", s.t, s.xyz, np.where(s.valid, "ok", "beam"))
    P = write_poses(tmp_path / "P.csv")
    r = subprocess.run([sys.executable, "-m", "app.cli", "analyze", "iso9283", "--stream", str(S), "--poses",
                        str(P), "--json", str(tmp_path / "o.json")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "ISO 9283 analysis" in r.stdout and (tmp_path / "o.json").exists()
