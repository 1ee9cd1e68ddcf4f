"""The arm measurement CSV: ``q1..q6`` (deg), ``x,y,z`` (mm, instrument frame), optional
``t`` (s), ``temperature`` (degC), ``load`` (kg); one row per measured pose, in measurement order.

Read line by line with an explicit encoding and bounded lines and fields;
anything it cannot read is refused with the file, line and column, and
nothing is returned half-read.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.text import MAX_ABS_MM, MAX_ABS_S, numbered_lines

REQUIRED = ("q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z")
OPTIONAL = ("t", "temperature", "load")
#: columns of a run's export (``station store export``) that are not measurements: accepted and not read
IGNORED = ("pose", "step_idx", "q_measured")
#: most poses of one file: a calibration measures tens to a few thousand stops (each some seconds); 20,000 is
#: more than a day of stops at 5 s each, and more than the identification and the diagnosis handle in minutes
MAX_ROWS = 20_000
#: largest value per column a robot and its instruments give (deg, mm, s, degC, kg); beyond is a unit or export
#: error: ten turns of a joint, 1 km, the year 2286 in Unix time, 1000 degC, 100 t
LIMITS = {**{f"q{k}": 3600.0 for k in range(1, 7)}, "x": MAX_ABS_MM, "y": MAX_ABS_MM, "z": MAX_ABS_MM,
          "t": MAX_ABS_S, "temperature": 1000.0, "load": 1.0e5}


@dataclass(frozen=True)
class ArmData:
    """Measured poses: ``q_deg`` (N, 6), ``xyz_mm`` (N, 3) and the optional columns (N,) or None."""

    q_deg: np.ndarray
    xyz_mm: np.ndarray
    t_s: np.ndarray | None = None
    temperature_c: np.ndarray | None = None
    load_kg: np.ndarray | None = None
    source: str = ""
    lines: np.ndarray | None = None  # (N,) file line of each pose, for messages

    @property
    def n(self) -> int:
        return int(self.q_deg.shape[0])


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_arm_csv(path) -> ArmData:
    """Read an arm measurement CSV; DataError naming file, line and column on anything wrong."""
    p = Path(path)
    header: list[str] | None = None
    rows: list[list[float]] = []
    lines: list[int] = []
    for lineno, line in numbered_lines(p):  # explicit encoding, bounded lines (station/readers/text.py)
        if header is None:
            header = _header(p, line)
            ncol = len(header)
            continue
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != ncol:
            raise DataError(f"{p}:{lineno}: {len(cells)} fields, the header has {ncol}")
        vals = []
        for col, (name, cell) in enumerate(zip(header, cells), 1):
            if name in IGNORED or (name == "t" and cell.strip().lower() in ("nan", "")):
                vals.append(math.nan)  # a run's export has t = nan where the instrument gave no time
                continue
            try:
                v = float(cell.strip())
            except ValueError:
                raise DataError(f"{p}:{lineno}:{col} ({name}): not a number: {cell.strip()[:40]!r}") from None
            if not math.isfinite(v):
                raise DataError(f"{p}:{lineno}:{col} ({name}): {cell.strip()[:40]} is not a finite number")
            if abs(v) > LIMITS[name]:
                raise DataError(f"{p}:{lineno}:{col} ({name}): {v:.6g} is beyond {LIMITS[name]:g}, "
                                "more than any robot or instrument gives (units? export error?)")
            vals.append(v)
        if len(rows) >= MAX_ROWS:
            raise DataError(f"{p}:{lineno}: more than {MAX_ROWS} poses; a calibration measures a few thousand "
                            "at most (split the file)")
        rows.append(vals)
        lines.append(lineno)
    if header is None:
        raise DataError(f"{p}: empty file (expected a header {','.join(REQUIRED)})")
    if not rows:
        raise DataError(f"{p}: no data rows")
    a = np.array(rows, dtype=float)
    col = {h: a[:, i] for i, h in enumerate(header)}
    if "t" in col and np.isnan(col["t"]).any():
        if not np.isnan(col["t"]).all():
            raise DataError(f"{p}: t: no time on some rows (nan or empty), a time on others; give t on every row "
                            "or on none")
        col["t"] = None
    return ArmData(q_deg=np.column_stack([col[f"q{k}"] for k in range(1, 7)]),
                   xyz_mm=np.column_stack([col["x"], col["y"], col["z"]]),
                   t_s=col.get("t"), temperature_c=col.get("temperature"), load_kg=col.get("load"), source=str(p),
                   lines=np.array(lines, dtype=np.int64))


def _header(p: Path, header_line: str) -> list[str]:
    header = [h.strip() for h in header_line.strip().split(",")]
    if header != [h for h in header if h]:
        raise DataError(f"{p}:1: empty column name in the header")
    unknown = [h for h in header if h not in REQUIRED + OPTIONAL + IGNORED]
    if unknown:
        raise DataError(f"{p}:1: unknown column(s) {', '.join(unknown)} "
                        f"(expected {','.join(REQUIRED)} and optionally {','.join(OPTIONAL)})")
    missing = [h for h in REQUIRED if h not in header]
    if missing:
        raise DataError(f"{p}:1: missing column(s) {', '.join(missing)}")
    if len(set(header)) != len(header):
        raise DataError(f"{p}:1: a column appears twice")
    return header


def write_arm_csv(path, q_deg, xyz_mm, **optional) -> None:
    """Write an arm measurement CSV (``optional``: ``t``, ``temperature``, ``load`` arrays)."""
    q = np.asarray(q_deg, dtype=float)
    x = np.asarray(xyz_mm, dtype=float)
    cols = [f"q{k}" for k in range(1, 7)] + ["x", "y", "z"]
    data = [q[:, k] for k in range(6)] + [x[:, k] for k in range(3)]
    for name in OPTIONAL:
        if optional.get(name) is not None:
            cols.append(name)
            data.append(np.asarray(optional[name], dtype=float))
    from station.readers.out_files import output_file

    with output_file(path, newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for row in np.column_stack(data):
            w.writerow([repr(float(v)) for v in row])
