"""Fake 3D scanner software behind a hot folder (the exchange of :mod:`drivers.scanner`).

A thread watches the folder; for every ``NAME.trigger`` it renders a scan of
the corner jig at the simulated arm's current pose (:meth:`World.scan`, a
cloud in the scanner frame, mm), writes it to ``NAME.ply.part``, removes the
trigger and renames the cloud to ``NAME.ply``, as scanner software does.

Test-only controls (``sim_``): :meth:`sim_corrupt_next` answers the next
trigger with a broken PLY, :meth:`sim_ignore_next` leaves it unanswered,
:meth:`sim_error_next` answers with ``NAME.error``, :meth:`sim_hide_jig_next`
answers with the scan minus the jig's faces (background and flying pixels
only: the jig out of view). ``faults`` at start schedules the same by the
trigger's number in this session (1-based): ``{"hide_jig": [3], "corrupt": [5]}``.

The PLY writer here is the fake's own (fakes never import drivers): binary
little-endian, ``x y z`` as float.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import numpy as np

__all__ = ["ScannerFolderFake", "start_fake", "ply_bytes"]


def ply_bytes(points_mm: np.ndarray) -> bytes:
    """A binary little-endian PLY of ``points_mm`` (M, 3) as float32."""
    P = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    head = ("ply\nformat binary_little_endian 1.0\ncomment fake scanner, scanner frame, mm\n"
            f"element vertex {P.shape[0]}\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    return head.encode("ascii") + P.astype("<f4").tobytes()


class ScannerFolderFake:
    """The fake scanner's software watching ``folder`` (start with :func:`start_fake`)."""

    def __init__(self, world, folder, *, poll_s: float = 0.005, faults=None) -> None:
        self.world = world
        self.folder = Path(folder)
        self.poll_s = float(poll_s)
        self.answered: list[str] = []
        self._faults: list[str] = []
        self._scheduled: dict[int, str] = {}
        for kind, numbers in (faults or {}).items():
            if kind not in ("corrupt", "ignore", "error", "hide_jig"):
                raise ValueError(f"fake scanner: unknown fault {kind!r} (corrupt, ignore, error, hide_jig)")
            self._scheduled.update({int(n): kind for n in numbers})
        self._count = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="fake-scanner-folder")

    @property
    def url(self) -> str:
        return f"ply://{self.folder.resolve()}"

    def start(self) -> "ScannerFolderFake":
        if not self.folder.is_dir():
            raise FileNotFoundError(f"fake scanner: folder {self.folder} does not exist")
        self._thread.start()
        return self

    # ---- test-only controls
    def sim_corrupt_next(self) -> None:
        """The next trigger is answered with a PLY whose body is cut short."""
        with self._lock:
            self._faults.append("corrupt")

    def sim_ignore_next(self) -> None:
        """The next trigger is never answered (the scanner hangs)."""
        with self._lock:
            self._faults.append("ignore")

    def sim_hide_jig_next(self) -> None:
        """The next trigger is answered with a cloud in which the jig is not seen."""
        with self._lock:
            self._faults.append("hide_jig")

    def sim_error_next(self) -> None:
        """The next trigger is answered with ``NAME.error``."""
        with self._lock:
            self._faults.append("error")

    # ---- the watcher
    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                triggers = sorted(self.folder.glob("*.trigger"))
            except OSError:
                triggers = []
            for trig in triggers:
                self._answer(trig)
            self._stop.wait(self.poll_s)

    def _answer(self, trig: Path) -> None:
        name = trig.name[: -len(".trigger")]
        with self._lock:
            self._count += 1
            fault = self._faults.pop(0) if self._faults else self._scheduled.get(self._count)
        if fault == "ignore":
            trig.unlink(missing_ok=True)
            return
        if fault == "error":
            (self.folder / f"{name}.error").write_text("projector over temperature\n", encoding="utf-8")
            trig.unlink(missing_ok=True)
            return
        scan = self.world.scan()
        data = ply_bytes(scan.points_mm[scan.labels < 0] if fault == "hide_jig" else scan.points_mm)
        if fault == "corrupt":
            data = data[: len(data) - 7]  # truncated body: the vertex count no longer fits
        part = self.folder / f"{name}.ply.part"
        part.write_bytes(data)
        trig.unlink(missing_ok=True)
        os.replace(part, self.folder / f"{name}.ply")
        self.answered.append(name)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def __enter__(self) -> "ScannerFolderFake":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_fake(world, folder, *, faults=None) -> ScannerFolderFake:
    """Start the fake scanner software on ``folder`` (which must exist); ``faults`` as in the module docstring."""
    return ScannerFolderFake(world, folder, faults=faults).start()
