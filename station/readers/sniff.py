"""Which reader a stream file needs, from its first lines (``--format`` overrides).

* ``csv``: the project's stream CSV, a comma-separated header line naming
  ``t``, ``x``, ``y``, ``z`` (or starting with ``t`` and naming a coordinate)
  (:mod:`station.readers.stream_csv`);
* ``sa``: a SpatialAnalyzer point export, ``//`` comment lines naming
  SpatialAnalyzer or an ``AXES =`` line (:mod:`station.readers.spatial_analyzer`);
* ``points``: anything else is read as a plain point list
  (:mod:`station.readers.point_list`), which refuses what it cannot read.
"""

from __future__ import annotations

from pathlib import Path

from station.errors import ConfigError, DataError
from station.readers.once import reads_once
from station.readers.point_list import read_point_list
from station.readers.spatial_analyzer import looks_like_sa, read_sa_points
from station.readers.stream import PointStream
from station.readers.stream_csv import STREAM_REQUIRED, read_stream_csv
from station.readers.text import head_lines

FORMATS = ("csv", "sa", "points")
FORMAT_NAMES = {"csv": "the project's stream CSV", "sa": "a SpatialAnalyzer point export",
                "points": "a plain point list"}


def sniff_format(path) -> str:
    """``csv``, ``sa`` or ``points`` from the file's first lines."""
    head = head_lines(path)
    if not any(line.strip() for line in head):
        raise DataError(f"{path}: line 1: empty file")
    if looks_like_sa(head):
        return "sa"
    first = next(line for line in head if line.strip())
    names = [c.strip().lower() for c in first.split(",")]
    # a comma-separated header naming the time and a coordinate: the project's CSV (perhaps lacking a column,
    # which its reader names)
    if names[0] == STREAM_REQUIRED[0] and any(c in names for c in STREAM_REQUIRED[1:]):
        return "csv"
    if all(c in names for c in STREAM_REQUIRED):
        return "csv"
    return "points"


@reads_once
def read_stream_file(path, fmt: str | None = None, *, group: str | None = None,
                     date_order: str | None = None) -> PointStream:
    """Read a stream in any known format (sniffed unless ``fmt`` is given); ``date_order`` for SpatialAnalyzer
    stamps whose day/month order the file does not settle (:mod:`station.readers.date_time`)."""
    p = Path(path)
    if fmt is not None and fmt not in FORMATS:
        raise ConfigError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    fmt = fmt or sniff_format(p)
    if group is not None and fmt != "sa":
        raise ConfigError(f"--group applies to SpatialAnalyzer exports; {p} is read as {FORMAT_NAMES[fmt]}")
    if fmt == "csv":
        return read_stream_csv(p)
    if fmt == "sa":
        return read_sa_points(p, group, date_order=date_order)
    return read_point_list(p)
