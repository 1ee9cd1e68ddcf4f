"""Plain point lists: ``id, x, y, z`` (or ``x, y, z``), with or without a header, comma or whitespace separated.

Lines starting with ``#`` or ``//`` are comments. The separator is a comma when
the first data line has one, otherwise whitespace; every line must then have
the same number of fields. A first line whose coordinates are not numbers is a
header: it names the columns (``x``, ``y``, ``z`` required, case-insensitive;
``id``/``name``/``point`` and ``t``/``time`` optional). Without a header, three
fields are ``x, y, z`` and four are ``id, x, y, z``. Positions in mm; a time
column in s. The rows are the points in file order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.stream import PointStream
from station.readers.text import MAX_ABS_S, MAX_ROWS, is_number, numbered_lines, parse_number

ID_NAMES = ("id", "name", "point", "label")
TIME_NAMES = ("t", "time", "t_s")


def _split(s: str, comma: bool) -> list[str]:
    return [c.strip() for c in s.split(",")] if comma else s.split()


def _is_comment(s: str) -> bool:
    return s.startswith("#") or s.startswith("//")


def _columns_from_header(cells: list[str], p, ln: int) -> dict[str, int]:
    low = [c.strip().lower() for c in cells]
    cols = {}
    for want in ("x", "y", "z"):
        if want not in low:
            raise DataError(f"{p}: line {ln}: the header {', '.join(cells)} has no column {want!r}")
        cols[want] = low.index(want)
    for key, names in (("id", ID_NAMES), ("t", TIME_NAMES)):
        hit = [k for k, c in enumerate(low) if c in names]
        if len(hit) > 1:
            raise DataError(f"{p}: line {ln}: more than one {key} column in the header")
        if hit:
            cols[key] = hit[0]
    if len(set(low)) != len(low):
        raise DataError(f"{p}: line {ln}: a column appears twice in the header")
    return cols


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_point_list(path) -> PointStream:
    """Read a plain point list; DataError naming file, line and column for anything malformed."""
    p = Path(path)
    comma = None
    cols: dict[str, int] | None = None
    nfield = None
    ids: list[str] = []
    vals: list[tuple[float, ...]] = []
    lines: list[int] = []
    for ln, line in numbered_lines(p):
        s = line.strip()
        if not s or _is_comment(s):
            continue
        if comma is None:
            comma = "," in s
        cells = _split(s, comma)
        if cols is None:
            nfield = len(cells)
            if nfield < 3:
                raise DataError(f"{p}: line {ln}: {nfield} field(s); a point list needs x, y, z (and an id)")
            if not all(is_number(c) for c in cells[-3:]):
                cols = _columns_from_header(cells, p, ln)
                continue
            if nfield == 3:
                cols = {"x": 0, "y": 1, "z": 2}
            elif nfield == 4:
                cols = {"id": 0, "x": 1, "y": 2, "z": 3}
            else:
                raise DataError(f"{p}: line {ln}: {nfield} fields without a header; expected x, y, z or id, x, y, z "
                                "(name the columns in a header line)")
        if len(cells) != nfield:
            raise DataError(f"{p}: line {ln}: {len(cells)} fields, expected {nfield}"
                            + (" (comma separated)" if comma else " (whitespace separated)"))
        row = [parse_number(cells[cols[c]], p, ln, c) for c in ("x", "y", "z")]
        if "t" in cols:
            row.append(parse_number(cells[cols["t"]], p, ln, "t", MAX_ABS_S))
        vals.append(tuple(row))
        ids.append(cells[cols["id"]] if "id" in cols else str(len(ids) + 1))
        lines.append(ln)
        if len(vals) > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} points")
    if not vals:
        raise DataError(f"{p}: no points in the file")
    a = np.array(vals, dtype=float)
    return PointStream(xyz_mm=a[:, :3], t_s=a[:, 3] if a.shape[1] == 4 else None, valid=np.ones(a.shape[0], bool),
                       line=np.array(lines, dtype=np.int64), names=tuple(ids), fmt="points", source=str(p))
