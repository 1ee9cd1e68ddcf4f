"""Inputs that can be read only once: standard input (``-``) and pipes (``<(cat f)``, ``/dev/fd/N``).

Some readers look at a file twice (its first lines to sniff the format, then the
whole of it); a pipe gives its content to the first look only. :func:`reads_once`
wraps a reader so that such an input is read once, into a private temporary
file the reader then opens as often as it needs; messages name the input as
the user gave it (``<stdin>`` for ``-``). Regular files are passed through.
"""

from __future__ import annotations

import functools
import os
import shutil
import stat
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

from station.errors import DataError

STDIN = "-"
STDIN_NAME = "<stdin>"


def _needs_copy(path) -> bool:
    if str(path) == STDIN:
        return True
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return False  # the reader names what is wrong
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


@contextmanager
def regular_file(path):
    """``(a path to a regular file with the input's content, the name to show)``; a copy for stdin and pipes."""
    if not _needs_copy(path):
        yield path, str(path)
        return
    shown = STDIN_NAME if str(path) == STDIN else str(path)
    with tempfile.TemporaryDirectory(prefix="station-input-") as d:
        copy = Path(d) / "input"
        try:
            with open(copy, "wb") as out:
                if str(path) == STDIN:
                    shutil.copyfileobj(sys.stdin.buffer, out)
                else:
                    with open(path, "rb") as src:
                        shutil.copyfileobj(src, out)
        except OSError as exc:
            raise DataError(f"{shown}: cannot read ({exc.strerror})") from None
        yield copy, shown


def reads_once(reader):
    """Wrap ``reader(path, ...)`` so that stdin (``-``) and pipes work and messages name the input given."""

    @functools.wraps(reader)
    def wrapper(path, *args, **kwargs):
        with regular_file(path) as (real, shown):
            if real is path:
                return reader(path, *args, **kwargs)
            try:
                return _renamed(reader(real, *args, **kwargs), str(real), shown)
            except DataError as exc:
                raise DataError(str(exc).replace(str(real), shown)) from None

    return wrapper


def _renamed(result, real: str, shown: str):
    """The reader's result with its ``source`` naming the input given, not the private copy."""
    import dataclasses

    if dataclasses.is_dataclass(result) and getattr(result, "source", None) == real:
        return dataclasses.replace(result, source=shown)
    return result
