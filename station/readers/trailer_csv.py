"""The trailer CSV ``t,kappa,psi[,v][,kappa_cmd]`` (s, 1/m, rad, m/s, 1/m): reader and writer.

Rows in time order; curvature and speed are averages over the interval
ending at ``t`` as odometry reports them. ``v`` is the speed, ``kappa_cmd``
the commanded curvature in force.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from station.errors import DataError

TRAILER_COLUMNS = ("t", "kappa", "psi")
#: optional columns: speed (m/s), commanded curvature (1/m, the set points in force)
OPTIONAL_COLUMNS = ("v", "kappa_cmd")
#: refuse files larger than this many rows (a month of 10 Hz data)
MAX_ROWS = 30_000_000


def read_trailer_csv(path) -> dict[str, np.ndarray]:
    """Read a trailer CSV (``t,kappa,psi`` [+ ``v``, ``kappa_cmd``]); DataError names the bad row/column.

    Extra columns are ignored. Rows must be in strictly increasing time.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from exc
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise DataError(f"{path}: line {line}: not UTF-8 text") from None
    with io.StringIO(text, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration as exc:
            raise DataError(f"{path} is empty (expected a header t,kappa,psi[,v])") from exc
        except csv.Error as exc:
            raise DataError(f"{path}: {exc}") from exc
        names = [h.strip() for h in header]
        missing = [c for c in TRAILER_COLUMNS if c not in names]
        if missing:
            raise DataError(f"{path}: missing column(s) {missing}; the header is {names} "
                            "(expected t,kappa,psi and optionally v)")
        wanted = list(TRAILER_COLUMNS) + [c for c in OPTIONAL_COLUMNS if c in names]
        idx = {c: names.index(c) for c in wanted}
        cols = {c: [] for c in wanted}
        try:
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not x.strip() for x in row):
                    continue
                if len(row) > len(names):
                    raise DataError(f"{path} line {line_no}: {len(row)} fields, the header has {len(names)}")
                if len(cols["t"]) >= MAX_ROWS:
                    raise DataError(f"{path}: more than {MAX_ROWS} rows")
                for c in wanted:
                    try:
                        value = float(row[idx[c]])
                    except IndexError as exc:
                        raise DataError(f"{path} line {line_no}: {len(row)} fields, no column {c!r}") from exc
                    except ValueError as exc:
                        raise DataError(f"{path} line {line_no}, column {c!r}: "
                                        f"{row[idx[c]]!r} is not a number") from exc
                    if not math.isfinite(value):
                        raise DataError(f"{path} line {line_no}, column {c!r}: {value} is not finite")
                    cols[c].append(value)
        except csv.Error as exc:
            raise DataError(f"{path}: {exc}") from exc
    data = {c: np.asarray(v, dtype=float) for c, v in cols.items()}
    t = data["t"]
    if t.size >= 2:
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise DataError(f"{path}: t must increase strictly; row {int(bad[0]) + 3} (t={t[bad[0] + 1]}) "
                            f"does not follow row {int(bad[0]) + 2} (t={t[bad[0]]})")
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
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(zip(*(c.tolist() for c in cols)))
