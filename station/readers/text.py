"""Line-oriented text input shared by the readers: explicit encoding, bounded lines, numbered.

Every reader refuses what it cannot read with a :class:`~station.errors.DataError`
that names the file and the line (and the column where there is one), and
returns nothing until the whole file has been read.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

from station.errors import DataError

#: longest line accepted (a row of a dozen numbers and a time stamp is far shorter)
MAX_LINE_CHARS = 4096
#: most data rows accepted from one file
MAX_ROWS = 20_000_000


def numbered_lines(path) -> Iterator[tuple[int, str]]:
    """``(line number from 1, text without the line end)`` for every line of a UTF-8 file (BOM allowed)."""
    p = Path(path)
    try:
        fh = open(p, encoding="utf-8-sig", newline="")
    except OSError as exc:
        raise DataError(f"{p}: cannot read ({exc.strerror})") from None
    with fh:
        ln = 0
        while True:
            ln += 1
            try:
                line = fh.readline(MAX_LINE_CHARS + 1)
            except UnicodeDecodeError as exc:
                raise DataError(f"{p}: line {ln}: not UTF-8 text ({exc.reason})") from None
            if not line:
                return
            if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
                raise DataError(f"{p}: line {ln}: longer than {MAX_LINE_CHARS} characters")
            yield ln, line.rstrip("\r\n")


def head_lines(path, n: int = 40) -> list[str]:
    """The first ``n`` lines (for sniffing the format); DataError if the file cannot be read."""
    out = []
    for _, line in numbered_lines(path):
        out.append(line)
        if len(out) >= n:
            break
    return out


def parse_number(cell: str, path, ln: int, column: str) -> float:
    """A finite float from a cell, or a DataError naming file, line and column."""
    text = cell.strip()
    try:
        v = float(text)
    except ValueError:
        what = "empty" if not text else f"{text[:40]!r} is not a number"
        raise DataError(f"{path}: line {ln}, column {column!r}: {what}") from None
    if not math.isfinite(v):
        raise DataError(f"{path}: line {ln}, column {column!r}: {text} is not a finite number")
    return v


def is_number(cell: str) -> bool:
    try:
        float(cell.strip())
    except ValueError:
        return False
    return True


def csv_records(path, required: tuple, *, what: str, optional: tuple | None = None) -> Iterator[tuple[int, dict]]:
    """``(line number, {column: stripped cell})`` for every data row of a CSV with a header line.

    The header (names lower-cased) must hold ``required``; with ``optional``
    given, no other column is accepted; no column twice. A row with another
    field count, or a file without a header, is a DataError naming the line.
    ``what`` names the kind of file in the messages.
    """
    import csv
    import io

    p = Path(path)
    header = None
    for ln, line in numbered_lines(p):
        if not line.strip():
            continue
        cells = [c.strip() for c in next(csv.reader(io.StringIO(line)))]
        if header is None:
            header = [c.lower() for c in cells]
            missing = [c for c in required if c not in header]
            if missing:
                extra = "" if optional is None else "".join(f"[,{c}]" for c in optional)
                raise DataError(f"{p}: line {ln}: missing column(s) {', '.join(missing)} "
                                f"({what} has {','.join(required)}{extra})")
            unknown = [] if optional is None else [c for c in header if c not in required + optional]
            if unknown:
                raise DataError(f"{p}: line {ln}: unknown column(s) {', '.join(unknown)}")
            if len(set(header)) != len(header):
                raise DataError(f"{p}: line {ln}: a column appears twice")
            continue
        if len(cells) != len(header):
            raise DataError(f"{p}: line {ln}: {len(cells)} fields, the header has {len(header)}")
        yield ln, dict(zip(header, cells))
    if header is None:
        raise DataError(f"{p}: line 1: empty file or missing header")

