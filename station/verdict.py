"""Verdicts: the outcome of one characteristic, one measurement, one run.

This module owns the verdict's words and its exit codes; everything else
holds an :class:`Outcome` and asks it for its text. Four outcomes, the same
everywhere (a stored characteristic, a plant's own measurement, a whole run,
the console, ``--json``, the report, the page, the fleet):

* ``PASS``: every limit asked was decided and kept (or none was asked);
* ``FAIL``: a limit was decided and not kept;
* ``NOT_DECIDED`` (shown ``NOT DECIDED``): a limit could not be decided: the
  characteristic was not computed, the run measured fewer cycles than asked,
  conformance was required and not met, or a decision rule that allows for
  measurement uncertainty (a guard band) can say neither pass nor fail;
* ``ABORTED``: the run did not finish (aborted, or stopped by a fault):
  nothing is decided, the run can be resumed.

Text: ``str(outcome)`` is the shown verdict ("NOT DECIDED": console, report
banner, the run's JSON); :attr:`Outcome.word` the lower-case word of a single
figure's stored outcome and of the page ("not decided"); :attr:`Outcome.cell`
a table cell that shouts only failures ("pass", "FAIL", "not decided").
:meth:`Outcome.parse` reads every one of them back, and the words stores
written before this module held ("pass", "fail", "not decided").

In the store a characteristic row keeps its outcome as ``passed`` (True,
False, None) beside its ``limit``: :func:`outcome_of` / :attr:`Outcome.passed`
convert, :func:`row_outcome` reads a stored row (a row without a limit is not
judged).

:func:`combine` gives the outcome of many (a run from its characteristics):
the worst one wins, in the order ABORTED > FAIL > NOT DECIDED > PASS.
:func:`exit_code` is the commands' one table of exit codes (``station
analyze``, ``station run``, ``station demo``, the acceptance API).

This module is the core's and small on purpose: other parts (decision
rules, measurements, the front doors) import it and nothing else here.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

#: a passing figure within this fraction of its limit is marginal (the plant's guard band, the config's
#: ``station.marginal_fraction``; :func:`station.analysis.decision.marginal_reason` flags it)
MARGINAL_FRACTION = 0.10


class Outcome(str, enum.Enum):
    """The outcome of a characteristic, a measurement or a run; its value is the text shown."""

    PASS = "PASS"
    FAIL = "FAIL"
    NOT_DECIDED = "NOT DECIDED"
    ABORTED = "ABORTED"

    def __str__(self) -> str:  # "NOT DECIDED", not "Outcome.NOT_DECIDED"
        return self.value

    @property
    def word(self) -> str:
        """Lower case: a figure's stored ``outcome``, the page's verdict ("pass", "fail", "not decided", "aborted")."""
        return self.value.lower()

    @property
    def cell(self) -> str:
        """A table cell: failures in capitals, the rest lower case ("pass", "FAIL", "not decided")."""
        return self.value if self is Outcome.FAIL else self.word

    @property
    def passed(self) -> bool | None:
        """As the store's ``passed``: True PASS, False FAIL, None NOT DECIDED; ValueError for ABORTED (no row's)."""
        if self is Outcome.ABORTED:
            raise ValueError("an aborted run has no passed/failed value")
        return {Outcome.PASS: True, Outcome.FAIL: False}.get(self)

    @classmethod
    def parse(cls, text: str) -> "Outcome":
        """An outcome from any of its texts, its name, or an old store's word ("not decided"); ValueError otherwise."""
        if isinstance(text, cls):
            return text
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


def row_outcome(row: Mapping) -> Outcome | None:
    """A stored row's outcome: its ``outcome`` where it has one (any text :meth:`Outcome.parse` reads), else
    from ``passed`` and ``limit``; None when it is not judged (no limit, no outcome)."""
    if row.get("outcome"):
        return Outcome.parse(row["outcome"])
    if row.get("limit") is None and row.get("passed") is None:
        return None
    return outcome_of(row.get("passed"))


# The commands' exit codes (``station analyze``, ``station run``, ``station demo``).
EXIT_PASS = 0
EXIT_FAIL = 1
#: bad input (a malformed file, an unknown option value): nothing ran (the command's own, no outcome's)
EXIT_BAD_INPUT = 2
EXIT_UNDECIDED = 3
#: NOT DECIDED only because ISO 9283 conformance was required (``--require-iso``) and is not met
EXIT_NOT_CONFORMANT = 4
EXIT_ABORTED = 5

_EXIT = {Outcome.PASS: EXIT_PASS, Outcome.FAIL: EXIT_FAIL, Outcome.NOT_DECIDED: EXIT_UNDECIDED,
         Outcome.ABORTED: EXIT_ABORTED}


def exit_code(outcome: Outcome, conformance_only: bool = False) -> int:
    """The command's exit code of an outcome: 0 PASS, 1 FAIL, 3 NOT DECIDED (4 when only because conformance
    was required and not met), 5 ABORTED; 2 (bad input) is no outcome's."""
    if outcome is Outcome.NOT_DECIDED and conformance_only:
        return EXIT_NOT_CONFORMANT
    return _EXIT[Outcome(outcome)]


@dataclass(frozen=True)
class Verdict:
    """An outcome with the reasons for it (one sentence each; empty for a plain PASS).

    ``conformance_only``: NOT DECIDED only because conformance was required and is not met (its exit code 4).
    """

    outcome: Outcome
    reasons: tuple[str, ...] = ()
    conformance_only: bool = False

    def __str__(self) -> str:
        return str(self.outcome) + (f" ({'; '.join(self.reasons)})" if self.reasons else "")

    @property
    def exit_code(self) -> int:
        return exit_code(self.outcome, self.conformance_only)

    def to_dict(self) -> dict:
        return {"verdict": self.outcome.value, "reasons": list(self.reasons)}


__all__ = ["Outcome", "Verdict", "combine", "outcome_of", "row_outcome", "exit_code", "SEVERITY",
           "EXIT_PASS", "EXIT_FAIL", "EXIT_BAD_INPUT", "EXIT_UNDECIDED", "EXIT_NOT_CONFORMANT", "EXIT_ABORTED"]
