"""The trailer CSV ``t,kappa,psi[,v][,kappa_cmd]`` (s, 1/m, rad, m/s, 1/m): reader and writer.

Rows in time order; curvature and speed are averages over the interval
ending at ``t`` as odometry reports them. ``v`` is the speed, ``kappa_cmd``
the commanded curvature in force.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.text import MAX_ABS_S, csv_records, parse_number
from station.readers.once import reads_once

TRAILER_COLUMNS = ("t", "kappa", "psi")
#: optional columns: speed (m/s), commanded curvature (1/m, the set points in force)
OPTIONAL_COLUMNS = ("v", "kappa_cmd")
#: refuse files larger than this many rows (a month of 10 Hz data)
MAX_ROWS = 30_000_000


#: largest value a trailer's instruments give, per column (s, 1/m, rad, m/s, 1/m): a curvature of 1 mm radius,
#: a hitch angle of a full turn, 100 m/s; a value beyond is a unit or export error, refused
LIMITS = {"t": MAX_ABS_S, "kappa": 1.0e3, "psi": 2.0 * math.pi, "v": 100.0, "kappa_cmd": 1.0e3}


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_trailer_csv(path) -> dict[str, np.ndarray]:
    """Read a trailer CSV (``t,kappa,psi`` [+ ``v``, ``kappa_cmd``]); DataError names the file, line and column.

    Extra columns are ignored; no column twice. Every line bounded, every
    value finite and within :data:`LIMITS`. Rows must be in strictly
    increasing time.
    """
    path = Path(path)
    cols: dict[str, list] | None = None
    lines: list[int] = []
    for line_no, row in csv_records(path, TRAILER_COLUMNS, what="a trailer CSV"):
        if len(lines) >= MAX_ROWS:
            raise DataError(f"{path}: line {line_no}: more than {MAX_ROWS} rows")
        if cols is None:
            cols = {c: [] for c in TRAILER_COLUMNS + tuple(c for c in OPTIONAL_COLUMNS if c in row)}
        for c, out in cols.items():
            out.append(parse_number(row[c], path, line_no, c, LIMITS[c]))
        lines.append(line_no)
    if cols is None:
        cols = {c: [] for c in TRAILER_COLUMNS}
    data = {c: np.asarray(v, dtype=float) for c, v in cols.items()}
    t = data["t"]
    if t.size >= 2:
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            k = int(bad[0])
            raise DataError(f"{path}: line {lines[k + 1]}, column 't': t must increase strictly; "
                            f"{t[k + 1]:.9g} does not follow {t[k]:.9g} (line {lines[k]})")
    return data


def write_trailer_csv(path, t, kappa, psi, v=None, kappa_cmd=None) -> None:
    """Write a trailer CSV (``t,kappa,psi`` [+ ``v``, ``kappa_cmd``]) in s, 1/m, rad, m/s."""
    cols = [np.asarray(t, float), np.asarray(kappa, float), np.asarray(psi, float)]
    header = ["t", "kappa", "psi"]
    for name, extra in (("v", v), ("kappa_cmd", kappa_cmd)):
        if extra is not None:
            cols.append(np.broadcast_to(np.asarray(extra, float), cols[0].shape))
            header.append(name)
    if len({c.shape for c in cols}) != 1 or cols[0].ndim != 1:
        raise DataError("t, kappa, psi (and v) must be 1-D arrays of one length")
    from station.readers.out_files import output_file

    with output_file(path, newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(zip(*(c.tolist() for c in cols)))
