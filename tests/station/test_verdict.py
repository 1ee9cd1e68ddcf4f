"""The one verdict vocabulary: outcomes, their order, their text."""

import itertools
import json

import pytest

from station.verdict import SEVERITY, Outcome, Verdict, combine, exit_code, outcome_of, row_outcome


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


def test_every_outcome_has_one_exit_code_one_text_and_parses_back():
    """The one table: each outcome's exit code, its shown text, its word and its cell, each read back."""
    expected = {Outcome.PASS: (0, "PASS", "pass", "pass"), Outcome.FAIL: (1, "FAIL", "fail", "FAIL"),
                Outcome.NOT_DECIDED: (3, "NOT DECIDED", "not decided", "not decided"),
                Outcome.ABORTED: (5, "ABORTED", "aborted", "aborted")}
    assert set(expected) == set(Outcome)
    for o, (code, text, word, cell) in expected.items():
        assert exit_code(o) == code and Verdict(o).exit_code == code
        assert (str(o), f"{o}", o.value, o.word, o.cell) == (text, text, text, word, cell)
        for shown in (str(o), o.word, o.cell, o.name, o.name.lower(), f"  {o.word.title()} "):
            assert Outcome.parse(shown) is o
        assert Outcome.parse(o) is o
        assert Outcome(json.loads(json.dumps(o))) is o  # the JSON holds the shown text
    # 4 is NOT DECIDED only because conformance was required; it changes no other outcome's code
    assert exit_code(Outcome.NOT_DECIDED, conformance_only=True) == 4
    assert Verdict(Outcome.NOT_DECIDED, ("not conformant",), conformance_only=True).exit_code == 4
    assert [exit_code(o, conformance_only=True) for o in (Outcome.PASS, Outcome.FAIL, Outcome.ABORTED)] == [0, 1, 5]
    # 2 (bad input) is no outcome's
    assert 2 not in {exit_code(o, c) for o in Outcome for c in (False, True)}


def test_words_of_old_stores_parse_into_outcomes():
    """Stores written before the one vocabulary held a figure's outcome as "pass"/"fail"/"not decided"."""
    assert [Outcome.parse(w) for w in ("pass", "fail", "not decided")] == [
        Outcome.PASS, Outcome.FAIL, Outcome.NOT_DECIDED]
    assert row_outcome({"limit": 0.5, "passed": True}) is Outcome.PASS
    assert row_outcome({"limit": 0.5, "passed": False}) is Outcome.FAIL
    assert row_outcome({"limit": 0.5, "passed": None, "value": None}) is Outcome.NOT_DECIDED
    assert row_outcome({"limit": None, "passed": None}) is None  # no limit: not judged
    assert row_outcome({"limit": 0.5, "passed": None, "outcome": "not decided"}) is Outcome.NOT_DECIDED
    assert row_outcome({"limit": 0.5, "passed": True, "outcome": "PASS"}) is Outcome.PASS
    # the store keeps a row's outcome as passed: the round trip loses nothing (ABORTED is no row's)
    for o in (Outcome.PASS, Outcome.FAIL, Outcome.NOT_DECIDED):
        assert outcome_of(o.passed) is o and row_outcome({"limit": 1.0, "passed": o.passed}) is o
    with pytest.raises(ValueError, match="aborted"):
        Outcome.ABORTED.passed
