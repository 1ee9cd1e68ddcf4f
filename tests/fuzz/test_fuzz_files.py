"""Property-based fuzzing of every file reader over whole files and absurd numbers (issue 24; hypothesis).

Every reader of ``station/readers/`` (stream CSV, poses CSV, plain point
list, SpatialAnalyzer export, stop list, registration CSV and frame JSON,
the sniffing front door) and the arm and trailer readers:

* any bytes end in a result or in the project's own error, never a foreign
  exception;
* any one line of a good file of up to 300 lines (not only the first 40)
  replaced by anything: a result, or a refusal naming the file and that line;
* any number in any row: 1e308, subnormals, integers of hundreds of digits,
  NaN, infinities. Read exactly when finite and within what an instrument
  gives (the reader's limit for that column); refused naming the file and
  the line otherwise.

Files are written under one temporary folder per test (hypothesis reruns the
body many times). The long run is ``bench/bench_fuzz.py``.
"""

from __future__ import annotations

import math
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from station.errors import StationError
from station.readers.arm_csv import LIMITS as ARM_LIMITS
from station.readers.arm_csv import read_arm_csv
from station.readers.point_list import read_point_list
from station.readers.registration_files import read_frame_json, read_registration_csv
from station.readers.sniff import read_stream_file
from station.readers.spatial_analyzer import read_sa_points
from station.readers.stop_list import read_stop_list
from station.readers.stream_csv import read_poses_csv, read_stream_csv
from station.readers.text import MAX_ABS_MM
from station.readers.trailer_csv import LIMITS as TRAILER_LIMITS
from station.readers.trailer_csv import read_trailer_csv

FUZZ = settings()  # the budget comes from the loaded profile (tests/fuzz/conftest.py)
_DIR = Path(tempfile.mkdtemp(prefix="fuzz-files-"))


@dataclass(frozen=True)
class Format:
    """A reader with a good file of it: ``head`` lines, then ``row(k)`` for each data row k."""

    name: str
    read: Callable
    head: tuple[str, ...]
    row: Callable[[int], list[str]]  # the cells of data row k
    sep: str
    number_cell: int  # a numeric cell of a row (its column's limit below)
    limit: float
    value: Callable[[object], float]  # the value of row 0's number cell in what the reader returns


def _t(k):
    return f"{k * 0.01:.2f}"


FORMATS = [
    Format("stream csv", read_stream_csv, ("t,x,y,z",), lambda k: [_t(k), f"{k * 0.001:.3f}", "1", "2"], ",", 1,
           MAX_ABS_MM, lambda r: r.xyz_mm[0, 0]),
    Format("poses csv", lambda p: read_poses_csv(p)[1], ("name,x,y,z",), lambda k: [f"P{k}", f"{k}.5", "1", "2"], ",",
           1, MAX_ABS_MM, lambda r: r[0, 0]),
    Format("point list", read_point_list, ("id x y z",), lambda k: [str(k + 1), f"{k}.25", "1", "2"], " ", 1,
           MAX_ABS_MM, lambda r: r.xyz_mm[0, 0]),
    Format("sniffed point list", read_stream_file, ("# points", "id,x,y,z"), lambda k: [str(k + 1), f"{k}.25", "1", "2"],
           ",", 1, MAX_ABS_MM, lambda r: r.xyz_mm[0, 0]),
    Format("spatialanalyzer", read_sa_points,
           ("// SpatialAnalyzer Point Export", "// AXES = CARTESIAN: X, Y, Z (mm)", "// Group, Point, Index, X, Y, Z"),
           lambda k: ["Stream", f"p{k}", str(k + 1), f"{k}.5", "1", "2"], ", ", 3, MAX_ABS_MM, lambda r: r.xyz_mm[0, 0]),
    Format("stop list", read_stop_list, ("pose,cycle,x,y,z",), lambda k: [f"P{k % 5 + 1}", str(k // 5 + 1), f"{k}.5",
                                                                           "1", "2"], ",", 2, MAX_ABS_MM,
           lambda r: r.points_mm[0, 0, 0]),
    Format("registration", lambda p: read_registration_csv(p)[2],
           ("name,base_x,base_y,base_z,tracker_x,tracker_y,tracker_z",),
           lambda k: [f"r{k}", str(k), str(k * k % 11), str(k % 3), f"{k}.5", "1", "2"], ",", 4, MAX_ABS_MM,
           lambda r: r[0, 0]),
    Format("arm csv", read_arm_csv, ("q1,q2,q3,q4,q5,q6,x,y,z",),
           lambda k: [str(k % 7), "10", "20", "30", "40", "50", f"{k}.5", "1", "2"], ",", 6, ARM_LIMITS["x"],
           lambda r: r.xyz_mm[0, 0]),
    Format("trailer csv", read_trailer_csv, ("t,kappa,psi",), lambda k: [_t(k), "0.01", "0.02"], ",", 1,
           TRAILER_LIMITS["kappa"], lambda r: r["kappa"][0]),
]
IDS = [f.name for f in FORMATS]


def _write(name: str, data: bytes) -> Path:
    path = _DIR / re.sub(r"\W", "_", name)
    path.write_bytes(data)
    return path


def _lines(fmt: Format, n: int) -> list[str]:
    return list(fmt.head) + [fmt.sep.join(fmt.row(k)) for k in range(n)]


def _names_line(msg: str, path: Path, line: int) -> bool:
    """The message names the file and the line (``line N``, ``:N:`` or ``line(s) ..., N``)."""
    return str(path) in msg and re.search(rf"(?<![\d.]){line}(?![\d.])", msg.replace(str(path), "")) is not None


# -- any bytes ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", FORMATS, ids=IDS)
@FUZZ
@given(data=st.binary(max_size=600))
def test_any_bytes_end_in_a_result_or_our_refusal(fmt, data):
    path = _write(fmt.name, data)
    try:
        fmt.read(path)
    except StationError:
        pass


@FUZZ
@given(data=st.one_of(st.binary(max_size=400), st.text(alphabet='[]{}":,0123456789.eE-Rt_m ', max_size=400)
                      .map(str.encode)))
def test_any_frame_file_ends_in_a_result_or_our_refusal(data):
    try:
        R, t, _ = read_frame_json(_write("frame", data))
    except StationError:
        return
    assert R.shape == (3, 3) and t.shape == (3,) and all(math.isfinite(v) for v in t)


# -- any line of a whole file --------------------------------------------------------------------------------
_JUNK = st.one_of(
    st.text(max_size=60).map(lambda s: s.replace("\n", " ").replace("\r", " ")),
    st.sampled_from(["", "1e308,1e308,1e308,1e308", "x" * 5000, "\x00\x00", ",,,,,,,,", "9" * 400,
                     '"unclosed,quote', "nan,nan,nan,nan"]),
)


@pytest.mark.parametrize("fmt", FORMATS, ids=IDS)
@FUZZ
@given(n=st.integers(45, 300), data=st.data(), junk=st.one_of(_JUNK.map(str.encode),
                                                               st.binary(min_size=1, max_size=40).filter(
                                                                   lambda b: b"\n" not in b and b"\r" not in b)))
def test_any_line_past_the_sniffed_ones_is_read_or_named(fmt, n, data, junk):
    lines = [s.encode() for s in _lines(fmt, n)]
    at = data.draw(st.integers(len(fmt.head), len(lines) - 1), label="replaced line index")
    lines[at] = junk
    path = _write(fmt.name, b"\n".join(lines) + b"\n")
    try:
        fmt.read(path)
    except StationError as exc:
        assert _names_line(str(exc), path, at + 1), f"line {at + 1} not named: {exc}"


# -- any number ---------------------------------------------------------------------------------------------
_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(allow_subnormal=True, min_value=-1e-300, max_value=1e-300).map(repr),
    st.integers(-10**400, 10**400).map(str),
    st.sampled_from(["1e308", "-1e308", "1.7976931348623157e308", "5e-324", "-5e-324", "2.2250738585072014e-308",
                     "1" + "0" * 400, "-" + "9" * 300, "1e-400", "nan", "inf", "-inf", "NaN", "Infinity",
                     "999999.999", "1000000.001", "1e6", "-1e6", "0", "-0.0"]),
)


@pytest.mark.parametrize("fmt", FORMATS, ids=IDS)
@FUZZ
@given(n=st.integers(45, 300), data=st.data(), number=_NUMBERS)
def test_any_number_is_read_exactly_or_refused_by_its_line(fmt, n, data, number):
    lines = _lines(fmt, n)
    k = data.draw(st.integers(0, n - 1), label="row")
    cells = fmt.row(k)
    cells[fmt.number_cell] = number
    lines[len(fmt.head) + k] = fmt.sep.join(cells)
    path = _write(fmt.name, ("\n".join(lines) + "\n").encode())
    value = float(number)
    good = math.isfinite(value) and abs(value) <= fmt.limit
    try:
        res = fmt.read(path)
    except StationError as exc:
        assert not good, f"{number} refused: {exc}"
        assert _names_line(str(exc), path, len(fmt.head) + k + 1), f"line not named: {exc}"
        return
    assert good, f"{number} accepted"
    if k == 0:
        assert fmt.value(res) == value
