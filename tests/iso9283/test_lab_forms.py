"""Lab files in the forms labs export them: date forms, coarse stamps, per-pose reflector lists, pipes.

Each file is written from simulated truth; the figures must equal those of the project's own CSV path (the
same points and times written as ``t,x,y,z`` or ``pose,cycle,reflector,x,y,z``) and the truth within the
noise. The sample files in ``samples/`` (copies of the lab-form samples) are read as they are.
"""

from __future__ import annotations

import io
import json
import math
import os
import threading
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from station.analysis.iso9283.poses import TABLE2_POSES_MM
from station.analysis.iso9283.lab_files import stream_time_base
from app.cli import main
from station.readers.spatial_analyzer import read_sa_points

from .conftest import chi3_q
from .labfiles import ap_ref, rp_ref, write_poses, write_sa, write_stops
from .synth import NAMES5, iso_stream, random_offsets

CMD = np.array(TABLE2_POSES_MM)
SERVO = dict(wn_hz=10.0, zeta=0.8)
SAMPLES = Path(__file__).parent / "samples"
SA_HEADER_LINES = 4  # write_sa's comment lines: row i is on line i + 5


def run(capsys, *argv):
    rc = main(["analyze", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def as_written(xyz):
    """The coordinates as write_sa writes them (10 decimals), read back."""
    return np.array([[float(f"{v:.10f}") for v in row] for row in xyz])


def write_csv_exact(path, t, xyz):
    """The project's stream CSV with every value as it stands (repr)."""
    path.write_text("t,x,y,z\n" + "".join(f"{float(a)!r},{float(b[0])!r},{float(b[1])!r},{float(b[2])!r}\n"
                                          for a, b in zip(t, xyz)))
    return path


def figures(d):
    return ({n: (p["AP_mm"], p["RP_mm"], p["PST_s"]) for n, p in d["poses"].items()},
            [m["MPT_s"] for m in d["MPT"]])


def assert_same_figures(a, b, tol=1e-7):
    pa, ma = figures(a)
    pb, mb = figures(b)
    assert pa.keys() == pb.keys()
    for n in pa:
        assert pa[n] == pytest.approx(pb[n], abs=tol), n
    assert ma == pytest.approx(mb, abs=tol)


def assert_truth(d, off, sig):
    for p, name in enumerate(NAMES5):
        pj = d["poses"][name]
        n = len(pj["attained"]["row"])
        assert abs(pj["AP_mm"] - np.linalg.norm(off[p])) < chi3_q(1e-6) * sig / math.sqrt(n) + 0.01


def stream_and_truth(rng, rate=100.0):
    off = random_offsets(rng)
    s = iso_stream(rng, n_cycles=3, rate_hz=rate, offsets_mm=off, scatter_mm=0.02, noise_mm=0.005, **SERVO)
    return s, off, math.hypot(0.02, 0.005)


def stamp_times(f, t_written, **kw):
    """The reader's times of an export, checked against the times written (to 1 ns); the CSV path gets these
    (the extraction's sample counts are sensitive to the last bit of a time, not to the form it came in)."""
    t = read_sa_points(f, **kw).t_s
    assert np.max(np.abs(t - t_written)) < 1e-9
    return t


def csv_path_json(tmp_path, capsys, t, xyz, P, name="ref", extra=()):
    C = write_csv_exact(tmp_path / f"{name}.csv", t, xyz)
    rc, _, err = run(capsys, "iso9283", "--stream", C, "--poses", P, "--json", tmp_path / f"{name}.json", *extra)
    assert rc == 0, err
    return json.loads((tmp_path / f"{name}.json").read_text())


FORMS = ("%m/%d/%y %H:%M:%S.%f", "%d/%m/%Y %H:%M:%S.%f", "%d.%m.%Y %H:%M:%S.%f", "%Y-%m-%dT%H:%M:%S.%f",
         "%Y/%m/%d %H:%M:%S.%f", "%m/%d/%Y %I:%M:%S.%f %p", "%d-%m-%Y %H:%M:%S.%f")


@pytest.mark.parametrize("form", FORMS)
def test_date_forms_give_the_csv_paths_figures(tmp_path, rng, capsys, form):
    s, off, sig = stream_and_truth(rng)
    # a day of the year and a time of day (12 h forms: afternoon and morning alike), far from midnight
    t0 = datetime(2025, 1, 1) + timedelta(days=int(rng.integers(0, 365)), seconds=float(rng.uniform(3600, 80000)))
    when = [t0 + timedelta(seconds=float(x)) for x in s.t]
    t_written = np.array([(w - when[0]).total_seconds() for w in when])
    f = write_sa(tmp_path / "export.txt", s.xyz, stamps=[w.strftime(form) for w in when])
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--json", tmp_path / "r.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["time_base"]["source"] == "stamps"
    ref = csv_path_json(tmp_path, capsys, stamp_times(f, t_written), as_written(s.xyz), P)
    assert_same_figures(d, ref)
    assert_truth(d, off, sig)


def midnight_run(rng, tmp_path, day, form):
    s, off, sig = stream_and_truth(rng)
    t0 = datetime(2025, 3, day, 23, 59, 59) - timedelta(seconds=float(rng.uniform(1.0, s.t[-1] - 1.0)))
    when = [t0 + timedelta(seconds=float(x)) for x in s.t]
    t_written = np.array([(w - when[0]).total_seconds() for w in when])
    f = write_sa(tmp_path / "night.txt", s.xyz, stamps=[w.strftime(form) for w in when])
    first_new = next(i for i, w in enumerate(when) if w.day != when[0].day)
    return s, off, sig, f, t_written, first_new


def test_a_run_over_midnight_asks_for_the_date_order_only_when_it_matters(tmp_path, rng, capsys):
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    # 03/11/25 -> 03/12/25: one day (month first) or thirty (day first); the file cannot say which
    s, off, sig, f, t_written, first_new = midnight_run(rng, tmp_path, 11, "%m/%d/%y %H:%M:%S.%f")
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P)
    assert rc == 2
    assert f"line {first_new + SA_HEADER_LINES + 1}, column 'date time'" in err
    assert "03/11 to 03/12" in err and "--date-order mdy" in err and "--date-order dmy" in err
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--date-order", "mdy",
                       "--json", tmp_path / "r.json")
    assert rc == 0, err
    assert "read as month/day (--date-order)" in out
    d = json.loads((tmp_path / "r.json").read_text())
    assert_same_figures(d, csv_path_json(tmp_path, capsys, stamp_times(f, t_written, date_order="mdy"),
                                         as_written(s.xyz), P))
    assert_truth(d, off, sig)
    # 13/03/2025 -> 14/03/2025: a field above 12 settles the order; nothing is asked
    s, off, sig, f, t_written, _ = midnight_run(rng, tmp_path, 13, "%d/%m/%Y %H:%M:%S.%f")
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--json", tmp_path / "r2.json")
    assert rc == 0, err
    assert "read as day/month (a date field above 12 says so)" in out
    d = json.loads((tmp_path / "r2.json").read_text())
    assert_same_figures(d, csv_path_json(tmp_path, capsys, stamp_times(f, t_written), as_written(s.xyz), P, "ref2"))
    # an order the dates contradict is refused
    rc, _, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--date-order", "mdy")
    assert rc == 2 and "--date-order mdy reads a month above 12" in err


def test_coarse_stamps_give_a_rate_estimated_from_them_said_and_marked(tmp_path, rng, capsys):
    rate = float(rng.uniform(120.0, 250.0))
    s, off, sig = stream_and_truth(rng, rate)
    phase = float(rng.uniform(0, 1))
    t0 = datetime(2025, 3, 11, 14, 7, 52)
    stamps = [(t0 + timedelta(seconds=math.floor(x + phase))).strftime("%m/%d/%y %H:%M:%S") for x in s.t]
    f = write_sa(tmp_path / "coarse.txt", s.xyz, stamps=stamps)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--json", tmp_path / "r.json")
    assert rc == 0, err
    assert "the rate ESTIMATED from the coarse stamps" in out and "PST_s*" in out and "MPT P" in out
    d = json.loads((tmp_path / "r.json").read_text())
    tb = d["time_base"]
    est = tb["rate_hz"]
    assert tb["source"] == "estimated_rate" and tb["estimated_figures"] == ["PST_s", "MPT_s", "drift"]
    assert all(p["PST_on_estimated_rate"] for p in d["poses"].values())
    assert all(m["on_estimated_rate"] for m in d["MPT"])
    span = tb["estimate"]["n_intervals"]
    assert abs(est - rate) <= 1.0 / span + 1e-9  # whole seconds hold the rate's samples, to a sample
    assert tb["estimate"]["spread_hz"] <= 1.0  # each second's count is the rate to within one sample
    assert tb["varying_rows"] == [] and "rate varies" not in out
    # the project's CSV path on the sample index / the estimated rate gives the same figures
    ref = csv_path_json(tmp_path, capsys, np.arange(s.t.size) / est, as_written(s.xyz), P)
    assert_same_figures(d, ref, tol=1e-6)
    assert_truth(d, off, sig)


def test_samples_lost_in_a_move_fail_the_check_against_the_motion_and_every_time_figure_is_refused(
        tmp_path, rng, capsys):
    rate = 200.0
    s, _, _ = stream_and_truth(rng, rate)
    sec = np.floor(s.t).astype(int)
    j = int(rng.integers(2, s.t_move_start.size - 1))  # in this move the logger lost a quarter second of samples
    first = int(np.searchsorted(s.t, s.t_move_start[j] + 0.3 * (s.t_arrive[j] - s.t_move_start[j])))
    n_lost = int(rate) // 4
    keep = np.setdiff1d(np.arange(s.t.size), np.arange(first, first + n_lost))
    t0 = datetime(2025, 3, 11, 9, 0, 0)
    stamps = [(t0 + timedelta(seconds=int(sec[i]))).strftime("%d.%m.%Y %H:%M:%S") for i in keep]
    f = write_sa(tmp_path / "lossy.txt", s.xyz[keep], stamps=stamps)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--json", tmp_path / "r.json")
    assert rc == 3, err
    # the stamp interval holding the loss is named where it starts
    k = int(sec[first])
    line = int(np.flatnonzero(sec[keep] == k)[0]) + SA_HEADER_LINES + 1
    assert f"note: line {line}, column 'date time': the rate varies here" in out
    d = json.loads((tmp_path / "r.json").read_text())
    tb = d["time_base"]
    assert tb["source"] == "refused" and line in tb["varying_rows"]
    # the move that lost the samples is short of its twins by the samples lost
    groups = tb["motion_check"]["identical_moves"]
    spread = max(g["spread_samples"] for g in groups)
    assert abs(spread - n_lost) <= 3 and not all(g["steady"] for g in groups)
    assert "identical moves" in err and "not evenly spaced" in err and "time figures refused" in err
    assert all(p["PST_s"] is None for p in d["poses"].values()) and all(m["MPT_s"] is None for m in d["MPT"])
    assert "PST_s P1" in tb["refused_figures"] and d["exit"]["code"] == 3
    assert "Hz" not in out.splitlines()[0]  # no rate stated on a clock that failed
    # AP and RP do not rest on the clock: as on the sample index at the true rate
    rc, _, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--rate-hz", rate, "--json", tmp_path / "k.json")
    assert rc == 0, err
    dk = json.loads((tmp_path / "k.json").read_text())
    for n in NAMES5:
        assert d["poses"][n]["RP_mm"] == pytest.approx(dk["poses"][n]["RP_mm"], abs=0.01)


def test_the_sample_export_with_two_digit_years_and_180_samples_per_stamp(tmp_path, capsys):
    f = SAMPLES / "sa_export_two_digit_year.txt"
    ps = read_sa_points(f)
    tb = stream_time_base(ps.t_s, ps.n, line=ps.line, source=ps.source, tcol="date time")
    assert tb.estimated and tb.info["rate_hz"] == pytest.approx(180.0)
    assert "month/day (every stamp has the same date" in ps.notes[0]
    # commanded poses: the two dwells' means as the lab would give them (the file's own points)
    d1 = np.linalg.norm(ps.xyz_mm - ps.xyz_mm[0], axis=1)
    far = d1 > d1.max() - 0.5
    P = write_poses(tmp_path / "P.csv", ["P1", "P2"], [ps.xyz_mm[d1 < 0.5].mean(axis=0), ps.xyz_mm[far].mean(axis=0)])
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--json", tmp_path / "r.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["time_base"]["source"] == "estimated_rate"
    assert {n: len(p["attained"]["row"]) for n, p in d["poses"].items()}["P2"] == 3


def draw_reflector_stops(rng, n_cycles, layout, off, scatter, noise):
    from scipy.spatial.transform import Rotation

    pts = np.empty((len(NAMES5), n_cycles, len(layout), 3))
    for c in range(n_cycles):
        for p in range(len(NAMES5)):
            rot = Rotation.from_rotvec(rng.normal(0, 5e-4, 3))
            pts[p, c] = CMD[p] + off[p] + rng.normal(0, scatter, 3) + rot.apply(layout) \
                + rng.normal(0, noise, layout.shape)
    return pts


def write_reflector_list(path, pts):
    """One pose's cycles (C, R, 3) as ``id, x, y, z`` lines, ids 1..R repeating once per cycle."""
    path.write_text("".join(f"{r + 1},  {p[0]:.9f},  {p[1]:.9f},  {p[2]:.9f}\n"
                            for cyc in pts for r, p in enumerate(cyc)))
    return path


def test_per_pose_reflector_lists_give_the_stop_lists_figures_and_rp_per_reflector(tmp_path, rng, capsys):
    n, scatter, noise = int(rng.integers(8, 15)), 0.02, 0.003
    layout = rng.normal(0, 50.0, (3, 3))
    layout -= layout.mean(axis=0)
    off = random_offsets(rng)
    pts = draw_reflector_stops(rng, n, layout, off, scatter, noise)
    files = [write_reflector_list(tmp_path / f"list_{name}.txt", pts[p]) for p, name in enumerate(NAMES5)]
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, out, err = run(capsys, "iso9283", "--stops", *files, "--poses", P, "--json", tmp_path / "r.json")
    assert rc == 0, err
    assert "RP refl 1" in out and "RP centroid" in out
    d = json.loads((tmp_path / "r.json").read_text())
    # the project's stop list CSV with a reflector column: the same figures
    pose = [name for name in NAMES5 for _ in range(n)]
    cyc = np.tile(np.arange(1, n + 1), len(NAMES5))
    S = write_stops(tmp_path / "S.csv", pose, cyc, pts.reshape(-1, 3, 3), reflectors=["1", "2", "3"])
    rc, _, err = run(capsys, "iso9283", "--stops", S, "--poses", P, "--json", tmp_path / "s.json")
    assert rc == 0, err
    ref = json.loads((tmp_path / "s.json").read_text())
    sig = math.hypot(scatter, noise / math.sqrt(3))
    for p, name in enumerate(NAMES5):
        a, b = d["poses"][name], ref["poses"][name]
        assert (a["AP_mm"], a["RP_mm"]) == pytest.approx((b["AP_mm"], b["RP_mm"]), abs=1e-9)
        cen = pts[p].mean(axis=1)
        assert a["AP_mm"] == pytest.approx(ap_ref(cen, CMD[p]), abs=1e-6)
        assert abs(a["AP_mm"] - np.linalg.norm(off[p])) < chi3_q(1e-6) * sig / math.sqrt(n) + 1e-3
        rr = next(r for r in d["reflector_RP"] if r["pose"] == name)
        assert rr["centroid_RP_mm"] == pytest.approx(a["RP_mm"], abs=1e-6)
        for r in range(3):
            assert rr["RP_mm"][str(r + 1)] == pytest.approx(rp_ref(pts[p][:, r]), abs=1e-6)
    # poses named on the command line instead of from the file names
    renamed = [f.rename(tmp_path / f"export{k}.txt") for k, f in enumerate(files)]
    rc, out, err = run(capsys, "iso9283", "--stops", *renamed, "--poses", P)
    assert rc == 2 and "'export0' is not in" in err and "--pose" in err
    rc, out, err = run(capsys, "iso9283", "--stops", *renamed, "--pose", *NAMES5, "--poses", P,
                       "--json", tmp_path / "n.json")
    assert rc == 0, err
    named = json.loads((tmp_path / "n.json").read_text())
    assert {k: (v["AP_mm"], v["RP_mm"]) for k, v in named["poses"].items()} == \
        {k: (v["AP_mm"], v["RP_mm"]) for k, v in d["poses"].items()}


def test_a_cycle_lacking_a_reflector_is_refused_with_its_lines(tmp_path, capsys):
    f = tmp_path / "P1.txt"
    f.write_text("1, 0, 0, 0\n2, 50, 0, 0\n3, 0, 50, 0\n1, 0, 0, 0\n3, 0, 50, 0\n1, 0, 0, 0\n")
    rc, _, err = run(capsys, "iso9283", "--stops", f)
    assert rc == 2 and f"{f}: lines 4-5: cycle 2 lacks reflector(s) 2" in err


def test_the_sample_reflector_list(tmp_path, capsys):
    f = SAMPLES / "reflector_list_pose1.txt"
    raw = np.loadtxt(f, delimiter=",")
    rc, out, err = run(capsys, "iso9283", "--stops", f, "--json", tmp_path / "r.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "r.json").read_text())
    assert list(d["poses"]) == ["pose1"] and d["poses"]["pose1"]["n_cycles"] == 10
    rr = d["reflector_RP"][0]
    for r in (1, 2, 3):
        assert rr["RP_mm"][str(r)] == pytest.approx(rp_ref(raw[raw[:, 0] == r, 1:]), abs=1e-9)
    cen = raw[:, 1:].reshape(10, 3, 3).mean(axis=1)
    assert d["poses"]["pose1"]["RP_mm"] == pytest.approx(rp_ref(cen), abs=1e-6)


@pytest.mark.parametrize("extra", [(), ("--rate-hz", "100")])
def test_hold_given_a_reflector_list_warns_instead_of_a_figure(capsys, extra):
    rc, out, err = run(capsys, "hold", "--stream", SAMPLES / "reflector_list_pose1.txt", *extra)
    assert rc == 2 and "noise" not in out
    assert "repeats 1, 2, 3 every 3 rows" in err and "per-pose reflector list" in err and "--stops" in err


def test_pipes_and_standard_input_are_read_once(tmp_path, rng, capsys, monkeypatch):
    s, _, _ = stream_and_truth(rng)
    S = write_csv_exact(tmp_path / "S.csv", s.t, s.xyz)
    P = write_poses(tmp_path / "P.csv", NAMES5, CMD)
    rc, _, err = run(capsys, "iso9283", "--stream", S, "--poses", P, "--json", tmp_path / "ref.json")
    assert rc == 0, err
    ref = json.loads((tmp_path / "ref.json").read_text())
    # --poses through a named pipe (as <(cat P.csv) gives it), --stream on standard input
    fifo = tmp_path / "poses.fifo"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_bytes(P.read_bytes()))
    writer.start()
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(S.read_bytes())))
    rc, out, err = run(capsys, "iso9283", "--stream", "-", "--poses", fifo, "--json", tmp_path / "p.json")
    writer.join(timeout=10)
    assert rc == 0, err
    assert "ISO 9283 analysis of <stdin>" in out
    assert_same_figures(json.loads((tmp_path / "p.json").read_text()), ref, tol=0.0)
    # a malformed file on standard input is named as such
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b"t,x,y,z\n0,1,2\n")))
    rc, _, err = run(capsys, "iso9283", "--stream", "-", "--poses", P)
    assert rc == 2 and "<stdin>: line 2" in err and "station-input" not in err


def test_stamp_forms_in_detail():
    from station.errors import DataError
    from station.readers.date_time import parse_stamp, stamps_to_seconds

    assert parse_stamp("02/12/25 12:00:01 AM").day_s == 1.0
    assert parse_stamp("02/12/25 12:00:01.5 PM").day_s == 43201.5
    assert parse_stamp("2025-02-12T16:52:45.25Z").day_s == 16 * 3600 + 52 * 60 + 45.25
    assert parse_stamp("02/12/25 13:00:01 PM") is None and parse_stamp("16:52:45") is None
    # 01/02 -> 02/03 over midnight: 31 days month first, 28 day first (2025): asked; 01/01 -> 02/02: 31 either way
    two = [parse_stamp("01/02/25 23:59:59"), parse_stamp("02/03/25 00:00:01")]
    with pytest.raises(DataError, match="--date-order"):
        stamps_to_seconds(two)
    assert stamps_to_seconds(two, date_order="mdy").t_s[1] == 31 * 86400 + 2
    assert stamps_to_seconds(two, date_order="dmy").t_s[1] == 28 * 86400 + 2
    same = stamps_to_seconds([parse_stamp("01/01/25 23:59:59"), parse_stamp("02/02/25 00:00:01")])
    assert same.settled_by == "either" and same.t_s[1] == 31 * 86400 + 2
    with pytest.raises(DataError, match="another form"):
        stamps_to_seconds([parse_stamp("01/01/25 10:00:00"), parse_stamp("2025-01-01 10:00:01")])
    with pytest.raises(DataError, match="does not exist"):
        stamps_to_seconds([parse_stamp("31.02.2025 10:00:00")])
