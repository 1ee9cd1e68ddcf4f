"""The project's tracker stream CSV ``t,x,y,z[,status][,a,b,c]`` and poses CSV ``name,x,y,z[,a,b,c]``.

* stream: ``t`` (s), ``x, y, z`` (mm); rows whose ``status`` is not ``0``/``ok``/
  ``valid`` are flagged invalid (e.g. a broken beam) and may hold empty or NaN
  positions; optional ``a, b, c`` (deg, 6-DOF orientation).
* poses: one commanded pose per row, ``name`` unique.

The time column is read as it stands; whether it can serve as the time base
(sorted, fine enough, consistent with the sample count) is decided by
:mod:`station.analysis.iso9283.time_base`.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.stream import PointStream
from station.readers.text import (
    MAX_ABS_MM, MAX_ABS_S, MAX_LINE_CHARS, MAX_ROWS, csv_columns, max_line_bytes, numbered_lines, parse_number,
)

#: status values that mean "valid sample" (case-insensitive)
OK_STATUS = ("0", "ok", "valid")
STREAM_REQUIRED = ("t", "x", "y", "z")
ORIENTATION = ("a", "b", "c")


def _header(path: Path) -> list[str]:
    for ln, line in numbered_lines(path):
        if not line.strip():
            raise DataError(f"{path}: line {ln}: empty file or missing header")
        try:
            return [h.strip() for h in next(csv.reader([line]))]
        except csv.Error as exc:
            raise DataError(f"{path}: line {ln}: not CSV ({exc})") from None
    raise DataError(f"{path}: line 1: empty file or missing header")


def _scan_for_error(path: Path, header: list[str], float_cols: list[str]) -> None:
    """Find the first malformed line and raise a DataError naming it (slow path)."""
    pos = {c: header.index(c) for c in float_cols}
    with open(path, "rb") as f:
        f.readline()
        for ln, raw in enumerate(f, start=2):
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise DataError(f"{path}: line {ln}, byte {exc.start + 1}: not UTF-8 text") from None
            if not text.strip("\r\n"):
                continue  # an empty line (a line of blanks is a row of one field)
            try:
                row = next(csv.reader([text]))
            except csv.Error as exc:
                raise DataError(f"{path}: line {ln}: not CSV ({exc})") from None
            if len(row) != len(header):
                raise DataError(f"{path}: line {ln}: {len(row)} fields, the header has {len(header)}")
            for c, k in pos.items():
                cell = row[k].strip()
                try:
                    float(cell)
                except ValueError:
                    raise DataError(f"{path}: line {ln}, column {c!r}: {cell[:40]!r} is not a number") from None
    raise DataError(f"{path}: could not be parsed as CSV")


def _status_ok(value: str) -> bool:
    """``0`` (any numeric zero), ``ok`` or ``valid`` mean a valid sample."""
    v = value.strip().lower()
    if v in OK_STATUS:
        return True
    try:
        return float(v) == 0.0
    except ValueError:
        return False


@reads_once
def read_stream_csv(path) -> PointStream:
    """Read a tracker stream CSV; DataError naming file, line and column for anything malformed.

    NaN or empty positions are accepted only in rows flagged invalid by ``status``.
    """
    path = Path(path)
    header = _header(path)
    missing = [c for c in STREAM_REQUIRED if c not in header]
    if missing:
        raise DataError(f"{path}: line 1: missing column(s) {', '.join(missing)} (need t,x,y,z)")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise DataError(f"{path}: line 1: duplicate column(s) {', '.join(dup)}")
    abc = [c for c in ORIENTATION if c in header]
    if abc and len(abc) != 3:
        raise DataError(f"{path}: line 1: orientation needs all of a,b,c, got {','.join(abc)}")
    floats = list(STREAM_REQUIRED) + abc
    has_status = "status" in header
    # every line bounded, not only the header: pyarrow below reads the whole file at once
    long = max_line_bytes(path)
    if long is not None:
        raise DataError(f"{path}: line {long[0]}: longer than {MAX_LINE_CHARS} characters")
    import pyarrow as pa
    from pyarrow import csv as pacsv

    try:
        types = {c: pa.float64() for c in floats}
        if has_status:
            types["status"] = pa.string()
        table = pacsv.read_csv(
            str(path),
            # the header as read above (names stripped: 't,x,y, z' names the column 'z')
            read_options=pacsv.ReadOptions(column_names=header, skip_rows=1),
            parse_options=pacsv.ParseOptions(ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types=types, include_columns=floats
                                                 + (["status"] if has_status else []),
                                                 strings_can_be_null=False),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowKeyError, UnicodeDecodeError):
        _scan_for_error(path, header, floats)
        raise  # pragma: no cover  (_scan_for_error always raises)
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc})") from exc
    out = {c: table.column(c).to_numpy(zero_copy_only=False).astype(float) for c in floats}
    n = table.num_rows
    if n == 0:
        raise DataError(f"{path}: no data rows after the header")
    if has_status:
        # the distinct status values once each (never a fixed-width array as wide as the longest cell)
        enc = table.column("status").combine_chunks().dictionary_encode()
        ok = np.array([_status_ok(u) for u in enc.dictionary.to_pylist()], dtype=bool)
        valid = ok[enc.indices.to_numpy(zero_copy_only=False).astype(np.int64)] if ok.size else np.ones(n, bool)
    else:
        valid = np.ones(n, bool)
    for c in floats:
        bad = ~np.isfinite(out[c]) if c == "t" else (~np.isfinite(out[c]) & valid)
        if bad.any():
            r = int(np.argmax(bad))
            what = "empty or not a number" if np.isnan(out[c][r]) else f"{float(out[c][r])} is not finite"
            hint = "" if c == "t" else " (flag such rows with a status instead)"
            raise DataError(f"{path}: line {r + 2}, column {c!r}: {what}{hint}")
        limit = MAX_ABS_S if c == "t" else (MAX_ABS_MM if c in "xyz" else 3600.0)
        big = (np.abs(out[c]) > limit) & (valid if c != "t" else True)
        if big.any():
            r = int(np.argmax(big))
            raise DataError(f"{path}: line {r + 2}, column {c!r}: {float(out[c][r]):.6g} is beyond {limit:g}, "
                            "more than any instrument measures (units? export error?)")
    xyz = np.stack([out["x"], out["y"], out["z"]], axis=1)
    abc_deg = np.stack([out["a"], out["b"], out["c"]], axis=1) if abc else None
    return PointStream(xyz_mm=xyz, t_s=out["t"], valid=valid, line=np.arange(n, dtype=np.int64) + 2,
                       abc_deg=abc_deg, fmt="csv", source=str(path))


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_poses_csv(path) -> tuple[list[str], np.ndarray, np.ndarray | None]:
    """Read ``name,x,y,z[,a,b,c]``; returns names, positions (P,3) mm, orientation (P,3) deg or None.

    Every line bounded and decoded on its own (:func:`~station.readers.text.numbered_lines`). The columns are
    checked whole; anything they do not pass is checked again row by row, naming the first fault.
    """
    path = Path(path)
    got = csv_columns(path, ("name", "x", "y", "z"), what="a poses file")
    c = got.cells
    abc = [k for k in ORIENTATION if k in c]
    if got.lines and abc and len(abc) != 3:  # checked at the first row
        raise DataError(f"{path}: orientation needs all of a,b,c, got {','.join(abc)}")
    cols = ["x", "y", "z"] + abc
    arr = None if got.error is not None or not got.lines else _poses_whole(c, cols)
    if arr is None:
        seen: set[str] = set()
        rows = []
        for i, ln in enumerate(got.lines):  # loop over rows: the first fault named
            name = c["name"][i]
            if not name:
                raise DataError(f"{path}: line {ln}, column 'name': empty")
            if name in seen:
                raise DataError(f"{path}: line {ln}, column 'name': duplicate pose {name[:40]!r}")
            seen.add(name)
            rows.append([parse_number(c[k][i], path, ln, k, MAX_ABS_MM if k in "xyz" else 3600.0) for k in cols])
            if len(rows) > MAX_ROWS:
                raise DataError(f"{path}: more than {MAX_ROWS} poses")
        if got.error is not None:
            raise got.error
        if not rows:
            raise DataError(f"{path}: no poses after the header")
        arr = np.array(rows)
    return list(c["name"]), arr[:, :3], (arr[:, 3:] if len(cols) > 3 else None)


def _poses_whole(c: dict, cols: list[str]) -> np.ndarray | None:
    """The poses' numbers (P, 3 or 6), checked whole; None when a check fails (the rows then say which)."""
    names = c["name"]
    if "" in names or len(set(names)) != len(names):
        return None
    try:
        arr = np.array([list(map(float, c[k])) for k in cols]).T
    except ValueError:
        return None
    bound = np.array([MAX_ABS_MM if k in "xyz" else 3600.0 for k in cols])
    if not (np.all(np.isfinite(arr)) and np.all(np.abs(arr) <= bound)):
        return None
    return np.ascontiguousarray(arr)
