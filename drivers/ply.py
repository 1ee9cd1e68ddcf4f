"""PLY point clouds: read and write the files 3D scanners produce.

Supported: ``format ascii 1.0``, ``binary_little_endian 1.0`` and
``binary_big_endian 1.0``; a ``vertex`` element with scalar properties that
include ``x``, ``y``, ``z`` (any PLY scalar type; other properties such as
normals or colours are read past). Elements before ``vertex`` must have
scalar properties only (their size is then known); elements after it
(faces, ...) are ignored. Written files hold ``x y z`` as ``float``
(float32) by default or ``double``.

Malformed files are refused with :class:`~station.errors.DataError` naming
the problem (missing magic, unknown format or type, no ``end_header``,
missing ``x/y/z``, a vertex count that does not fit the file, truncated or
non-numeric data, non-finite coordinates). The declared vertex count is
checked against the bytes present before anything is allocated.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from station.errors import DataError

__all__ = ["read_ply", "write_ply", "parse_ply", "MAX_HEADER_BYTES"]

#: the header must end within this many bytes
MAX_HEADER_BYTES = 65536

_TYPES = {
    "char": "i1", "int8": "i1",
    "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4",
    "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def _header(data: bytes, source: str):
    end_marker = data.find(b"end_header", 0, MAX_HEADER_BYTES)
    if not data.startswith(b"ply"):
        raise DataError(f"{source}: not a PLY file (missing 'ply' magic in the first bytes)")
    if end_marker < 0:
        raise DataError(f"{source}: no 'end_header' within the first {MAX_HEADER_BYTES} bytes")
    nl = data.find(b"\n", end_marker)
    body_start = len(data) if nl < 0 else nl + 1
    try:
        text = data[:end_marker].decode("ascii")
    except UnicodeDecodeError as exc:
        raise DataError(f"{source}: header is not ASCII ({exc})") from exc
    lines = [ln.strip() for ln in text.replace("\r", "").split("\n")]
    if lines[0] != "ply":
        raise DataError(f"{source}: first line must be 'ply', got {lines[0]!r}")
    fmt = None
    elements: list[dict] = []
    for no, line in enumerate(lines[1:], start=2):
        if not line or line.startswith("comment") or line.startswith("obj_info"):
            continue
        parts = line.split()
        key = parts[0]
        if key == "format":
            if len(parts) != 3 or parts[1] not in _FORMATS:
                raise DataError(f"{source}: header line {no}: unknown format {line!r} (ascii, binary_little_endian, binary_big_endian)")
            if parts[2] != "1.0":
                raise DataError(f"{source}: header line {no}: unsupported PLY version {parts[2]!r}")
            fmt = parts[1]
        elif key == "element":
            if len(parts) != 3:
                raise DataError(f"{source}: header line {no}: malformed element line {line!r}")
            try:
                count = int(parts[2])
            except ValueError:
                raise DataError(f"{source}: header line {no}: element count {parts[2]!r} is not an integer") from None
            if count < 0:
                raise DataError(f"{source}: header line {no}: negative element count {count}")
            elements.append({"name": parts[1], "count": count, "props": [], "has_list": False})
        elif key == "property":
            if not elements:
                raise DataError(f"{source}: header line {no}: property before any element")
            if len(parts) >= 2 and parts[1] == "list":
                if len(parts) != 5 or parts[2] not in _TYPES or parts[3] not in _TYPES:
                    raise DataError(f"{source}: header line {no}: malformed list property {line!r}")
                elements[-1]["has_list"] = True
                elements[-1]["props"].append((parts[4], None))
            else:
                if len(parts) != 3:
                    raise DataError(f"{source}: header line {no}: malformed property line {line!r}")
                if parts[1] not in _TYPES:
                    raise DataError(f"{source}: header line {no}: unknown property type {parts[1]!r}")
                elements[-1]["props"].append((parts[2], _TYPES[parts[1]]))
        else:
            raise DataError(f"{source}: header line {no}: unexpected keyword {key!r}")
    if fmt is None:
        raise DataError(f"{source}: header has no 'format' line")
    return fmt, elements, body_start


def _check_representable(values: np.ndarray, dtype: np.dtype, axis: str, source: str) -> None:
    """DataError naming the first vertex whose ``axis`` value the declared type cannot hold exactly."""
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(values) | (values != np.round(values)) | (values < info.min) | (values > info.max)
        kind = f"an integer in [{info.min}, {info.max}]"
    else:
        with np.errstate(over="ignore"):
            bad = ~np.isfinite(values) | ~np.isfinite(values.astype(dtype))
        kind = f"a finite {dtype.name}"
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise DataError(f"{source}: vertex {k}: {axis} = {float(values[k]):.10g} is not {kind} (the declared type "
                        f"{dtype.name})")


def parse_ply(data: bytes, source: str = "<bytes>") -> np.ndarray:
    """Parse PLY bytes into vertex coordinates.

    Parameters
    ----------
    data : bytes
        Whole file content.
    source : str
        Name used in error messages.

    Returns
    -------
    points : ndarray, shape (N, 3), float64

    Raises
    ------
    DataError
        Any malformation (see the module docstring).
    """
    fmt, elements, body = _header(data, source)
    names = [e["name"] for e in elements]
    if "vertex" not in names:
        raise DataError(f"{source}: no 'vertex' element in the header")
    vi = names.index("vertex")
    vert = elements[vi]
    if vert["has_list"]:
        raise DataError(f"{source}: the vertex element has a list property; only scalar properties are supported")
    pnames = [p for p, _ in vert["props"]]
    for axis in ("x", "y", "z"):
        if axis not in pnames:
            raise DataError(f"{source}: the vertex element has no '{axis}' property (has {pnames})")
    if len(set(pnames)) != len(pnames):
        raise DataError(f"{source}: duplicate vertex property names {pnames}")
    n = vert["count"]
    cols = [pnames.index(a) for a in ("x", "y", "z")]

    if fmt == "ascii":
        text_lines = data[body:].decode("ascii", errors="replace").splitlines()
        rows = [ln for ln in text_lines if ln.strip()]
        skip = 0
        for e in elements[:vi]:
            skip += e["count"]
        if len(rows) < skip + n:
            raise DataError(f"{source}: truncated: header declares {n} vertices but only {max(len(rows) - skip, 0)} data lines follow")
        block = rows[skip : skip + n]
        width = len(pnames)
        try:
            # no comment character: '1 2 3#junk' is a malformed line, not a line with a comment
            table = (np.loadtxt(io.StringIO("\n".join(block)), dtype=float, ndmin=2, comments=None) if n
                     else np.zeros((0, width)))
        except ValueError as exc:
            if "column" in str(exc) and "convert" not in str(exc):
                raise DataError(f"{source}: vertex lines must have {width} values each ({exc})") from exc
            raise DataError(f"{source}: non-numeric vertex data ({exc})") from exc
        if table.shape != (n, width):
            raise DataError(f"{source}: vertex lines must have {width} values each; got shape {table.shape}")
        pts = table[:, cols]
        # values take the declared type (a 'float' column holds float32 values); a value the type
        # cannot hold is refused, never cast (uchar 300 is not 44, int 1.7 is not 1)
        types = [vert["props"][c][1] for c in cols]
        for i, t in enumerate(types):
            _check_representable(pts[:, i], np.dtype(t), "xyz"[i], source)
        pts = np.column_stack([pts[:, i].astype(types[i]).astype(float) for i in range(3)]) if n else np.zeros((0, 3))
    else:
        endian = _FORMATS[fmt]
        offset = body
        for e in elements[:vi]:
            if e["has_list"]:
                raise DataError(f"{source}: element {e['name']!r} before 'vertex' has a list property; cannot skip it")
            rec = sum(np.dtype(t).itemsize for _, t in e["props"])
            offset += rec * e["count"]
        dtype = np.dtype([(p, endian + t) for p, t in vert["props"]])
        need = dtype.itemsize * n
        have = len(data) - offset
        if have < need:
            raise DataError(
                f"{source}: truncated: header declares {n} vertices ({need} bytes) but only {max(have, 0)} bytes follow"
            )
        arr = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
        pts = np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(float) if n else np.zeros((0, 3))
    if not np.all(np.isfinite(pts)):
        bad = int(np.argmax(~np.all(np.isfinite(pts), axis=1)))
        raise DataError(f"{source}: vertex {bad} has a non-finite coordinate")
    return np.ascontiguousarray(pts, dtype=float).reshape(n, 3)


def read_ply(path) -> np.ndarray:
    """Read the ``x, y, z`` of every vertex of a PLY file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    points : ndarray, shape (N, 3)

    Raises
    ------
    DataError
        Malformed file (see the module docstring).
    OSError
        The file cannot be read.
    """
    p = Path(path)
    return parse_ply(p.read_bytes(), source=str(p))


def write_ply(path, points, *, binary: bool = True, dtype: str = "float", comments=()) -> int:
    """Write points as a PLY file (atomically: temp file, then rename).

    Parameters
    ----------
    path : str or os.PathLike
    points : array_like, shape (N, 3)
        Finite coordinates, mm.
    binary : bool
        ``binary_little_endian`` (default) or ``ascii``.
    dtype : {"float", "double"}
        Property type of ``x, y, z``.
    comments : iterable of str
        Header comments (single lines).

    Returns
    -------
    int
        Number of vertices written.

    Raises
    ------
    DataError
        Wrong shape, non-finite points, bad dtype or a comment with a newline.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DataError(f"`points` must have shape (N, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise DataError("`points` contains non-finite coordinates")
    if dtype not in ("float", "double"):
        raise DataError(f"`dtype` must be 'float' or 'double', got {dtype!r}")
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0"]
    for c in comments:
        c = str(c)
        if "\n" in c or "\r" in c:
            raise DataError("PLY comments must be single lines")
        head.append(f"comment {c}")
    head += [f"element vertex {pts.shape[0]}"] + [f"property {dtype} {a}" for a in "xyz"] + ["end_header"]
    header = ("\n".join(head) + "\n").encode("ascii")
    if binary:
        body = pts.astype("<f4" if dtype == "float" else "<f8").tobytes()
    else:
        buf = io.BytesIO()
        arr = pts.astype(np.float32).astype(float) if dtype == "float" else pts
        np.savetxt(buf, arr, fmt="%.9g" if dtype == "float" else "%.17g")
        body = buf.getvalue()
    target = Path(path)
    tmp = target.with_name(target.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(header)
        fh.write(body)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, target)
    return int(pts.shape[0])
