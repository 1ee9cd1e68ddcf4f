"""Abort a run the moment a named step starts (the runner's progress is the event; no polling)."""

from __future__ import annotations

from app.terminal import ProgressLine
from station.runner import RunControl


class AbortAtStep(ProgressLine):
    """A progress line that asks ``control`` to abort when step ``name`` reports progress (``detail``, when
    given: that progress of the step, e.g. ``"pose C7"``)."""

    def __init__(self, control: RunControl, name: str, detail: str | None = None) -> None:
        super().__init__(None)
        self.control, self.name, self.detail = control, name, detail

    def update(self, idx: int, step, detail: str = "") -> None:
        super().update(idx, step, detail)
        if step.name == self.name and (self.detail is None or detail == self.detail):
            self.control.abort()
