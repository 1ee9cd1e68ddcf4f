"""SpatialAnalyzer point exports (ASCII), as a lab exports a tracker stream or a set of points.

The file opens with comment lines starting ``//``; of these the reader uses::

    // SpatialAnalyzer ...                                   (marks the format)
    // Points Relative to Coordinate Frame 'A::World'         (the frame, kept)
    // AXES = CARTESIAN: X, Y, Z (mm)                         (required: the units)

then one point per line, comma separated::

    group, point, index, x, y, z[, date time]

Units from the ``AXES`` line (mm, cm, m, in, ft) are converted to mm. Group and
point names are kept. The date-time column, when there is one, becomes ``t_s``
(seconds from the first row); it must be present on every row or on none. The
date forms read, and when the day/month order must be given, are in
:mod:`station.readers.date_time`.

A group is one contiguous block of lines; a group that starts again after
another one (mixed groups) is refused. The stream is one group: the named one,
or else the largest when every other group is small next to it (a stray group
of a few points at the end, measured by hand, is the usual case); those left
out are named in ``notes``. Groups of similar size are refused without a name.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.date_time import FORM_TEXT, parse_stamp, stamps_to_seconds
from station.readers.stream import PointStream
from station.readers.text import MAX_ROWS, is_number, numbered_lines, parse_number

MARKER = "spatialanalyzer"
#: length units of the AXES line -> mm
UNITS_MM = {
    "mm": 1.0, "millimeter": 1.0, "millimeters": 1.0, "millimetre": 1.0, "millimetres": 1.0,
    "cm": 10.0, "centimeter": 10.0, "centimeters": 10.0,
    "m": 1000.0, "meter": 1000.0, "meters": 1000.0, "metre": 1000.0, "metres": 1000.0,
    "in": 25.4, "inch": 25.4, "inches": 25.4,
    "ft": 304.8, "feet": 304.8, "foot": 304.8,
}
#: a group left out of a stream must be smaller than this fraction of the stream's group
STRAY_FRACTION = 0.05
_AXES = re.compile(r"^//\s*AXES\s*=\s*(?P<kind>[A-Za-z]+)\s*:\s*(?P<axes>[^()]*?)\s*(\((?P<unit>[^()]*)\))?\s*$",
                   re.IGNORECASE)
_FRAME = re.compile(r"Coordinate\s+Frame\s+'(?P<frame>[^']*)'", re.IGNORECASE)


def looks_like_sa(head: list[str]) -> bool:
    """A SpatialAnalyzer export: ``//`` comments naming SpatialAnalyzer or carrying an ``AXES =`` line."""
    for line in head:
        s = line.strip()
        if not s:
            continue
        if not s.startswith("//"):
            return False
        if MARKER in s.lower().replace(" ", "") or _AXES.match(s):
            return True
    return False


def parse_axes_line(text: str, path, ln: int) -> tuple[str, float]:
    """``(unit name, mm per unit)`` from ``// AXES = CARTESIAN: X, Y, Z (mm)``; DataError otherwise."""
    m = _AXES.match(text.strip())
    if m is None:
        raise DataError(f"{path}: line {ln}: cannot read the AXES line {text.strip()!r} "
                        "(expected '// AXES = CARTESIAN: X, Y, Z (mm)')")
    if m.group("kind").lower() != "cartesian":
        raise DataError(f"{path}: line {ln}: AXES are {m.group('kind')}; only CARTESIAN X, Y, Z can be read")
    axes = [a.strip().lower() for a in m.group("axes").split(",")]
    if axes != ["x", "y", "z"]:
        raise DataError(f"{path}: line {ln}: AXES {m.group('axes').strip()!r}: expected X, Y, Z")
    unit = (m.group("unit") or "").strip()
    if not unit:
        raise DataError(f"{path}: line {ln}: the AXES line names no unit (expected e.g. '(mm)')")
    if unit.lower() not in UNITS_MM:
        raise DataError(f"{path}: line {ln}: unknown length unit {unit!r} on the AXES line "
                        f"(known: mm, cm, m, in, ft)")
    return unit, UNITS_MM[unit.lower()]


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_sa_points(path, group: str | None = None, *, whole_file: bool = False,
                   date_order: str | None = None) -> PointStream:
    """Read a SpatialAnalyzer point export into a :class:`PointStream`.

    Parameters
    ----------
    path : path-like
    group : str, optional
        The group to return (default: the largest, others must be strays).
    whole_file : bool
        Return every group (a point set, not a stream); ``names`` are then ``group:point``.
    date_order : ``mdy`` or ``dmy``, optional
        Day and month order of ``A/B/Y`` dates when the file does not settle it
        (:mod:`station.readers.date_time`).
    """
    p = Path(path)
    unit = None
    scale = 1.0
    frame = None
    seen_marker = False
    rows: list[tuple[str, str, float, float, float, float | None, int]] = []
    stamps = []
    last_stamp: tuple = (None, None)
    has_time: bool | None = None
    header_seen = False
    for ln, line in numbered_lines(p):
        s = line.strip()
        if not s:
            continue
        if s.startswith("//"):
            if MARKER in s.lower().replace(" ", ""):
                seen_marker = True
            if re.match(r"^//\s*AXES\b", s, re.IGNORECASE):
                if rows:
                    raise DataError(f"{p}: line {ln}: an AXES line after the data starts")
                unit, scale = parse_axes_line(s, p, ln)
            fm = _FRAME.search(s)
            if fm and frame is None:
                frame = fm.group("frame")
            continue
        cells = [c.strip() for c in s.split(",")]
        if not rows and not header_seen and len(cells) >= 6 and not is_number(cells[3]):
            header_seen = True  # an uncommented column header
            continue
        if unit is None and not seen_marker:
            raise DataError(f"{p}: line {ln}: not a SpatialAnalyzer export (no '// SpatialAnalyzer' line and no "
                            "AXES line before the data)")
        if unit is None:
            raise DataError(f"{p}: line {ln}: data before an '// AXES = CARTESIAN: X, Y, Z (unit)' line: "
                            "the units are unknown")
        if len(cells) not in (6, 7):
            raise DataError(f"{p}: line {ln}: {len(cells)} fields; expected group, point, index, x, y, z[, date time]")
        g, name = cells[0], cells[1]
        if not g:
            raise DataError(f"{p}: line {ln}, column 'group': empty")
        x, y, z = (parse_number(cells[k], p, ln, c) for k, c in ((3, "x"), (4, "y"), (5, "z")))
        stamp = cells[6] if len(cells) == 7 else ""
        this_time = bool(stamp)
        if has_time is None:
            has_time = this_time
        elif has_time != this_time:
            raise DataError(f"{p}: line {ln}: " + ("no date time where the rows before have one" if has_time
                                                    else "a date time where the rows before have none"))
        if this_time:
            st = last_stamp[1] if stamp == last_stamp[0] else parse_stamp(stamp)  # coarse stamps repeat
            last_stamp = (stamp, st)
            if st is None:
                raise DataError(f"{p}: line {ln}, column 'date time': {stamp[:40]!r} is not a date and time this "
                                f"reader knows ({FORM_TEXT})")
            stamps.append(st)
        rows.append((g, name, x * scale, y * scale, z * scale, None, ln))
        if len(rows) > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} points")
    if not seen_marker and unit is None:
        raise DataError(f"{p}: not a SpatialAnalyzer export (no '// SpatialAnalyzer' line, no AXES line)")
    if not rows:
        raise DataError(f"{p}: no points after the header")
    reading = None
    if has_time:
        reading = stamps_to_seconds(stamps, date_order=date_order,
                                    where=lambda i: f"{p}: line {rows[i][6]}, column 'date time'")
        rows = [r[:5] + (t,) + r[6:] for r, t in zip(rows, reading.t_s)]
    # groups: contiguous blocks
    blocks: list[tuple[str, int, int]] = []  # (group, first row, last row)
    for k, r in enumerate(rows):
        if blocks and blocks[-1][0] == r[0]:
            blocks[-1] = (r[0], blocks[-1][1], k)
            continue
        earlier = [b for b in blocks if b[0] == r[0]]
        if earlier:
            prev = blocks[-1]
            raise DataError(f"{p}: line {r[6]}: group {r[0]!r} starts again after group {prev[0]!r} "
                            f"(lines {rows[prev[1]][6]}-{rows[prev[2]][6]}); mixed groups cannot be read as one "
                            "stream: export each group on its own")
        blocks.append((r[0], k, k))
    notes = []
    if reading is not None and reading.order is not None:
        why = {"field>12": "a date field above 12 says so", "option": "--date-order",
               "one date": "every stamp has the same date, so the order does not change the intervals",
               "either": "the intervals are the same in either order"}[reading.settled_by]
        notes.append(f"dates A/B/Y read as {'month/day' if reading.order == 'mdy' else 'day/month'} ({why})")
    for i in () if reading is None else reading.leap_rows:
        notes.append(f"line {rows[i][6]}: a leap second (:60) before this line is counted: the stamps from here on "
                     "are one second later than their time of day")
    if whole_file:
        keep = range(len(rows))
        chosen = None
    else:
        sizes = {b[0]: b[2] - b[1] + 1 for b in blocks}
        if group is not None:
            if group not in sizes:
                raise DataError(f"{p}: no group {group!r} (groups: {', '.join(sizes)})")
            chosen = group
        else:
            chosen = max(sizes, key=lambda k: sizes[k])
            big = [b for b in sizes if b != chosen and sizes[b] >= STRAY_FRACTION * sizes[chosen]]
            if big:
                raise DataError(f"{p}: several groups of comparable size ("
                                + ", ".join(f"{b} {sizes[b]} points" for b in [chosen] + big)
                                + "): name the stream's group (--group)")
        for b in blocks:
            if b[0] != chosen:
                notes.append(f"group {b[0]!r} ({b[2] - b[1] + 1} points, lines {rows[b[1]][6]}-{rows[b[2]][6]}) "
                             f"left out: not the stream's group {chosen!r}")
        b = next(b for b in blocks if b[0] == chosen)
        keep = range(b[1], b[2] + 1)
    sel = [rows[k] for k in keep]
    xyz = np.array([[r[2], r[3], r[4]] for r in sel], dtype=float)
    t = np.array([r[5] for r in sel], dtype=float) if has_time else None
    if t is not None:
        t = t - t[0]
    names = tuple((f"{r[0]}:{r[1]}" if whole_file else r[1]) for r in sel)
    return PointStream(xyz_mm=xyz, t_s=t, valid=np.ones(len(sel), bool),
                       line=np.array([r[6] for r in sel], dtype=np.int64), names=names, fmt="sa", source=str(p),
                       group=chosen, frame=frame, units=unit or "mm", notes=tuple(notes))
