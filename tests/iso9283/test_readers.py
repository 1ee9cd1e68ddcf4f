"""Readers of the files labs have: SpatialAnalyzer exports, plain point lists, stop lists, registration files.

Every fixture is written here from numbers drawn each run; the reader must give them back (in mm),
and refuse a malformed file naming the file and line.
"""

from __future__ import annotations

import json
from datetime import datetime, timedelta

import numpy as np
import pytest

from station.errors import ConfigError, DataError
from station.readers.point_list import read_point_list
from station.readers.registration_files import read_frame_json, read_registration_csv
from station.readers.sniff import read_stream_file, sniff_format
from station.readers.spatial_analyzer import read_sa_points
from station.readers.stop_list import read_stop_list

UNITS = {"mm": 1.0, "m": 1000.0, "in": 25.4}


def sa_text(groups, unit="mm", frame="A::World", stamps=None, axes_line=None):
    """A SpatialAnalyzer point export: ``groups`` is a list of (group, names, xyz_mm)."""
    scale = UNITS[unit] if unit in UNITS else 1.0
    lines = ["// SpatialAnalyzer Point Export", f"// Points Relative to Coordinate Frame '{frame}'",
             axes_line or f"// AXES = CARTESIAN: X, Y, Z ({unit})", "// Group, Point, Index, X, Y, Z, Date Time"]
    k = 0
    for g, names, xyz in groups:
        for i, (n, p) in enumerate(zip(names, xyz)):
            row = f"{g}, {n}, {i + 1}, {p[0] / scale:.9f}, {p[1] / scale:.9f}, {p[2] / scale:.9f}"
            if stamps is not None:
                row += ", " + stamps[k]
            lines.append(row)
            k += 1
    return "\n".join(lines) + "\n"


def test_sa_export_units_groups_names_and_a_trailing_stray_group(tmp_path, rng):
    unit = str(rng.choice(list(UNITS)))
    n, n_stray = int(rng.integers(200, 400)), int(rng.integers(1, 6))
    xyz = rng.uniform(-2000, 2000, (n, 3))
    stray = rng.uniform(-2000, 2000, (n_stray, 3))
    t0 = datetime(2024, 3, 5, 10, 15, 1)
    dt = rng.uniform(0.004, 0.02)
    stamps = [(t0 + timedelta(seconds=k * dt)).strftime("%Y-%m-%d %H:%M:%S.%f") for k in range(n + n_stray)]
    path = tmp_path / "export.txt"
    path.write_text(sa_text([("Stream", [f"P{k}" for k in range(n)], xyz),
                             ("Scratch", [f"nest{k}" for k in range(n_stray)], stray)], unit=unit, stamps=stamps))
    assert sniff_format(path) == "sa"
    s = read_stream_file(path)
    assert s.fmt == "sa" and s.group == "Stream" and s.frame == "A::World" and s.units == unit
    assert s.n == n and np.allclose(s.xyz_mm, xyz, atol=1e-6 * UNITS[unit])
    assert s.names[:3] == ("P0", "P1", "P2")
    assert np.allclose(s.t_s, np.arange(n) * dt, atol=1e-6)  # microsecond stamps
    assert s.line.tolist() == list(range(5, 5 + n))
    (note,) = s.notes
    assert f"group 'Scratch' ({n_stray} points, lines {5 + n}-{4 + n + n_stray}) left out" in note
    # the stray group on its own, by name
    only = read_sa_points(path, "Scratch")
    assert np.allclose(only.xyz_mm, stray, atol=1e-6 * UNITS[unit]) and only.t_s[0] == 0.0


@pytest.mark.parametrize("fmt", ["%m/%d/%Y %I:%M:%S %p", "%d.%m.%Y %H:%M:%S"])
def test_sa_date_time_formats_and_no_time(tmp_path, rng, fmt):
    n = 50
    xyz = rng.uniform(-500, 500, (n, 3))
    t0 = datetime(2023, 11, 30, 23, 59, 30)
    stamps = [(t0 + timedelta(seconds=k)).strftime(fmt) for k in range(n)]
    p = tmp_path / "a.txt"
    p.write_text(sa_text([("G", [str(k) for k in range(n)], xyz)], stamps=stamps))
    assert np.array_equal(read_sa_points(p).t_s, np.arange(n, dtype=float))  # across midnight
    p.write_text(sa_text([("G", [str(k) for k in range(n)], xyz)]))
    assert read_sa_points(p).t_s is None


def test_bad_sa_exports_are_refused_naming_the_line(tmp_path, rng):
    xyz = rng.uniform(-500, 500, (40, 3))
    names = [f"p{k}" for k in range(40)]

    def refused(text, *msg, group=None):
        p = tmp_path / "bad.txt"
        p.write_text(text)
        with pytest.raises(DataError) as e:
            read_sa_points(p, group)
        assert str(p) in str(e.value) and all(m in str(e.value) for m in msg), str(e.value)

    refused(sa_text([("G", names, xyz)], axes_line="// AXES = CARTESIAN: X, Y, Z (furlong)"), "line 3",
            "unknown length unit 'furlong'")
    refused(sa_text([("G", names, xyz)], axes_line="// AXES = POLAR: R, Theta, Phi (mm)"), "line 3", "POLAR")
    refused(sa_text([("G", names, xyz)], axes_line="// AXES = CARTESIAN: X, Y, Z"), "line 3", "names no unit")
    refused(sa_text([("G", names, xyz)], axes_line="// units: mm"), "line 5", "units are unknown")
    k = int(rng.integers(5, 30))
    mixed = sa_text([("A", names[:k], xyz[:k]), ("B", names[k:k + 3], xyz[k:k + 3]), ("A", names[k + 3:], xyz[k + 3:])])
    refused(mixed, f"line {5 + k + 3}", "group 'A' starts again after group 'B'", "mixed groups")
    lines = sa_text([("G", names, xyz)]).splitlines()
    j = int(rng.integers(5, 40))
    cells = lines[j].split(",")
    cells[4] = " nan"
    lines[j] = ",".join(cells)
    refused("\n".join(lines) + "\n", f"line {j + 1}, column 'y'", "not a finite number")
    even = sa_text([("A", names[:20], xyz[:20]), ("B", names[20:], xyz[20:])])
    refused(even, "several groups of comparable size", "--group")
    refused(even, "no group 'C'", group="C")


def test_plain_point_lists_with_and_without_header(tmp_path, rng):
    n = int(rng.integers(20, 60))
    xyz = rng.uniform(-3000, 3000, (n, 3))
    cases = {
        "comma_header.csv": "id,x,y,z\n" + "".join(f"{k},{a:.6f},{b:.6f},{c:.6f}\n" for k, (a, b, c) in enumerate(xyz)),
        "space_noheader.txt": "# from the tracker\n" + "".join(f"pt{k}  {a:.6f}\t{b:.6f} {c:.6f}\n"
                                                              for k, (a, b, c) in enumerate(xyz)),
        "xyz_only.txt": "".join(f"{a:.6f} {b:.6f} {c:.6f}\n" for a, b, c in xyz),
        "named_cols.csv": "Z, X, Point, Y\n" + "".join(f"{c:.6f}, {a:.6f}, q{k}, {b:.6f}\n"
                                                       for k, (a, b, c) in enumerate(xyz)),
    }
    for name, text in cases.items():
        p = tmp_path / name
        p.write_text(text)
        assert sniff_format(p) == "points", name
        s = read_stream_file(p)
        assert s.fmt == "points" and s.t_s is None and s.n == n
        assert np.allclose(s.xyz_mm, xyz, atol=1e-6), name
    assert read_point_list(tmp_path / "space_noheader.txt").names[-1] == f"pt{n - 1}"
    assert read_point_list(tmp_path / "named_cols.csv").names[0] == "q0"
    assert read_point_list(tmp_path / "space_noheader.txt").line[0] == 2


def test_bad_point_lists(tmp_path):
    def refused(text, *msg):
        p = tmp_path / "bad.txt"
        p.write_text(text)
        with pytest.raises(DataError) as e:
            read_point_list(p)
        assert str(p) in str(e.value) and all(m in str(e.value) for m in msg), str(e.value)

    refused("1,2,3,4\n2,3,4\n", "line 2: 3 fields, expected 4 (comma separated)")
    refused("a 1 2 3\nb 1 x 3\n", "line 2, column 'y'", "'x' is not a number")
    refused("a 1 2 3\nb 1 nan 3\n", "line 2, column 'y'", "not a finite number")
    refused("id,x,y\n1,2,3\n", "line 1", "no column 'z'")
    refused("1 2 3 4 5\n", "line 1: 5 fields without a header")
    refused("# only a comment\n", "no points")


def test_sniffing_the_project_csv_and_the_format_override(tmp_path, rng):
    p = tmp_path / "s.csv"
    t = np.arange(10) * 0.01
    xyz = rng.normal(size=(10, 3))
    p.write_text("t,x,y,z\n" + "".join(f"{a},{b},{c},{d}\n" for a, (b, c, d) in zip(t, xyz)))
    assert sniff_format(p) == "csv"
    s = read_stream_file(p)
    assert s.fmt == "csv" and np.allclose(s.t_s, t) and np.allclose(s.xyz_mm, xyz)
    forced = read_stream_file(p, "points")  # a point list with a header naming t, x, y, z reads the same
    assert forced.fmt == "points" and np.allclose(forced.t_s, t) and np.allclose(forced.xyz_mm, xyz)
    with pytest.raises(DataError, match="not a SpatialAnalyzer export"):
        read_stream_file(p, "sa")
    with pytest.raises(ConfigError, match="--format must be one of csv, sa, points"):
        read_stream_file(p, "xls")
    with pytest.raises(ConfigError, match="--group applies to SpatialAnalyzer"):
        read_stream_file(p, group="G")


def _write(path, text):
    path.write_text(text)
    return path


def test_stop_list_with_reflectors_and_approach(tmp_path, rng):
    poses, cycles, refl = ["P1", "P2"], [1, 2, 3], ["A", "B", "C"]
    pts = rng.uniform(-1000, 1000, (2, 3, 3, 3))
    rows = [(p, c, r, "+x" if c < 3 else "-z", pts[i, j, k]) for i, p in enumerate(poses) for j, c in enumerate(cycles)
            for k, r in enumerate(refl)]
    order = rng.permutation(len(rows))  # rows of one stop need not be adjacent
    text = "pose,cycle,reflector,approach,x,y,z\n" + "".join(
        f"{rows[i][0]},{rows[i][1]},{rows[i][2]},{rows[i][3]},{rows[i][4][0]:.6f},{rows[i][4][1]:.6f},"
        f"{rows[i][4][2]:.6f}\n" for i in order)
    sl = read_stop_list(_write(tmp_path / "stops.csv", text))
    assert sl.n == 6 and sl.reflectors == ("A", "B", "C")
    for k in range(sl.n):
        i, j = poses.index(sl.pose[k]), cycles.index(int(sl.cycle[k]))
        assert np.allclose(sl.points_mm[k], pts[i, j], atol=1e-6)
        assert sl.approach[k] == ("+x" if sl.cycle[k] < 3 else "-z")
        assert np.allclose(sl.centroid_mm[k], pts[i, j].mean(axis=0), atol=1e-6)
    plain = read_stop_list(_write(tmp_path / "plain.csv", "pose,cycle,x,y,z\nP1,0,1,2,3\nP1,1,1.5,2,3\n"))
    assert plain.reflectors == ("",) and plain.approach is None and plain.points_mm.shape == (2, 1, 3)


def test_bad_stop_lists(tmp_path):
    head = "pose,cycle,reflector,x,y,z\n"
    good = ["P1,1,A,0,0,0", "P1,1,B,100,0,0", "P1,1,C,0,100,0", "P1,2,A,0,0,1", "P1,2,B,100,0,1", "P1,2,C,0,100,1"]

    def refused(lines, *msg):
        p = _write(tmp_path / "bad.csv", head + "\n".join(lines) + "\n")
        with pytest.raises(DataError) as e:
            read_stop_list(p)
        assert str(p) in str(e.value) and all(m in str(e.value) for m in msg), str(e.value)

    refused(good[:4] + good[5:], "pose P1 cycle 2 (line(s) 5, 6) has no row for reflector(s) B")
    refused(good + ["P1,2,C,0,100,2"], "line 8: pose P1 cycle 2 reflector C appears twice (first on line 7)")
    refused(good[:2] + ["P1,1,C,0,nan,0"] + good[3:], "line 4, column 'y'", "not a finite number")
    refused(good[:2] + ["P1,x,C,0,1,0"] + good[3:], "line 4, column 'cycle'")
    refused(good[:1] + ["P1,1,,0,1,0"], "line 3, column 'reflector': empty")
    p = _write(tmp_path / "nohead.csv", "pose,x,y,z\nP1,1,2,3\n")
    with pytest.raises(DataError, match="missing column"):
        read_stop_list(p)


def test_registration_files(tmp_path, rng):
    n = int(rng.integers(3, 8))
    base, trk = rng.uniform(-1000, 1000, (n, 3)), rng.uniform(-1000, 1000, (n, 3))
    text = "name,base_x,base_y,base_z,tracker_x,tracker_y,tracker_z\n" + "".join(
        f"R{k},{b[0]:.6f},{b[1]:.6f},{b[2]:.6f},{t[0]:.6f},{t[1]:.6f},{t[2]:.6f}\n"
        for k, (b, t) in enumerate(zip(base, trk)))
    names, b, t = read_registration_csv(_write(tmp_path / "r.csv", text))
    assert names == [f"R{k}" for k in range(n)] and np.allclose(b, base, atol=1e-6) and np.allclose(t, trk, atol=1e-6)
    two = "\n".join(text.splitlines()[:3]) + "\n"
    with pytest.raises(DataError, match="at least 3 point pairs .* got 2"):
        read_registration_csv(_write(tmp_path / "two.csv", two))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    tt = rng.normal(size=3) * 1000
    f = _write(tmp_path / "f.json", json.dumps({"register base frame": {"R": R.tolist(), "t_mm": tt.tolist(),
                                                                        "rms_mm": 0.2, "method": "best-fit"}}))
    R2, t2, obj = read_frame_json(f)
    assert np.allclose(R2, R) and np.allclose(t2, tt) and obj["method"] == "best-fit"
    with pytest.raises(DataError, match="key 'R': need a finite 3x3 array"):
        read_frame_json(_write(tmp_path / "g.json", json.dumps({"R": [[1, 0], [0, 1]], "t_mm": [0, 0, 0]})))
    with pytest.raises(DataError, match="line 1: not JSON"):
        read_frame_json(_write(tmp_path / "h.json", "{R: 1"))
