"""What a person sees and answers at the terminal during a run: the progress bar and the prompts.

:class:`ProgressLine` shows a run's progress (:class:`station.runner.Progress`)
on a terminal or as plain lines on a pipe; :class:`InteractiveOperator` asks
the run's questions there and steps the bar aside while it asks. The
terminal operator is the one operator of an armed run at a terminal
(:func:`app.assemble.require_person`).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from station.errors import SafetyError
from station.runner import Step
from station.shown import shown


class InteractiveOperator:
    """Asks on the terminal; anything but y/yes is a no.

    A person answers only where both streams are a terminal: a pipe or a file
    on either (``yes | station run --arm``) answers nothing of an armed run.
    :meth:`require_terminal` checks that once (before anything is recorded)
    and makes every later :meth:`confirm` check it again, so a stream swapped
    for a pipe afterwards is refused too.
    """

    def __init__(self, stdin: TextIO = sys.stdin, stdout: TextIO = sys.stderr) -> None:
        self.stdin, self.stdout = stdin, stdout
        self._terminal_required = False

    def not_a_terminal(self) -> list[str]:
        """The names of the streams that are not a terminal (empty where a person can answer)."""
        return [name for name, stream in (("standard input", self.stdin), ("the prompt's output", self.stdout))
                if not _is_terminal(stream)]

    def require_terminal(self) -> None:
        """:class:`~station.errors.SafetyError` unless both streams are a terminal; from now on each
        prompt checks it again."""
        missing = self.not_a_terminal()
        if missing:
            raise SafetyError(f"an armed run needs a person to answer its confirmations at a terminal: "
                              f"{' and '.join(missing)} {'is' if len(missing) == 1 else 'are'} not a terminal "
                              "(a pipe or a file cannot confirm real motion); nothing moved")
        self._terminal_required = True

    def confirm(self, message: str) -> bool:
        if self._terminal_required:
            self.require_terminal()
        with _PausedDisplay():  # the progress bar steps aside: the prompt has a line of its own
            self.stdout.write(f"? {message} [y/N] ")
            self.stdout.flush()
            line = self.stdin.readline()
        return line.strip().lower() in ("y", "yes")


def _is_terminal(stream) -> bool:
    """True where ``stream`` is an open terminal (a tty); a closed or file-less stream is not."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


#: the progress display on the terminal now (one run at a time per process), paused while a person is asked
_ACTIVE_DISPLAY: "ProgressLine | None" = None


class _PausedDisplay:
    """``with _PausedDisplay():`` the progress bar is off the terminal, so a prompt gets a line of its own."""

    def __enter__(self):
        self.display = _ACTIVE_DISPLAY
        if self.display is not None:
            self.display.pause()
        return self

    def __exit__(self, *exc) -> None:
        if self.display is not None:
            self.display.unpause()


class ProgressLine:
    """The run's progress: on a terminal a bar drawn by ``rich`` (it knows the terminal's width, redraws in
    place, steps aside for prompts and log lines); on a pipe or file plain lines, at most one a second for
    the details within a step::

        [#####...........] 12/168 run cycle 3 P4  elapsed 0:41  remaining ~1:10
    """

    def __init__(self, stream: TextIO | None = sys.stderr, total: int = 0) -> None:
        self.stream = stream
        self.total = total
        self.t0 = time.monotonic()
        self.done = 0
        self._tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self._last = 0.0
        self._bar = None  # rich.progress.Progress while shown
        self._task = None
        self._paused = False

    def _fmt(self, seconds: float) -> str:
        s = int(max(0, seconds))
        return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"

    def _times(self) -> str:
        elapsed = time.monotonic() - self.t0
        frac = self.done / self.total if self.total else 0.0
        remaining = f"~{self._fmt(elapsed * (1 - frac) / frac)}" if frac > 0 else "?"
        return f"elapsed {self._fmt(elapsed)}  remaining {remaining}"

    def _start_bar(self) -> None:
        global _ACTIVE_DISPLAY
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn
        from rich.table import Column

        # the bar's own escapes go to the terminal itself (the CLI screens what commands print, see app.cli);
        # the names in it are screened here
        console = Console(file=getattr(self.stream, "unscreened", self.stream), force_terminal=True, highlight=False, soft_wrap=False)
        self._bar = Progress(
            BarColumn(bar_width=16),
            TextColumn("{task.fields[count]}"),
            TextColumn("{task.description}", table_column=Column(ratio=1, no_wrap=True, overflow="ellipsis")),
            TextColumn("{task.fields[times]}", table_column=Column(no_wrap=True)),
            console=console, auto_refresh=False, transient=True, expand=True)
        self._task = self._bar.add_task("", total=max(self.total, 1), times="", count="")
        self._bar.start()
        _ACTIVE_DISPLAY = self

    def update(self, idx: int, step: Step, detail: str = "") -> None:
        if self.stream is None:
            return
        label = " ".join(x for x in (step.name, step.label, detail) if x)
        if not self._tty:
            now = time.monotonic()
            if now - self._last < 1.0 and detail:
                return
            self._last = now
            frac = self.done / self.total if self.total else 0.0
            bar = "#" * int(24 * frac) + "." * (24 - int(24 * frac))
            self.stream.write(f"[{bar}] {idx + 1:>3}/{self.total} {label}  {self._times()}\n")
            self.stream.flush()
            return
        if self._bar is None:
            self._start_bar()
        now = time.monotonic()
        if detail and now - self._last < 0.1:
            return  # at most ten redraws a second for the details within a step
        self._last = now
        from rich.text import Text

        self._bar.update(self._task, completed=self.done, total=max(self.total, 1), description=Text(shown(label)),
                         times=self._times(), count=f"{idx + 1:>3}/{self.total}")
        if not self._paused:
            self._bar.refresh()

    def log(self, message: str) -> None:
        if self.stream is None:
            return
        if self._bar is not None and not self._paused:
            from rich.text import Text

            self._bar.console.print(Text(shown(message, lines=True)))  # above the bar, which is redrawn below it
            return
        self.stream.write(message + "\n")
        self.stream.flush()

    def pause(self) -> None:
        """Take the bar off the terminal (a prompt follows on a line of its own)."""
        if self._bar is not None and not self._paused:
            self._paused = True
            self._bar.stop()

    def unpause(self) -> None:
        if self._bar is not None and self._paused:
            self._paused = False
            self._bar.start()
            self._bar.refresh()

    def finish(self) -> None:
        global _ACTIVE_DISPLAY
        if self._bar is not None:
            if not self._paused:
                self._bar.stop()
            self._bar = None
            self._paused = False
        if _ACTIVE_DISPLAY is self:
            _ACTIVE_DISPLAY = None
