"""Line-oriented text input shared by the readers: explicit encoding, bounded lines, numbered.

Every reader refuses what it cannot read with a :class:`~station.errors.DataError`
that names the file and the line (and the column where there is one), and
returns nothing until the whole file has been read.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from station.errors import DataError

#: longest line accepted (a row of a dozen numbers and a time stamp is far shorter); every line of every file
MAX_LINE_CHARS = 4096
#: most data rows accepted from one file
MAX_ROWS = 20_000_000
#: largest coordinate accepted, mm: 1 km (a laser tracker reaches some 80 m, a total station a few km in the
#: field, never a robot cell); a value beyond is no measurement but a unit or export error
MAX_ABS_MM = 1.0e6
#: largest time stamp accepted, s: the year 2286 in Unix time (stamps relative to a start are far smaller)
MAX_ABS_S = 1.0e10
#: most bytes read from a pipe, a device or standard input: some 400,000 rows, read in seconds and some 100 MB
#: (a reader keeps every row, so an endless pipe of good rows must end well before time and memory do); a
#: larger input is given as the file itself
MAX_PIPE_BYTES = 16 << 20
#: largest regular file a reader taking every line reads in one piece (:func:`numbered_lines`), bytes
WHOLE_FILE_BYTES = 64 << 20


def pipe_too_long(shown, limit: int) -> DataError:
    """The refusal of a pipe (or stdin, a device) that gives more than ``limit`` bytes."""
    return DataError(f"{shown}: more than {limit / (1 << 20):g} MiB from a pipe or standard input "
                     "(give the file itself)")


def read_small_text(path, most_bytes: int, label: str, too_large: str, error: type[Exception] = DataError) -> str:
    """The UTF-8 text (BOM allowed) of a small file, read in one bounded read: ``error`` starting with ``label``
    when it cannot be read, holds more than ``most_bytes`` (``too_large`` says what such a file holds) or is
    not UTF-8 (naming the line)."""
    try:
        with open(path, "rb") as fh:
            raw = fh.read(most_bytes + 1)
    except OSError as exc:
        raise error(f"{label}: cannot read ({exc.strerror})") from None
    if len(raw) > most_bytes:
        raise error(f"{label}: larger than {most_bytes} bytes; {too_large}")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise error(f"{label}: line {line}: not UTF-8 text") from None


def numbered_lines(path, whole: bool = False) -> Iterator[tuple[int, str]]:
    """``(line number from 1, text without the line end)`` for every line of a UTF-8 file (BOM allowed).

    Every line is bounded (:data:`MAX_LINE_CHARS`) and decoded on its own, so
    a bad byte is named on its own line and byte. ``whole``: a regular file of
    at most :data:`WHOLE_FILE_BYTES` is read and decoded in one piece (for a
    reader that takes every line); a file that does not pass as one piece
    (a bad byte, an overlong line) is then read line by line, naming the fault.
    """
    import os
    import stat

    p = Path(path)
    try:
        fh = open(p, "rb")
    except OSError as exc:
        raise DataError(f"{p}: cannot read ({exc.strerror})") from None
    with fh:
        st = os.fstat(fh.fileno())
        if whole and stat.S_ISREG(st.st_mode) and st.st_size <= WHOLE_FILE_BYTES:
            lines = _all_lines(fh, p)
            if lines is not None:
                yield from enumerate(lines, 1)
                return
            fh.seek(0)
        # a pipe or a device is read where it is (no copy): bounded in bytes too, as a copy would be
        limit = None if stat.S_ISREG(st.st_mode) else MAX_PIPE_BYTES
        ln = total = 0
        while True:
            ln += 1
            try:
                raw = fh.readline(4 * MAX_LINE_CHARS + 1)
            except OSError as exc:
                raise DataError(f"{p}: line {ln}: cannot read ({exc.strerror})") from None
            if not raw:
                return
            total += len(raw)
            if limit is not None and total > limit:
                raise pipe_too_long(p, limit)
            if ln == 1 and raw.startswith(b"\xef\xbb\xbf"):
                raw = raw[3:]
            ended = raw.endswith(b"\n")
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                if ended or len(raw) <= 4 * MAX_LINE_CHARS or exc.start < len(raw) - 3:
                    raise DataError(f"{p}: line {ln}, byte {exc.start + 1}: not UTF-8 text ({exc.reason})") from None
                line = raw.decode("utf-8", "replace")  # cut inside a character: overlong anyway
            if len(line.rstrip("\r\n")) > MAX_LINE_CHARS or (not ended and len(raw) > 4 * MAX_LINE_CHARS):
                cr = " (its lines end in CR alone? save the file with LF or CRLF line ends)" \
                    if "\r" in line.rstrip("\r\n") else ""
                raise DataError(f"{p}: line {ln}: longer than {MAX_LINE_CHARS} characters{cr}")
            yield ln, line.rstrip("\r\n")


def _all_lines(fh, p) -> list[str] | None:
    """Every line of a regular file read in one piece, as :func:`numbered_lines` gives them one by one; None when
    the file is not UTF-8 or a line is too long (its line-by-line reading names which)."""
    try:
        raw = fh.read(WHOLE_FILE_BYTES + 1)
    except OSError as exc:
        raise DataError(f"{p}: line 1: cannot read ({exc.strerror})") from None
    if len(raw) > WHOLE_FILE_BYTES:
        return None  # grown since: line by line
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return None
    lines = text.split("\n")
    if lines[-1] == "":
        lines.pop()  # the file ends with a line end
    lines = [line.rstrip("\r") for line in lines]
    if lines and max(map(len, lines)) > MAX_LINE_CHARS:
        return None
    return lines


def max_line_bytes(path, limit: int = 4 * MAX_LINE_CHARS) -> tuple[int, int] | None:
    """``(line number, length in bytes)`` of the first line longer than ``limit`` bytes, or None (one pass).

    For readers that hand a whole file to a fast parser: every line is still
    bounded, not only the first ones.
    """
    import numpy as np

    p = Path(path)
    try:
        fh = open(p, "rb")
    except OSError as exc:
        raise DataError(f"{p}: cannot read ({exc.strerror})") from None
    with fh:
        ln, run = 1, 0  # line number of the current line, bytes of it seen so far
        while True:
            chunk = fh.read(1 << 22)
            if not chunk:
                return (ln, run) if run > limit else None
            nl = np.flatnonzero(np.frombuffer(chunk, dtype=np.uint8) == 10)
            if nl.size == 0:
                run += len(chunk)
                if run > limit:
                    return ln, run
                continue
            lengths = np.diff(nl, prepend=-1)  # bytes of each completed line, its newline counted
            lengths[0] += run
            over = np.flatnonzero(lengths > limit + 1)
            if over.size:
                return ln + int(over[0]), int(lengths[over[0]]) - 1
            ln += nl.size
            run = len(chunk) - int(nl[-1]) - 1
            if run > limit:
                return ln, run


def head_lines(path, n: int = 40) -> list[str]:
    """The first ``n`` lines (for sniffing the format); DataError if the file cannot be read."""
    out = []
    for _, line in numbered_lines(path):
        out.append(line)
        if len(out) >= n:
            break
    return out


def parse_number(cell: str, path, ln: int, column: str, max_abs: float = MAX_ABS_MM) -> float:
    """A finite float of at most ``max_abs`` in size from a cell, or a DataError naming file, line and column.

    ``max_abs`` defaults to :data:`MAX_ABS_MM` (coordinates); give :data:`MAX_ABS_S` for time stamps.
    """
    text = cell.strip()
    try:
        v = float(text)
    except ValueError:
        what = "empty" if not text else f"{text[:40]!r} is not a number"
        raise DataError(f"{path}: line {ln}, column {column!r}: {what}") from None
    if not math.isfinite(v):
        raise DataError(f"{path}: line {ln}, column {column!r}: {text[:40]} is not a finite number")
    if abs(v) > max_abs:
        raise DataError(f"{path}: line {ln}, column {column!r}: {v:.6g} is beyond {max_abs:g}, "
                        "more than any instrument measures (units? export error?)")
    return v


def is_number(cell: str) -> bool:
    try:
        float(cell.strip())
    except ValueError:
        return False
    return True


def _cells(line: str, p, ln: int) -> list[str]:
    """The stripped cells of one CSV line (the csv module's reading, which a line without quotes or CR is split to)."""
    if '"' in line or "\r" in line or "\x00" in line:
        import csv
        import io

        try:
            return [c.strip() for c in next(csv.reader(io.StringIO(line)))]
        except csv.Error as exc:
            raise DataError(f"{p}: line {ln}: not CSV ({exc})") from None
    return [c.strip() for c in line.split(",")]


def _csv_rows(p: Path, required: tuple, what: str, optional: tuple | None, whole: bool = False) -> Iterator:
    """The header (names lower-cased), then ``(line number, cells)`` for every data row: :func:`csv_records`'s
    checks."""
    header = None
    rows = 0
    for ln, line in numbered_lines(p, whole):
        if not line.strip():
            continue
        cells = _cells(line, p, ln)
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
            yield header
            continue
        if len(cells) != len(header):
            raise DataError(f"{p}: line {ln}: {len(cells)} fields, the header has {len(header)}")
        rows += 1
        if rows > MAX_ROWS:
            raise DataError(f"{p}: line {ln}: more than {MAX_ROWS} rows")
        yield ln, cells
    if header is None:
        raise DataError(f"{p}: line 1: empty file or missing header")


def csv_records(path, required: tuple, *, what: str, optional: tuple | None = None) -> Iterator[tuple[int, dict]]:
    """``(line number, {column: stripped cell})`` for every data row of a CSV with a header line.

    The header (names lower-cased) must hold ``required``; with ``optional``
    given, no other column is accepted; no column twice. A row with another
    field count, or a file without a header, is a DataError naming the line.
    ``what`` names the kind of file in the messages.
    """
    rows = _csv_rows(Path(path), required, what, optional)
    header = next(rows)
    for ln, cells in rows:  # loop over data rows
        yield ln, dict(zip(header, cells))


@dataclass(frozen=True)
class CsvColumns:
    """The data rows of a CSV read whole (:func:`csv_columns`): ``lines`` (line number of each row) and
    ``cells[column]`` (a tuple of the stripped cells), and the DataError that ended the reading early, if any
    (the rows before it are here: a reader checks them first, so the first fault in the file is named)."""

    lines: list[int]
    cells: dict[str, tuple[str, ...]]
    error: DataError | None


def csv_columns(path, required: tuple, *, what: str, optional: tuple | None = None) -> CsvColumns:
    """The rows of :func:`csv_records` as columns, in one pass: for readers that check whole columns at once."""
    p = Path(path)
    header: list[str] = []
    lines: list[int] = []
    rows: list[list[str]] = []
    error = None
    try:
        it = _csv_rows(p, required, what, optional, whole=True)
        header = next(it)
        for ln, cells in it:  # loop over data rows
            lines.append(ln)
            rows.append(cells)
    except DataError as exc:
        error = exc
    return CsvColumns(lines, dict(zip(header, zip(*rows))) if rows else {h: () for h in header}, error)
