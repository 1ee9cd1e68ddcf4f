"""The one verdict vocabulary: outcomes, their order, their text."""

import itertools

import pytest

from station.verdict import SEVERITY, Outcome, Verdict, combine, outcome_of


def test_the_worst_outcome_wins_whatever_the_order():
    for k in range(1, 5):
        for combo in itertools.product(list(Outcome), repeat=k):
            worst = min(combo, key=SEVERITY.index)
            assert combine(combo) is worst
            assert combine(reversed(combo)) is worst


def test_nothing_to_judge_is_a_pass_and_one_undecided_limit_is_not():
    assert combine([]) is Outcome.PASS
    assert combine([Outcome.PASS] * 20 + [Outcome.NOT_DECIDED]) is Outcome.NOT_DECIDED
    assert combine([Outcome.NOT_DECIDED, Outcome.FAIL]) is Outcome.FAIL
    assert combine([Outcome.FAIL, Outcome.ABORTED]) is Outcome.ABORTED


def test_stored_passed_maps_to_outcomes():
    assert outcome_of(True) is Outcome.PASS
    assert outcome_of(False) is Outcome.FAIL
    assert outcome_of(None) is Outcome.NOT_DECIDED


def test_text_round_trips_and_rejects_others():
    for o in Outcome:
        assert Outcome.parse(str(o)) is o
        assert Outcome.parse(o.name.lower()) is o
    assert str(Outcome.NOT_DECIDED) == "NOT DECIDED"
    with pytest.raises(ValueError, match="not an outcome"):
        Outcome.parse("MARGINAL")


def test_a_verdict_says_its_reasons():
    v = Verdict(Outcome.NOT_DECIDED, ("P1 n_cycles 18 of 30",))
    assert str(v) == "NOT DECIDED (P1 n_cycles 18 of 30)"
    assert v.to_dict() == {"verdict": "NOT DECIDED", "reasons": ["P1 n_cycles 18 of 30"]}
