"""Output files of the command line: written only over a regular file (or a new one), whole or not at all.

Every output path option (``--out``, ``--json``, ``--report``, ``--model-out``,
``--ur-deltas``) goes through :func:`check_output` (before anything is
computed) and :func:`output_file` / :func:`write_output` (to write). What is
already at the path decides: nothing or a regular file is fine; a directory,
a device node (``/dev/full``), a pipe or a socket is refused, naming what is
there, and is never replaced. A path under a regular file, an over-long name
or a place nothing can be written to (``/proc``) is refused the same way.
The content goes to a private temporary file beside the target, which then
replaces it in one step: a write that fails leaves the old file as it was
and no temporary file behind.

Output directories (``simulate --out DIR``, ``store export --out DIR``) go
through :func:`output_dir`: an existing directory or a new one; anything
else is refused.
"""

from __future__ import annotations

import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

from station.errors import ConfigError

__all__ = ["check_output", "check_outputs", "output_file", "write_output", "output_dir", "what_is_there"]

#: longest file name of one path component, bytes (the common file systems' limit)
MAX_NAME_BYTES = 255


def what_is_there(mode: int) -> str:
    """The kind of file an ``st_mode`` names, in words."""
    for test, name in ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a pipe"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "not a regular file"


def _refuse(option: str, path, why: str) -> ConfigError:
    text = str(path)
    return ConfigError(f"{option} {text if len(text) <= 120 else text[:100] + '...'}: {why}")


def _check_names(path: Path, option: str, *, file: bool = True) -> None:
    if not str(path) or (file and (str(path).endswith(os.sep) or path.name in ("", ".", ".."))):
        raise _refuse(option, path, "not a file name")
    for part in path.parts:
        if len(os.fsencode(part)) > MAX_NAME_BYTES:
            raise _refuse(option, path, f"a name of {len(os.fsencode(part))} bytes; at most {MAX_NAME_BYTES}")


def _first_existing_ancestor(path: Path, option: str) -> Path:
    """The nearest existing ancestor of ``path``; refused unless it is a directory."""
    for anc in path.absolute().parents:
        try:
            st = os.stat(anc)
        except FileNotFoundError:
            continue
        except NotADirectoryError:
            continue  # a file further up: named when the loop reaches it
        except OSError as exc:
            raise _refuse(option, path, f"{anc}: {exc.strerror}") from None
        if not stat.S_ISDIR(st.st_mode):
            raise _refuse(option, path, f"{anc} is {what_is_there(st.st_mode)}, not a directory")
        return anc
    return Path(path.anchor or os.sep)


def _lookup(p: Path, option: str):
    """``os.stat(p)``, or None when nothing is there (then its nearest existing ancestor must be a directory)."""
    try:
        return os.stat(p)
    except (FileNotFoundError, NotADirectoryError):
        _first_existing_ancestor(p, option)
        return None
    except OSError as exc:
        raise _refuse(option, p, f"cannot look at it ({exc.strerror})") from None


def check_output(path, option: str = "output") -> Path:
    """``path`` as a Path if a file may be written there; ConfigError naming ``option`` and what is there otherwise.

    Nothing is created. A symbolic link is judged by what it points to.
    """
    p = Path(path)
    _check_names(p, option)
    st = _lookup(p, option)
    if st is None:
        return p
    if not stat.S_ISREG(st.st_mode):
        raise _refuse(option, p, f"is {what_is_there(st.st_mode)}; only a regular file is replaced")
    return p


def check_outputs(args, **options) -> None:
    """:func:`check_output` for each ``attribute="--option"`` of ``args`` that is set (before anything is computed)."""
    for attr, option in options.items():
        value = getattr(args, attr, None)
        if value is not None:
            check_output(value, option)


def _new_file_mode() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


@contextmanager
def output_file(path, option: str = "output", *, binary: bool = False, newline: str | None = None):
    """A file handle whose content replaces ``path`` when the block ends without an error.

    Refused (ConfigError naming ``option``) as :func:`check_output` refuses;
    an error while writing (a full disk, no permission) is a ConfigError too,
    and leaves the target as it was.
    """
    p = check_output(path, option)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name[:60]}.", suffix=".tmp", dir=p.parent)
    except OSError as exc:
        raise _refuse(option, p, f"cannot write there ({exc.strerror})") from None
    try:
        try:
            if binary:
                fh = os.fdopen(fd, "wb")
            else:
                fh = os.fdopen(fd, "w", encoding="utf-8", newline=newline)
        except BaseException:
            os.close(fd)
            raise
        try:
            with fh:
                yield fh
        except OSError as exc:
            raise _refuse(option, p, f"cannot write ({exc.strerror})") from None
        check_output(p, option)  # still nothing but a regular file there
        try:
            mode = os.stat(p).st_mode & 0o7777 if p.exists() else _new_file_mode()
            os.chmod(tmp, mode)
            os.replace(tmp, p)
        except OSError as exc:
            raise _refuse(option, p, f"cannot write ({exc.strerror})") from None
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


def write_output(path, text: str, option: str = "output") -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`output_file`; the path written."""
    with output_file(path, option) as fh:
        fh.write(text)
    return Path(path)


def output_dir(path, option: str = "--out", *, create: bool = True) -> Path:
    """``path`` as an existing directory (created with its parents if missing, unless ``create`` is false: a check
    before anything is computed); ConfigError naming what is there."""
    p = Path(path)
    _check_names(p, option, file=False)
    st = _lookup(p, option)
    if st is None:
        if create:
            try:
                p.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise _refuse(option, p, f"cannot create the directory ({exc.strerror})") from None
        return p
    if not stat.S_ISDIR(st.st_mode):
        raise _refuse(option, p, f"is {what_is_there(st.st_mode)}, not a directory")
    return p
