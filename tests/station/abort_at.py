"""Abort a run the moment a named step starts (the runner's progress is the event; no polling)."""

from __future__ import annotations

from station.runner import ProgressLine, RunControl


class AbortAtStep(ProgressLine):
    """A progress line that asks ``control`` to abort when step ``name`` reports progress."""

    def __init__(self, control: RunControl, name: str) -> None:
        super().__init__(None)
        self.control, self.name = control, name

    def update(self, idx: int, step, detail: str = "") -> None:
        super().update(idx, step, detail)
        if step.name == self.name:
            self.control.abort()
