"""PLY point clouds: round trips and malformed files refused (drivers.ply)."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest

from drivers.ply import parse_ply, read_ply, write_ply
from station.errors import DataError


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("dtype", ["float", "double"])
def test_round_trip(tmp_path, rng, binary, dtype):
    pts = rng.normal(0, 500, (1234, 3))
    path = tmp_path / "scan.ply"
    assert write_ply(path, pts, binary=binary, dtype=dtype, comments=["simulated scan"]) == 1234
    back = read_ply(path)
    expect = pts.astype(np.float32).astype(float) if dtype == "float" else pts
    np.testing.assert_array_equal(back, expect)
    assert not (tmp_path / "scan.ply.tmp").exists()


def test_empty_cloud_round_trip(tmp_path):
    write_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    assert read_ply(tmp_path / "e.ply").shape == (0, 3)


def test_foreign_layouts():
    # big endian, extra properties, an element before the vertices, faces after
    verts = [(1.5, -2.0, 3.25, 0.0, 0.0, 1.0, 200), (4.0, 5.0, -6.5, 1.0, 0.0, 0.0, 7)]
    header = (
        "ply\nformat binary_big_endian 1.0\ncomment from another tool\n"
        "element camera 1\nproperty float fx\nproperty uchar id\n"
        "element vertex 2\nproperty double x\nproperty double y\nproperty double z\n"
        "property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    body = struct.pack(">fB", 500.0, 3)
    for v in verts:
        body += struct.pack(">dddfffB", *v)
    body += struct.pack(">Biii", 3, 0, 1, 1)
    pts = parse_ply(header + body)
    np.testing.assert_array_equal(pts, [[1.5, -2.0, 3.25], [4.0, 5.0, -6.5]])
    ascii_ply = b"ply\r\nformat ascii 1.0\r\nelement vertex 2\r\nproperty float z\r\nproperty float y\r\n" \
                b"property float x\r\nend_header\r\n1 2 3\r\n4 5 6\r\n"
    np.testing.assert_array_equal(parse_ply(ascii_ply), [[3, 2, 1], [6, 5, 4]])


GOOD_HEAD = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"


@pytest.mark.parametrize(
    "data, message",
    [
        (b"PLX\nformat ascii 1.0\nend_header\n", "not a PLY file"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "no 'end_header'"),
        (b"ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown format"),
        (b"ply\nelement vertex 0\nproperty float x\nend_header\n", "no 'format'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n", "no 'z'"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty quad x\nend_header\n", "unknown property type 'quad'"),
        (b"ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", "negative element count"),
        (b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n", "not an integer"),
        (b"ply\nformat ascii 1.0\nelement point 1\nproperty float x\nend_header\n1\n", "no 'vertex' element"),
        (GOOD_HEAD.replace("2", "1000000000000").encode() + b"\x00" * 24, "declares 1000000000000 vertices"),
        (GOOD_HEAD.encode() + b"\x00" * 23, "truncated: header declares 2 vertices \\(24 bytes\\) but only 23"),
        (GOOD_HEAD.replace("binary_little_endian", "ascii").encode() + b"1 2 3\n4 five 6\n", "non-numeric"),
        (GOOD_HEAD.replace("binary_little_endian", "ascii").encode() + b"1 2 3\n", "only 1 data lines"),
        (GOOD_HEAD.replace("binary_little_endian", "ascii").encode() + b"1 2 3 4\n5 6\n", "3 values each"),
        (GOOD_HEAD.replace("binary_little_endian", "ascii").encode() + b"1 2 3\nnan 5 6\n", "vertex 1: x = nan is not a finite"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nproperty float y\nproperty float z\nend_header\n",
         "list property"),
        (b"ply\nformat ascii 1.0\nbogus line\nend_header\n", "unexpected keyword 'bogus'"),
    ],
)
def test_malformed_refused(data, message):
    t0 = time.monotonic()
    with pytest.raises(DataError, match=message):
        parse_ply(data, source="test.ply")
    assert time.monotonic() - t0 < 1.0  # refused at once, nothing huge allocated


def test_write_refuses_bad_points(tmp_path):
    with pytest.raises(DataError, match=r"shape \(N, 3\)"):
        write_ply(tmp_path / "x.ply", np.zeros((3, 2)))
    with pytest.raises(DataError, match="non-finite"):
        write_ply(tmp_path / "x.ply", np.array([[0.0, np.inf, 1.0]]))
    with pytest.raises(DataError, match="single lines"):
        write_ply(tmp_path / "x.ply", np.zeros((1, 3)), comments=["a\nb"])
    assert not (tmp_path / "x.ply").exists()


def test_file_name_in_errors(tmp_path):
    p = tmp_path / "broken.ply"
    p.write_bytes(b"garbage")
    with pytest.raises(DataError, match="broken.ply"):
        read_ply(p)


def _ascii(ptype: str, rows) -> bytes:
    head = f"ply\nformat ascii 1.0\nelement vertex {len(rows)}\n" + "".join(
        f"property {ptype} {a}\n" for a in "xyz") + "end_header\n"
    return (head + "\n".join(rows) + "\n").encode()


@pytest.mark.parametrize("ptype, row, match", [
    ("uchar", "300 1 2", "x = 300 is not an integer in \\[0, 255\\]"),
    ("int", "1 1.7 2", "y = 1.7 is not an integer"),
    ("int", "1 2 inf", "z = inf is not an integer"),
    ("int", "nan 2 3", "x = nan is not an integer"),
    ("float", "1 2 3#junk", "non-numeric"),
    ("float", "1e39 2 3", "not a finite float32"),
])
def test_ascii_values_the_declared_type_cannot_hold_are_refused_not_cast(ptype, row, match):
    """Issue reproducers: uchar 300 was read as 44, int 1.7 as 1, int inf as -2147483648, '3#junk' as 3."""
    with pytest.raises(DataError, match=match):
        parse_ply(_ascii(ptype, ["0 0 0", row]))
    # the same type holds representable values exactly
    assert parse_ply(_ascii(ptype, ["0 0 0", "1 2 3"])).tolist() == [[0, 0, 0], [1, 2, 3]]
