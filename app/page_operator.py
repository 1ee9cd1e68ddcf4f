"""The operator whose questions wait for an answer from the operator's page.

It lives beside the front door (not in :mod:`app.web`) because the safety gate
(:func:`app.assemble.require_person`) names it: the page's button, behind the
token and CSRF check, is one of the two ways a person answers an armed run.
"""

from __future__ import annotations

import threading

from station.errors import RunStateError
from station.runner import RunAborted, RunControl

#: how often a waiting prompt looks at the abort request, s
_POLL_S = 0.1


class WebOperator:
    """Operator whose questions wait for an answer from a page (any page watching the run).

    ``confirm`` blocks the run's thread until :meth:`answer` is called with the
    pending prompt's id; an abort request while waiting raises
    :class:`~station.runner.RunAborted` (the run stops, resumable). A person
    answers on the page (its button, behind the token and CSRF check): an
    armed run takes this class as a person (:func:`app.assemble.require_person`).
    """

    def __init__(self, control: RunControl) -> None:
        self._control = control
        self._cond = threading.Condition()
        self._prompt: dict | None = None
        self._answer: bool | None = None
        self._seq = 0
        #: (message, answer) of every prompt answered, in order
        self.asked: list[tuple[str, bool]] = []

    @property
    def prompt(self) -> dict | None:
        """The pending question ``{"id", "message"}``, or None."""
        with self._cond:
            return dict(self._prompt) if self._prompt else None

    def confirm(self, message: str) -> bool:
        with self._cond:
            self._seq += 1
            self._prompt = {"id": self._seq, "message": message}
            self._answer = None
            try:
                while self._answer is None:
                    if self._control.abort_requested:
                        raise RunAborted("run aborted while waiting for the operator (resumable)")
                    self._cond.wait(_POLL_S)
                answer = self._answer
            finally:
                self._prompt = None
        self.asked.append((message, answer))
        return answer

    def answer(self, prompt_id: int, yes: bool) -> None:
        """Answer the pending prompt; RunStateError if ``prompt_id`` is not the one waiting."""
        with self._cond:
            if self._prompt is None or self._prompt["id"] != prompt_id:
                raise RunStateError(f"prompt {prompt_id} is not waiting for an answer (answered already?)")
            self._answer = bool(yes)
            self._prompt = None  # answered: no page offers it again
            self._cond.notify_all()
