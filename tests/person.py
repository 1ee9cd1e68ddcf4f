"""A person at the terminal, for tests that drive armed runs against the fakes.

An armed run refuses scripted answers (``--yes``, a callable, an answer
file): only an operator that is a person answers its confirmations. These
tests stand in for that person by typing into the terminal the station
reads (:class:`~station.runner.InteractiveOperator`), so every prompt is
really asked and its text can be checked.
"""

from __future__ import annotations

import io

from station.runner import InteractiveOperator

#: more answers than any procedure asks
TYPED_YES = "y\n" * 50


def person_typing_yes() -> InteractiveOperator:
    """An operator at the terminal who answers yes to each prompt; what was asked is in ``.stdout``."""
    return InteractiveOperator(stdin=io.StringIO(TYPED_YES), stdout=io.StringIO())
