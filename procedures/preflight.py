"""Checks that every procedure's preflight uses, before anything moves.

Each function returns the problems it finds as sentences (an empty list when
there are none). A procedure's own ``preflight_problems`` (named in its
registry entry) combines them with the checks of its plan;
:func:`procedures.execute.preflight` refuses the run with all of them at once.
Nothing here opens a device: the facts come from the drivers' own capability
checks (``rate_problem`` of a tracker driver class) and from the file system.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from procedures.devices import DeviceSet
from station.errors import StationError


def report_dir_problems(report_dir) -> list[str]:
    """Why reports could not be written to ``report_dir`` (created when the run writes its report).

    Tried for real, not judged by permission bits (root passes every
    ``os.access`` check, and ``/proc`` or a read-only mount refuses anyway):
    the missing folders are made, a probe file is written and removed, and
    the folders made are removed again.
    """
    d = Path(report_dir)
    probe = d
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        return [f"report_dir {d}: {probe} is a file, not a folder"]
    if not os.access(probe, os.W_OK | os.X_OK):
        return [f"report_dir {d}: {probe} is not writable"]
    made: list[Path] = []
    try:
        for part in reversed([d, *d.parents]):
            if not part.exists():
                part.mkdir()
                made.append(part)
        fd, name = tempfile.mkstemp(prefix=".preflight-", dir=d)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        return [f"report_dir {d}: cannot write a file there ({exc.strerror or exc})"]
    finally:
        for part in reversed(made):
            try:
                part.rmdir()
            except OSError:
                pass
    return []


def tracker_rate_problems(devices: DeviceSet, rate_hz: float, *, field: str = "tracker_rate_hz") -> list[str]:
    """Why the tracker of ``devices`` cannot stream at ``rate_hz`` (no tracker: nothing to check)."""
    if "tracker" in devices.drivers:
        check = getattr(devices.drivers["tracker"], "rate_problem", None)
    elif "tracker" in devices.urls:
        from drivers.tracker_url import tracker_class

        try:
            check = tracker_class(devices.urls["tracker"]).rate_problem
        except StationError as exc:
            return [f"tracker URL: {exc}"]
    else:
        return []
    problem = check(rate_hz) if check is not None else None
    return [f"{field}: {problem}"] if problem else []

