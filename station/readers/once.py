"""Inputs that can be read only once: standard input (``-``) and pipes (``<(cat f)``, ``/dev/fd/N``).

Some readers look at a file twice (its first lines to sniff the format, then the
whole of it); a pipe gives its content to the first look only. :func:`reads_once`
wraps a reader so that such an input is read once, into a private temporary
file the reader then opens as often as it needs; messages name the input as
the user gave it (``<stdin>`` for ``-``). Regular files are passed through.

The copy is bounded as every input is: at most :data:`MAX_COPY_BYTES` (16 MiB), and a
line longer than the readers take (:data:`~station.readers.text.MAX_LINE_CHARS`)
ends it at once (``/dev/zero`` is refused after 16 KB, not after filling the
disk). A reader that reads its input once, front to back
(``@reads_once(one_pass=True)``), gets the pipe itself: no copy at all. The
temporary file has no name from the moment it is created (it is
unlinked and read through ``/proc/self/fd``), so nothing is left behind however
the process ends, killed included. Small inputs read whole (model files, UR
calibration files) need no copy: :func:`read_bytes` reads at most a bound.
"""

from __future__ import annotations

import functools
import os
import stat
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from station.errors import DataError
from station.readers.text import MAX_LINE_CHARS, MAX_PIPE_BYTES, pipe_too_long

STDIN = "-"
STDIN_NAME = "<stdin>"
#: most bytes copied from standard input or a pipe (a regular file is read where it lies: give the file itself)
MAX_COPY_BYTES = MAX_PIPE_BYTES
#: bytes read at a time
_CHUNK = 1 << 20


def _needs_copy(path) -> bool:
    if str(path) == STDIN:
        return True
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return False  # the reader names what is wrong
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


def shown_name(path) -> str:
    """The name messages give an input: ``<stdin>`` for ``-``, else the path as given."""
    return STDIN_NAME if str(path) == STDIN else str(path)


@contextmanager
def _source(path, shown: str):
    if str(path) == STDIN:
        yield sys.stdin.buffer
        return
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise DataError(f"{shown}: cannot read ({exc.strerror})") from None
    with fh:
        yield fh


@contextmanager
def _nameless_file():
    """``(a writable binary file, a path that opens it again)``: a temporary file without a name on the disk."""
    try:
        fd, name = tempfile.mkstemp(prefix="station-input-")
    except OSError as exc:
        raise DataError(f"no room for a copy of a pipe in {tempfile.gettempdir()} ({exc.strerror})") from None
    proc = f"/proc/self/fd/{fd}"
    named = not os.path.exists(proc)  # no /proc: the name is kept and removed on the way out
    if not named:
        os.unlink(name)
    try:
        with os.fdopen(fd, "w+b") as fh:
            yield fh, (name if named else proc)
    finally:
        if named:
            try:
                os.unlink(name)
            except FileNotFoundError:
                pass


def copy_bounded(src, dst, shown: str, max_bytes: int) -> int:
    """Copy ``src`` to ``dst`` (binary files); DataError past ``max_bytes`` or at a line no reader takes."""
    line_limit = 4 * MAX_LINE_CHARS  # bytes: a line of MAX_LINE_CHARS characters of up to 4 bytes each
    total, line, run = 0, 1, 0  # bytes so far, number of the current line, its bytes so far
    while True:
        chunk = src.read(_CHUNK)
        if not chunk:
            return total
        total += len(chunk)
        if total > max_bytes:
            raise pipe_too_long(shown, max_bytes)
        first = chunk.find(b"\n")
        if first < 0:
            run += len(chunk)
        else:
            if run + first > line_limit:
                run += first
            else:
                line += chunk.count(b"\n")
                run = len(chunk) - chunk.rfind(b"\n") - 1
        if run > line_limit:
            raise DataError(f"{shown}: line {line}: longer than {MAX_LINE_CHARS} characters")
        dst.write(chunk)


@contextmanager
def regular_file(path, *, max_bytes: int | None = None):
    """``(a path to a regular file with the input's content, the name to show)``; a bounded copy for stdin and pipes."""
    if not _needs_copy(path):
        yield path, str(path)
        return
    shown = shown_name(path)
    limit = MAX_COPY_BYTES if max_bytes is None else max_bytes
    with _nameless_file() as (out, real):
        try:
            with _source(path, shown) as src:
                copy_bounded(src, out, shown, limit)
            out.flush()
        except OSError as exc:
            raise DataError(f"{shown}: cannot read ({exc.strerror})") from None
        yield real, shown


def read_bytes(path, max_bytes: int, what: str) -> bytes:
    """The whole of a small input (a file, ``-``, a pipe or a device) in one bounded read; no copy on the disk.

    DataError naming the input when it cannot be read or holds more than
    ``max_bytes`` (``what`` says what the input is, for the message).
    """
    shown = shown_name(path)
    try:
        with _source(path, shown) as src:
            data = src.read(max_bytes + 1)
    except OSError as exc:
        raise DataError(f"{shown}: cannot read ({exc.strerror})") from None
    if len(data) > max_bytes:
        raise DataError(f"{shown}: larger than {max_bytes} bytes; {what}")
    return data


def read_text(path, max_bytes: int, what: str) -> str:
    """:func:`read_bytes` decoded as UTF-8 (a BOM allowed); DataError naming the line of a bad byte."""
    raw = read_bytes(path, max_bytes, what)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise DataError(f"{shown_name(path)}: line {line}: not UTF-8 text") from None


def reads_once(reader=None, *, one_pass: bool = False):
    """Wrap ``reader(path, ...)`` so that stdin (``-``) and pipes work and messages name the input given.

    ``@reads_once(one_pass=True)``: the reader reads its input once, front to
    back, with its own bounds on lines and rows; a pipe or a device is then
    handed to it as it is (standard input as ``/proc/self/fd/0``), without a
    copy on the disk. Otherwise the input is copied (:func:`regular_file`).
    """
    if reader is None:
        return functools.partial(reads_once, one_pass=one_pass)

    @functools.wraps(reader)
    def wrapper(path, *args, **kwargs):
        direct = _direct_path(path) if one_pass else None
        if direct is not None:
            return _as_given(reader, direct, shown_name(path), args, kwargs)
        with regular_file(path) as (real, shown):
            if real is path:
                return reader(path, *args, **kwargs)
            return _as_given(reader, str(real), shown, args, kwargs)

    return wrapper


def _as_given(reader, real: str, shown: str, args, kwargs):
    """``reader(real, ...)`` with ``real`` named as ``shown`` in its result and its messages."""
    try:
        return _renamed(reader(real, *args, **kwargs), real, shown)
    except DataError as exc:
        raise DataError(str(exc).replace(real, shown)) from None


def _direct_path(path) -> str | None:
    """A path that opens a pipe or device input where it is, or None (a regular file, or no such path)."""
    if str(path) != STDIN:
        return str(path) if _needs_copy(path) else None
    try:
        fd = sys.stdin.fileno()  # no descriptor (a stand-in for stdin): copied instead
    except (AttributeError, ValueError, OSError):
        return None
    proc = f"/proc/self/fd/{fd}"
    return proc if os.path.exists(proc) else None


def _renamed(result, real: str, shown: str):
    """The reader's result with its ``source`` naming the input given, not the private copy."""
    import dataclasses

    if dataclasses.is_dataclass(result) and getattr(result, "source", None) == real:
        return dataclasses.replace(result, source=shown)
    return result
