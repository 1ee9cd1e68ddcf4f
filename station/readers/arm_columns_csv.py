"""Joint-angle and target files of ``station predict arm`` / ``station compensate arm``.

A CSV with a header; the columns a command requires and those it allows
(``q1..q6`` deg, ``x,y,z`` mm, ``t`` s, ``temperature`` degC, ``load`` kg,
``dir1..dir6`` the sign of each joint's last motion, -1/0/+1). Anything it
cannot read is refused with the file, line and column; nothing half-read
is returned.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.text import numbered_lines

Q_COLS = tuple(f"q{k}" for k in range(1, 7))
XYZ_COLS = ("x", "y", "z")
DIR_COLS = tuple(f"dir{k}" for k in range(1, 7))
CONTEXT_COLS = ("t", "temperature", "load") + DIR_COLS
MAX_ROWS = 1_000_000


def read_columns_csv(path, required: tuple, optional: tuple) -> dict:
    """``{column: (N,) array}`` of the file's columns; DataError naming file, line and column."""
    p = Path(path)
    header = None
    rows = []
    for lineno, line in numbered_lines(p):
        if header is None:
            header = [h.strip() for h in line.strip().split(",")]
            unknown = [h for h in header if h not in required + optional]
            if unknown:
                raise DataError(f"{p}:1: unknown column(s) {', '.join(unknown)} (expected {','.join(required)}"
                                f"{' and optionally ' + ','.join(optional) if optional else ''})")
            missing = [h for h in required if h not in header]
            if missing:
                raise DataError(f"{p}:1: missing column(s) {', '.join(missing)}")
            if len(set(header)) != len(header):
                raise DataError(f"{p}:1: a column appears twice")
            group = [c for c in header if c in Q_COLS]
            if group and len(group) != 6:
                raise DataError(f"{p}:1: q1..q6 come together (have {', '.join(group)})")
            group = [c for c in header if c in DIR_COLS]
            if group and len(group) != 6:
                raise DataError(f"{p}:1: dir1..dir6 come together (have {', '.join(group)})")
            continue
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != len(header):
            raise DataError(f"{p}:{lineno}: {len(cells)} fields, the header has {len(header)}")
        vals = []
        for col, (name, cell) in enumerate(zip(header, cells), 1):
            try:
                v = float(cell.strip())
            except ValueError:
                raise DataError(f"{p}:{lineno}:{col} ({name}): not a number: {cell.strip()[:40]!r}") from None
            if not math.isfinite(v):
                raise DataError(f"{p}:{lineno}:{col} ({name}): {cell.strip()} is not a finite number")
            if name in DIR_COLS and v not in (-1.0, 0.0, 1.0):
                raise DataError(f"{p}:{lineno}:{col} ({name}): a direction is -1, 0 or 1, got {cell.strip()}")
            vals.append(v)
        rows.append(vals)
        if len(rows) > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} rows")
    if header is None:
        raise DataError(f"{p}: empty file (expected a header {','.join(required)})")
    if not rows:
        raise DataError(f"{p}: no data rows")
    a = np.array(rows, dtype=float)
    return {h: a[:, i] for i, h in enumerate(header)}


def write_columns_csv(path, columns: dict) -> None:
    """Write ``{name: (N,) array}`` as a CSV (columns in the dict's order)."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[k], dtype=float) for k in names])
    from station.readers.out_files import output_file

    with output_file(path, newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for row in data:
            w.writerow([repr(float(v)) for v in row])
