"""Verdicts: the outcome of one characteristic, one measurement, one run.

Four outcomes, the same everywhere (a stored characteristic, a plant's own
measurement, a whole run, the console, ``--json``, the report, the page):

* ``PASS``: every limit asked was decided and kept (or none was asked);
* ``FAIL``: a limit was decided and not kept;
* ``NOT_DECIDED`` (shown ``NOT DECIDED``): a limit could not be decided: the
  characteristic was not computed, the run measured fewer cycles than asked,
  conformance was required and not met, or a decision rule that allows for
  measurement uncertainty (a guard band) can say neither pass nor fail;
* ``ABORTED``: the run did not finish (aborted, or stopped by a fault):
  nothing is decided, the run can be resumed.

:func:`combine` gives the outcome of many (a run from its characteristics):
the worst one wins, in the order ABORTED > FAIL > NOT DECIDED > PASS.
:func:`outcome_of` reads the store's ``passed`` (True, False or None for a
characteristic with a limit; a row without a limit is not judged).

This module is the core's and small on purpose: other parts (decision
rules, measurements, the front doors) import it and nothing else here.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass


class Outcome(str, enum.Enum):
    """The outcome of a characteristic, a measurement or a run; its value is the text shown."""

    PASS = "PASS"
    FAIL = "FAIL"
    NOT_DECIDED = "NOT DECIDED"
    ABORTED = "ABORTED"

    def __str__(self) -> str:  # "NOT DECIDED", not "Outcome.NOT_DECIDED"
        return self.value

    @classmethod
    def parse(cls, text: str) -> "Outcome":
        """An outcome from its shown text or its name (``"NOT DECIDED"``, ``"not_decided"``); ValueError otherwise."""
        key = str(text).strip().upper().replace("_", " ")
        for o in cls:
            if o.value == key:
                return o
        raise ValueError(f"not an outcome: {text!r} (one of {', '.join(o.value for o in cls)})")


#: worst first: the first present in :func:`combine`'s input wins
SEVERITY = (Outcome.ABORTED, Outcome.FAIL, Outcome.NOT_DECIDED, Outcome.PASS)


def combine(outcomes: Iterable[Outcome]) -> Outcome:
    """The outcome of several: the worst present (ABORTED > FAIL > NOT DECIDED > PASS); none at all is PASS."""
    present = {Outcome(o) for o in outcomes}
    for o in SEVERITY:
        if o in present:
            return o
    return Outcome.PASS


def outcome_of(passed: bool | None) -> Outcome:
    """A judged characteristic's outcome from the store's ``passed``: True PASS, False FAIL, None NOT DECIDED."""
    if passed is None:
        return Outcome.NOT_DECIDED
    return Outcome.PASS if passed else Outcome.FAIL


@dataclass(frozen=True)
class Verdict:
    """An outcome with the reasons for it (one sentence each; empty for a plain PASS)."""

    outcome: Outcome
    reasons: tuple[str, ...] = ()

    def __str__(self) -> str:
        return str(self.outcome) + (f" ({'; '.join(self.reasons)})" if self.reasons else "")

    def to_dict(self) -> dict:
        return {"verdict": self.outcome.value, "reasons": list(self.reasons)}


__all__ = ["Outcome", "Verdict", "combine", "outcome_of", "SEVERITY"]
