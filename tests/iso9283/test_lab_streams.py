"""`station analyze iso9283 --stream` on the files a lab exports: SpatialAnalyzer, point lists, bad clocks.

Figures are checked against the equations written out in the test (eqs. (1)-(2)) on the file's own
points at the rows the analysis reports, and against the synthetic truth within the noise.
"""

from __future__ import annotations

import json
import math
from datetime import timedelta

import numpy as np
import pytest

from station.analysis.iso9283.characteristics import analyze_iso9283
from station.analysis.iso9283.poses import TABLE2_POSES_MM
from app.cli import main

from .conftest import chi3_q
from .labfiles import MM_PER, T0, ap_ref, rp_ref, write_points, write_poses, write_sa
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


def check_figures(d, xyz_file, off, sig):
    """AP, RP of every pose from the file's points at the reported rows, and against the truth."""
    for p, name in enumerate(NAMES5):
        pj = d["poses"][name]
        rows = np.array(pj["attained"]["row"])
        att = xyz_file[rows]
        assert np.allclose(att[:, 0], pj["attained"]["x_mm"], atol=2e-6)
        assert pj["AP_mm"] == pytest.approx(ap_ref(att, CMD[p]), abs=1e-5)
        assert pj["RP_mm"] == pytest.approx(rp_ref(att), abs=1e-5)
        n = len(rows)
        assert abs(pj["AP_mm"] - np.linalg.norm(off[p])) < chi3_q(1e-6) * sig / math.sqrt(n) + 0.01


def test_spatialanalyzer_export_in_any_unit_with_a_stray_group(tmp_path, rng, capsys):
    unit = str(rng.choice(list(MM_PER)))
    off = random_offsets(rng)
    s = iso_stream(rng, n_cycles=3, rate_hz=100.0, offsets_mm=off, scatter_mm=0.02, noise_mm=0.005, **SERVO)
    stray = rng.uniform(-500, 500, (int(rng.integers(1, 4)), 3))
    f = write_sa(tmp_path / "export.txt", s.xyz, t_s=s.t, unit=unit, stray=stray)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "--stream", f, "--poses", P, "--limit-mm", "0.5", "--json", tmp_path / "r.json")
    assert rc == 0, err
    assert f"note: group 'Scratch' ({len(stray)} points" in out and "left out" in out
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["input"]["format"] == "sa" and d["input"]["units"] == unit and d["input"]["group"] == "Stream"
    assert d["stream"]["n_rows"] == s.t.size  # the stray group is not part of the stream
    check_figures(d, s.xyz, off, math.hypot(0.02, 0.005))
    assert d["exit"] == {"code": 0, "reasons": []}


def test_point_list_with_the_sample_rate(tmp_path, rng, capsys):
    off = random_offsets(rng)
    rate = float(rng.choice([100.0, 200.0]))
    s = iso_stream(rng, n_cycles=3, rate_hz=rate, offsets_mm=off, scatter_mm=0.02, noise_mm=0.005, **SERVO)
    f = write_points(tmp_path / "pts.txt", s.xyz, sep=str(rng.choice([" ", "\t", ","])))
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "--stream", f, "--poses", P)
    assert rc == 2 and "has no time stamps: give the sample rate with --rate-hz" in err
    rc, out, err = run(capsys, "--stream", f, "--poses", P, "--rate-hz", rate, "--json", tmp_path / "r.json")
    assert rc == 0, err
    assert f"time base: sample index / {rate:g} Hz" in out
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["time_base"] == {"source": "sample_index", "rate_hz": rate}
    check_figures(d, s.xyz, off, math.hypot(0.02, 0.005))
    # the synthetic stream is sampled at exactly i / rate: the same analysis as on its own time stamps
    ref = analyze_iso9283(s.t, np.round(s.xyz, 6), CMD, names=NAMES5, extraction=COUNT)
    for name in NAMES5:
        assert d["poses"][name]["attained"]["row"] == ref.poses[name].attained_row.tolist()
        assert d["poses"][name]["PST_s"] == pytest.approx(ref.poses[name].overshoot.PST_s, abs=1e-6)


def test_coarse_drifting_time_stamps_give_an_estimated_rate_then_the_rate_gives_the_true_time_base(
        tmp_path, rng, capsys):
    rate = 100.0
    off = random_offsets(rng)
    s = iso_stream(rng, n_cycles=3, rate_hz=rate, offsets_mm=off, scatter_mm=0.02, noise_mm=0.005, **SERVO)
    drift = rng.uniform(-3e-3, 3e-3)  # the logging PC's clock runs off the tracker's sampling
    t_pc = s.t * (1.0 + drift) + rng.uniform(0, 1)
    stamps = [(T0 + timedelta(seconds=math.floor(t))).strftime("%m/%d/%Y %I:%M:%S %p") for t in t_pc]  # 1 s steps
    f = write_sa(tmp_path / "coarse.txt", s.xyz, stamps=stamps)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "--stream", f, "--poses", P, "--json", tmp_path / "est.json")
    assert rc == 0, err
    assert "the rate ESTIMATED from the coarse stamps" in out and "PST_s*" in out
    tb = json.loads((tmp_path / "est.json").read_text())["time_base"]
    assert tb["source"] == "estimated_rate"
    # the PC's seconds hold rate / (1 + drift) samples; the whole intervals' count is off by less than a sample
    span = tb["estimate"]["n_intervals"] * tb["estimate"]["stamp_resolution_s"]
    assert abs(tb["rate_hz"] - rate / (1.0 + drift)) < 1.0 / span + 1e-9
    rc, out, err = run(capsys, "--stream", f, "--poses", P, "--rate-hz", rate, "--json", tmp_path / "r.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "r.json").read_text())
    ref = analyze_iso9283(s.t, np.round(s.xyz, 6), CMD, names=NAMES5, extraction=COUNT)
    for name in NAMES5:
        pj, pr = d["poses"][name], ref.poses[name]
        assert pj["attained"]["row"] == pr.attained_row.tolist()
        assert pj["PST_s"] == pytest.approx(pr.overshoot.PST_s, abs=1e-6)
    assert [m["MPT_s"] for m in d["MPT"]] == pytest.approx([m.MPT_s for m in ref.posing_times], abs=1e-6)


def test_windows_in_samples_make_the_chosen_samples_independent_of_the_rate(tmp_path, rng, capsys):
    s = iso_stream(rng, n_cycles=3, rate_hz=100.0, offsets_mm=random_offsets(rng), scatter_mm=0.02, noise_mm=0.02,
                   wn_hz=6.0, zeta=0.5)
    f = write_points(tmp_path / "pts.txt", s.xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    out = {}
    r1 = 100.0
    r2 = float(rng.uniform(1.2, 3.0)) * r1
    for r in (r1, r2):
        rc, _, err = run(capsys, "--stream", f, "--poses", P, "--rate-hz", r, "--window-samples", 11,
                         "--json", tmp_path / f"{r}.json")
        assert rc == 0, err
        out[r] = json.loads((tmp_path / f"{r}.json").read_text())
    a, b = out[r1], out[r2]
    assert a["extraction"]["M"] == b["extraction"]["M"] == 5
    for name in NAMES5:
        pa, pb = a["poses"][name], b["poses"][name]
        assert pa["attained"]["row"] == pb["attained"]["row"]
        assert pa["overshoot_per_cycle"]["row_settled"] == pb["overshoot_per_cycle"]["row_settled"]
        assert pb["PST_s"] == pytest.approx(pa["PST_s"] * r1 / r2, abs=1e-6)
    assert [m["MPT_s"] for m in b["MPT"]] == pytest.approx([m["MPT_s"] * r1 / r2 for m in a["MPT"]], abs=1e-6)
    rc, _, err = run(capsys, "--stream", f, "--poses", P, "--window-samples", 11)
    assert rc == 2 and "--window-samples needs --rate-hz" in err
    rc, _, err = run(capsys, "--stream", f, "--poses", P, "--rate-hz", 100, "--window-samples", 10)
    assert rc == 2 and "odd number" in err


def test_bad_stream_files_exit_2_naming_file_and_line(tmp_path, rng, capsys):
    s = iso_stream(rng, n_cycles=2, rate_hz=100.0, **SERVO)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    good = write_sa(tmp_path / "g.txt", s.xyz[:300], t_s=s.t[:300]).read_text().splitlines()
    bad_units = list(good)
    bad_units[2] = "// AXES = CARTESIAN: X, Y, Z (furlong)"
    (tmp_path / "u.txt").write_text("\n".join(bad_units) + "\n")
    rc, _, err = run(capsys, "--stream", tmp_path / "u.txt", "--poses", P)
    assert rc == 2 and "u.txt: line 3: unknown length unit 'furlong'" in err
    mixed = good[:50] + [g.replace("Stream", "Other", 1) for g in good[50:60]] + good[60:]
    (tmp_path / "m.txt").write_text("\n".join(mixed) + "\n")
    rc, _, err = run(capsys, "--stream", tmp_path / "m.txt", "--poses", P)
    assert rc == 2 and "m.txt: line 61: group 'Stream' starts again after group 'Other'" in err
    k = int(rng.integers(10, 290))
    nan = list(good)
    cells = nan[k].split(",")
    cells[5] = " nan"
    nan[k] = ",".join(cells)
    (tmp_path / "n.txt").write_text("\n".join(nan) + "\n")
    rc, _, err = run(capsys, "--stream", tmp_path / "n.txt", "--poses", P, "--json", tmp_path / "x.json")
    assert rc == 2 and f"n.txt: line {k + 1}, column 'z'" in err and not (tmp_path / "x.json").exists()
    rc, _, err = run(capsys, "--stream", tmp_path / "g.txt", "--poses", P, "--format", "csv")
    assert rc == 2 and "missing column" in err
    rc, _, err = run(capsys, "--stream", tmp_path / "g.txt")
    assert rc == 2 and "--poses is required with --stream" in err
