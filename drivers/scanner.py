"""3D scanner over a hot folder: the station asks for a scan with a trigger file, the scanner answers with a PLY.

Structured-light scanners' own software commonly offers a *hot folder*: it
watches a folder for a request, scans, and exports the cloud into the same
folder. The device URL names the folder: ``ply:///data/scans``.

The exchange, for a capture named ``NAME`` (letters, digits, ``._-``)::

    station                                   scanner software
    -------                                   ----------------
    writes NAME.trigger.tmp, renames it
      to NAME.trigger (atomic: the scanner
      never sees half a request)        --->  sees NAME.trigger, scans
                                              writes the cloud to a temporary
                                              name (NAME.ply.part), renames it
                                              to NAME.ply, removes NAME.trigger
    sees NAME.ply, reads it             <---  (or writes NAME.error: one line,
                                              why it could not scan)

* The cloud is in the scanner's frame, mm (any PLY format
  :func:`drivers.ply.read_ply` reads). The station leaves ``NAME.ply`` in the
  folder: it is the raw measurement.
* A name whose ``NAME.ply`` or ``NAME.error`` is already there is refused
  before the trigger is written (a stale answer would be taken for the new
  scan).
* No answer within ``timeout_s`` (monotonic clock): the trigger is taken
  back (removed) and :class:`~station.errors.DeviceTimeout` is raised.
* ``NAME.error``: :class:`~station.errors.DeviceFault` with its text.
* A malformed PLY: :class:`~station.errors.DataError` naming the file and
  what is wrong (from :mod:`drivers.ply`).

Errors: ``StationError`` > ``ConfigError`` (bad URL, missing folder, bad
name), ``DataError`` (bad file), ``DeviceError`` > ``DeviceFault`` (the
scanner reported an error, a stale answer), ``DeviceTimeout`` (no answer).
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.ply import read_ply
from drivers.transport import ListeningDeadline
from station.device_urls import parse_device_url
from station.errors import ConfigError, DataError, DeviceError, DeviceFault, DeviceTimeout

__all__ = ["ScannerDriver", "ScannerInfo", "TRIGGER_SUFFIX", "ANSWER_SUFFIX", "ERROR_SUFFIX"]

TRIGGER_SUFFIX = ".trigger"
ANSWER_SUFFIX = ".ply"
ERROR_SUFFIX = ".error"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


@dataclass(frozen=True)
class ScannerInfo:
    """What :meth:`ScannerDriver.connect` found."""

    name: str
    folder: str


#: s: what the driver's look at the folder between two polls may take when this process runs
LOOK_S = 0.05


class ScannerDriver:
    """A 3D scanner behind a hot folder (see the module docstring).

    Parameters
    ----------
    folder : str or os.PathLike
        The exchange folder.
    timeout_s : float
        Default time a capture may take (s), counted only while this process runs
        (:class:`drivers.transport.ListeningDeadline`).
    poll_s : float
        How often the folder is looked at while waiting (s).
    """

    def __init__(self, folder, *, timeout_s: float = 30.0, poll_s: float = 0.01) -> None:
        for name, v in (("timeout_s", timeout_s), ("poll_s", poll_s)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 < float(v) < 1e5):
                raise ConfigError(f"scanner: `{name}` must be a number of seconds > 0, got {v!r}")
        self.folder = Path(folder)
        self.timeout_s = float(timeout_s)
        self.poll_s = float(poll_s)
        self.connected = False

    @classmethod
    def from_url(cls, url, *, timeout_s: float | None = None, **options) -> "ScannerDriver":
        """``ply:///path/to/folder``; ``timeout_s``: how long a scan may take."""
        u = parse_device_url(url, scheme="ply")
        if timeout_s is not None:
            options["timeout_s"] = timeout_s
        if not u.path:
            raise ConfigError(f"device URL {u.raw!r}: a ply URL needs the folder path, e.g. ply:///data/scans")
        return cls(u.path, **options)

    def connect(self) -> ScannerInfo:
        """Check the folder: it exists, is a folder, and the station may write and read in it."""
        if not self.folder.exists():
            raise ConfigError(f"scanner folder {self.folder} does not exist")
        if not self.folder.is_dir():
            raise ConfigError(f"scanner folder {self.folder} is not a folder")
        if not os.access(self.folder, os.R_OK | os.W_OK | os.X_OK):
            raise ConfigError(f"scanner folder {self.folder}: the station may not read and write in it")
        self.connected = True
        return ScannerInfo(name=f"hot folder {self.folder}", folder=str(self.folder))

    def close(self) -> None:
        self.connected = False

    def paths(self, name: str) -> tuple[Path, Path, Path]:
        """(trigger, answer, error) files of capture ``name``."""
        if not isinstance(name, str) or not _NAME.match(name):
            raise ConfigError(f"scanner: capture name {name!r} must be 1-128 letters, digits or ._- "
                              "(no path separators), starting with a letter or digit")
        return (self.folder / (name + TRIGGER_SUFFIX), self.folder / (name + ANSWER_SUFFIX),
                self.folder / (name + ERROR_SUFFIX))

    def capture(self, name: str, timeout_s: float | None = None) -> np.ndarray:
        """Ask for one scan and wait for it; the cloud (M, 3) in the scanner frame, mm.

        Raises
        ------
        ConfigError
            Bad name, not connected.
        DeviceFault
            The scanner answered with ``NAME.error``, or an answer for ``NAME``
            was there before the request.
        DeviceTimeout
            No answer within ``timeout_s``.
        DataError
            The answer is not a readable PLY.
        """
        if not self.connected:
            raise ConfigError("scanner: connect() before capture()")
        trigger, answer, error = self.paths(name)
        wait_s = self.timeout_s if timeout_s is None else float(timeout_s)
        if not (wait_s > 0):
            raise ConfigError(f"scanner: `timeout_s` must be > 0, got {timeout_s!r}")
        for p in (answer, error):
            if p.exists():
                raise DeviceFault(f"scanner: {p} is already there before capture {name!r} was asked for "
                                  "(a stale answer; use a new name or move it away)")
        tmp = trigger.with_name(trigger.name + ".tmp")
        try:
            tmp.write_text(f"capture {name}\n", encoding="ascii")
            os.replace(tmp, trigger)
        except OSError as exc:
            raise DeviceError(f"scanner: cannot write the trigger {trigger}: {exc}") from exc
        # the scanner's silence, counted only while this process looks: a gap longer than a poll (and the
        # looks' own time) is a host that did not run, and counts that much only
        deadline = ListeningDeadline(wait_s, self.poll_s + LOOK_S)
        while True:
            if answer.exists():
                return self._read(answer)
            if error.exists():
                self._take_back(trigger)
                try:
                    why = error.read_text(encoding="utf-8", errors="replace").strip()[:500]
                except OSError as exc:
                    why = f"(unreadable: {exc})"
                raise DeviceFault(f"scanner could not scan {name!r}: {why or '(no reason given)'}")
            if deadline.expired():
                self._take_back(trigger)
                raise DeviceTimeout(f"scanner: no {answer.name} in {self.folder} within {wait_s:g} s "
                                    "(is the scanner software watching the folder?)")
            time.sleep(self.poll_s)

    @staticmethod
    def _take_back(trigger: Path) -> None:
        try:
            trigger.unlink()
        except FileNotFoundError:
            pass

    @staticmethod
    def _read(answer: Path) -> np.ndarray:
        try:
            return read_ply(answer)
        except DataError:
            raise
        except OSError as exc:
            raise DataError(f"{answer}: cannot be read: {exc}") from exc
