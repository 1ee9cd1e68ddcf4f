"""Hostile input, second pass (issue 24, items 1-8): past the first 40 lines, absurd but finite numbers.

Each test is an item's reproducer: on the commit the issue was filed against it hung, raised a
traceback, allocated gigabytes, or passed absurd data with exit 0. Now each ends in a clean
refusal (exit 2, ``station: error:``) naming the file, the line and the column, or in a result.
Random draws come from the ``rng`` fixture (seed printed; ``ISO_TEST_SEED`` replays it).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drivers.nmea_codec import NmeaDecoder, OdometrySample, encode_sentence
from fakes.sim.arm_measurements import instrument_frame, measure, random_poses
from procedures.preflight import report_dir_problems
from station.analysis.arm.calibration import check_joint_limits
from station.analysis.registration import fit_rigid
from app.cli import main
from tests.hostile import refused as _refused
from station.errors import DataError
from station.models.robots import get_robot
from station.readers.arm_csv import write_arm_csv
from station.readers.stream_csv import read_stream_csv
from station.readers.trailer_csv import write_trailer_csv

STOPS = "pose,cycle,x,y,z\n" + "".join(f"P{p},{c},{100 * p + 0.01 * c},{50 * p},{10 * c}\n"
                                       for c in range(1, 4) for p in range(1, 4))
POSES = "name,x,y,z\n" + "".join(f"P{p},{100 * p},{50 * p},20\n" for p in range(1, 4))
PAIRS_HEAD = "name,base_x,base_y,base_z,tracker_x,tracker_y,tracker_z\n"




def _stops(tmp_path) -> list[str]:
    """``--stops S --poses P`` of a small good stop list."""
    (tmp_path / "stops.csv").write_text(STOPS)
    (tmp_path / "poses.csv").write_text(POSES)
    return ["--stops", str(tmp_path / "stops.csv"), "--poses", str(tmp_path / "poses.csv")]


def _stream_rows(n, x=None):
    return "".join(f"{i * 0.01:.2f},{x if x is not None and i == n // 2 else i * 0.001},0,0\n" for i in range(n))


# -- item 1: registration with 1e308 ----------------------------------------------------------------------------
@pytest.mark.parametrize("rows", [
    "a,0,0,0,1e308,0,0\nb,100,0,0,100,0,0\nc,0,100,0,0,100,0\n",
    "a,1e308,1e308,1e308,0,0,0\nb,1e308,1e308,1e308,100,0,0\nc,1e308,1e308,1e308,0,100,0\n",
])
def test_registration_with_1e308_is_refused_not_hung(tmp_path, capsys, rows):
    reg = tmp_path / "reg.csv"
    reg.write_text(PAIRS_HEAD + rows)
    _refused(capsys, ["analyze", "iso9283", *_stops(tmp_path), "--register", str(reg)],
             f"{reg}: line 2, column '", "beyond")


def test_rigid_fit_refuses_coordinates_no_instrument_gives():
    a = np.array([[0.0, 0, 0], [100, 0, 0], [0, 100, 0]])
    b = a.copy()
    b[0, 0] = 1e300
    with pytest.raises(DataError, match="point 1"):
        fit_rigid(a, b)


# -- item 2: every line bounded, not only the first 40 ------------------------------------------------------------
def test_a_huge_status_cell_after_line_40_is_refused_by_its_line(tmp_path, rng):
    n = 2000
    bad = int(rng.integers(41, n))  # a data row after the sniffed lines
    rows = [f"{i * 0.01:.2f},{i * 0.001},0,0,{'x' * 100_000 if i + 2 == bad else '0'}" for i in range(n)]
    f = tmp_path / "s.csv"
    f.write_text("t,x,y,z,status\n" + "\n".join(rows) + "\n")
    with pytest.raises(DataError, match=rf"line {bad}: longer than 4096"):
        read_stream_csv(f)


def test_a_status_column_costs_what_its_distinct_values_cost(tmp_path):
    """The validity of each row from the distinct status values (not an array as wide as the longest cell)."""
    f = tmp_path / "s.csv"
    status = ["0", "ok", "beam broken " + "y" * 4000, "VALID", "2"]
    f.write_text("t,x,y,z,status\n" + "".join(f"{i * 0.01:.2f},{i},0,0,{status[i % 5]}\n" for i in range(50)))
    ps = read_stream_csv(f)
    assert ps.valid.tolist() == [i % 5 in (0, 1, 3) for i in range(50)]


# -- item 3: tracebacks ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000,
                                  '{"R": [[1,0,0],[0,1,0],[0,0,1]], "t_mm": [' + "9" * 5000 + ",0,0]}",
                                  '{"R": [[1,0,0],[0,1,0],[0,0,1]], "t_mm": [' + "9" * 400 + ",0,0]}",
                                  '{"R": [[' + "9" * 400 + ',0,0],[0,1,0],[0,0,1]], "t_mm": [0,0,0]}'])
def test_hostile_frame_files_are_refused(tmp_path, capsys, text):
    frame = tmp_path / "frame.json"
    frame.write_text(text)
    _refused(capsys, ["analyze", "iso9283", *_stops(tmp_path), "--frame", str(frame)], str(frame))


@pytest.mark.parametrize("cycle, why", [("99999999999999999999", "not a cycle number"), ("-5", "not a cycle number"),
                                        ("9" * 5000, "longer than 4096")])
def test_stop_list_cycles_are_bounded(tmp_path, capsys, cycle, why):
    stops = tmp_path / "stops.csv"
    stops.write_text(STOPS + f"P1,{cycle},1,2,3\n")
    _refused(capsys, ["analyze", "iso9283", "--stops", str(stops)], f"{stops}: line 11", why)


def test_poses_files_are_read_line_by_line(tmp_path, capsys):
    stream = tmp_path / "s.csv"
    stream.write_text("t,x,y,z\n" + _stream_rows(200))
    poses = tmp_path / "p.csv"
    poses.write_text("name,x,y,z\nP1,1,2,3\nP2," + "1" * 140_000 + ",2,3\n")
    _refused(capsys, ["analyze", "iso9283", "--stream", str(stream), "--poses", str(poses)],
             f"{poses}: line 3: longer than 4096")
    # a bad byte after the first 8 KB: named on its own line
    body = "name,x,y,z\n" + "".join(f"P{k},{k},2,3\n" for k in range(1, 1000))
    poses.write_bytes(body.encode() + b"Q\xff,1,2,3\n")
    _refused(capsys, ["analyze", "iso9283", "--stream", str(stream), "--poses", str(poses)],
             f"{poses}: line 1001, byte 2: not UTF-8")


@pytest.mark.parametrize("window", ["1e-9", "1e-6"])
def test_hold_windows_hold_samples(tmp_path, capsys, window):
    """--window-s 1e-9 tried to allocate 223 GiB; 1e-6 printed nan and wrote NaN into the JSON."""
    s = tmp_path / "s.csv"
    s.write_text("t,x,y,z\n" + "".join(f"{i * 0.01:.2f},{0.001 * math.sin(i)},0,0\n" for i in range(50)))
    out = tmp_path / "h.json"
    for extra in ([], ["--rate-hz", "100"]):
        _refused(capsys, ["analyze", "hold", "--stream", str(s), "--window-s", window, "--json", str(out), *extra],
                 "holds less than 2 samples")
        assert not out.exists()


# -- items 3-5: arm data ---------------------------------------------------------------------------------------
def _arm_case(rng, n=60):
    nom = get_robot("rb5-850")
    q = random_poses(nom.joint_limits_rad, n, rng)
    meas = measure(nom.dh_nominal, q, instrument_frame(rng), 0.02, rng)
    return np.degrees(q), meas


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_absurd_arm_values_are_refused_naming_line_and_column(tmp_path, capsys, rng, command):
    q, x = _arm_case(rng)
    f = tmp_path / "A.csv"
    k = int(rng.integers(0, len(q)))
    for col, value, qq, xx in (("y", 1e308, q, x), ("x", 1e9, q, x), ("q3", 1e20, q, x)):
        qq, xx = qq.copy(), xx.copy()
        if col.startswith("q"):
            qq[k, 2] = value
        else:
            xx[k, "xyz".index(col)] = value
        write_arm_csv(f, qq, xx)
        _refused(capsys, [command, "arm", "--robot", "rb5-850", "--data", str(f)],
                 f"{f}:{k + 2}:", f"({col})", "beyond")
    write_arm_csv(f, q, np.full_like(x, 1e308))
    _refused(capsys, [command, "arm", "--robot", "rb5-850", "--data", str(f)], f"{f}:2:7 (x)")


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_one_point_10_m_off_is_named_not_averaged(tmp_path, capsys, rng, command):
    q, x = _arm_case(rng)
    f = tmp_path / "A.csv"
    k = int(rng.integers(1, len(q)))
    x[k] += rng.normal(size=3) / math.sqrt(3) * 10_000.0
    write_arm_csv(f, q, x)
    _refused(capsys, [command, "arm", "--robot", "rb5-850", "--data", str(f)], f"{f}: line {k + 2}:", "gross outlier")


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_clean_arm_data_passes_the_screen(tmp_path, capsys, rng, command):
    """No false alarm: a nominal arm with tracker noise (and the as-built deviations of a real one)."""
    from station.analysis.arm.screen import screen_arm_poses

    nom, built = get_robot("rb5-850"), get_robot("rb5-850-as-built")
    q = random_poses(nom.joint_limits_rad, 200, rng)
    screen_arm_poses(nom.dh_nominal, q, measure(built.dh_nominal, q, instrument_frame(rng), 0.05, rng))


@pytest.mark.parametrize("rows", ["identical", "zero joints"])
@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_repeated_poses_are_refused_quickly(tmp_path, capsys, rng, command, rows):
    """3,000 identical rows took 50 s in diagnose arm; all-zero joints passed."""
    q, x = _arm_case(rng, 1)
    if rows == "zero joints":
        q[:] = 0.0
    f = tmp_path / "A.csv"
    write_arm_csv(f, np.repeat(q, 3000, axis=0), np.repeat(x, 3000, axis=0))
    _refused(capsys, [command, "arm", "--robot", "rb5-850", "--data", str(f)], "only 1 distinct joint pose")


def test_arm_files_hold_at_most_what_a_calibration_measures(tmp_path, capsys, rng):
    """10^6 identical rows passed 3 GB in calibrate arm: the reader stops at its limit and says why."""
    from station.readers.arm_csv import MAX_ROWS

    q, x = _arm_case(rng, 1)
    f = tmp_path / "A.csv"
    write_arm_csv(f, np.repeat(q, MAX_ROWS + 5, axis=0), np.repeat(x, MAX_ROWS + 5, axis=0))
    _refused(capsys, ["calibrate", "arm", "--robot", "rb5-850", "--data", str(f)],
             f"{f}:{MAX_ROWS + 2}: more than {MAX_ROWS} poses")


def test_joint_limit_message_prints_a_sane_number():
    lim = np.tile([-math.pi, math.pi], (6, 1))
    q = np.zeros((2, 6))
    q[1, 2] = 1e306
    with pytest.raises(DataError) as exc:
        check_joint_limits(q, lim)
    assert "q3 = 5.72958e+307 deg" in str(exc.value) and len(str(exc.value)) < 200


# -- item 5: streams, trailer, NMEA --------------------------------------------------------------------------
def test_a_stream_row_with_x_1e308_is_refused_by_line_and_column(tmp_path, capsys, rng):
    n = 400
    rows = _stream_rows(n, x="1e308").splitlines()
    f = tmp_path / "s.csv"
    f.write_text("t,x,y,z\n" + "\n".join(rows) + "\n")
    poses = tmp_path / "p.csv"
    poses.write_text("name,x,y,z\nP1,1,2,3\n")
    _refused(capsys, ["analyze", "iso9283", "--stream", str(f), "--poses", str(poses)],
             f"{f}: line {n // 2 + 2}, column 'x': 1e+308 is beyond")


def test_trailer_files_with_a_column_twice_are_refused(tmp_path, capsys):
    f = tmp_path / "T.csv"
    t = np.arange(200) * 0.1
    write_trailer_csv(f, t, 0.01 * np.sin(t), 0.02 * np.sin(t))
    text = f.read_text().splitlines()
    f.write_text("\n".join([text[0] + ",psi"] + [r + ",0.5" for r in text[1:]]) + "\n")
    _refused(capsys, ["diagnose", "trailer", "--l1", "1", "--l2", "1", "--data", str(f)],
             f"{f}: line 1: a column appears twice")


@pytest.mark.parametrize("fields", [["PODO", "1e308", "0.5", "0.01", "0.1"], ["PODO", "1", "0.5", "0.01", "1e5"],
                                    ["PODO", "1", "5e3", "0.01", "0.1"], ["PODOA", "C", "1e300", "0.1"]])
def test_nmea_values_no_unit_gives_are_malformed(fields):
    dec = NmeaDecoder()
    ok = encode_sentence(["PODO", "12.5", "0.5", "0.01", "0.1"])
    msgs = dec.feed(encode_sentence(fields) + ok)
    assert msgs == [OdometrySample(12.5, 0.5, 0.01, 0.1)]
    assert dec.stats.malformed == 1 and dec.stats.sentences == 2


# -- item 6: messages name their line ---------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["registration", "stops", "points"])
def test_a_bad_byte_is_named_on_its_own_line(tmp_path, capsys, rng, kind):
    bad = int(rng.integers(3, 60))
    if kind == "registration":
        head, row = PAIRS_HEAD, lambda k: f"p{k},{k},{k * k % 7},{k % 3},{k},{k * k % 7},{k % 3}\n"
    elif kind == "stops":
        head, row = "pose,cycle,x,y,z\n", lambda k: f"P{k % 3 + 1},{k // 3 + 1},{k},0,0\n"
    else:
        head, row = "id,x,y,z\n", lambda k: f"{k},{k},0,0\n"
    lines = [head.encode()] + [row(k).encode() for k in range(1, 70)]
    lines[bad - 1] = lines[bad - 1][:2] + b"\xfe" + lines[bad - 1][2:]
    f = tmp_path / "f.csv"
    f.write_bytes(b"".join(lines))
    argv = {"registration": ["analyze", "iso9283", *_stops(tmp_path), "--register", str(f)],
            "stops": ["analyze", "iso9283", "--stops", str(f)],
            "points": ["analyze", "hold", "--stream", str(f), "--rate-hz", "100"]}[kind]
    _refused(capsys, argv, f"{f}: line {bad}, byte 3: not UTF-8")


# -- item 7: report_dir tried before anything moves ------------------------------------------------------------
def test_a_report_dir_nothing_can_be_written_to_fails_preflight(tmp_path):
    assert report_dir_problems("/proc/station-reports")
    assert report_dir_problems(tmp_path / "a" / "b") == []
    assert not (tmp_path / "a").exists()  # the probe leaves nothing behind
    (tmp_path / "f").write_text("")
    assert "is a file" in report_dir_problems(tmp_path / "f" / "r")[0]


# -- item 8: NMEA decoding linear however the bytes arrive ------------------------------------------------------
class _CountingBuffer(bytearray):
    """A bytearray that adds up how many bytes its searches look at (up to the hit, or the whole span)."""

    scanned = 0

    def _count(self, hit, start, end, reverse=False):
        lo, hi = start or 0, len(self) if end is None else min(end, len(self))
        type(self).scanned += max(0, hi - lo) if hit < 0 else (hi - hit if reverse else hit - lo + 1)
        return hit

    def find(self, sub, start=None, end=None):
        return self._count(super().find(sub, *(x for x in (start, end) if x is not None)), start, end)

    def rfind(self, sub, start=None, end=None):
        return self._count(super().rfind(sub, *(x for x in (start, end) if x is not None)), start, end, True)


@pytest.mark.parametrize("junk", [b"$" * 200_000, b"$PODO," * 40_000, b"x" * 200_000 + b"$" * 1000])
def test_nmea_decoding_looks_at_each_byte_a_bounded_number_of_times(junk):
    """``feed(b"$" * 10**6)`` in one call took 5.3 s (0.55 s in 4 KB pieces): the searches were quadratic."""
    dec = NmeaDecoder()
    dec._buf = _CountingBuffer()
    _CountingBuffer.scanned = 0
    good = encode_sentence(["PODO", "1.5", "0.5", "0.01", "0.1"])
    msgs = dec.feed(junk + b"\r\n" + good)
    assert msgs == [OdometrySample(1.5, 0.5, 0.01, 0.1)]
    assert _CountingBuffer.scanned < 400 * len(junk)  # linear: a few sentence lengths per byte at most


def test_hold_json_has_no_nan(tmp_path, rng):
    s = tmp_path / "s.csv"
    s.write_text("t,x,y,z\n" + "".join(f"{i * 0.01:.2f},{rng.normal(0, 0.01)},0,0\n" for i in range(300)))
    out = tmp_path / "h.json"
    assert main(["analyze", "hold", "--stream", str(s), "--window-s", "0.5", "--json", str(out)]) == 0
    json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
