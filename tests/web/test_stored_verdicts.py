"""The page's verdict of runs stored before the one verdict vocabulary: every old form still reads.

A run stored by older code may lack the ``verdict`` result; its report step's
verdict (the shown text, or "NO LIMITS"), its rows' ``passed`` or its status
then say it, in the page's lower-case word.
"""

import pytest

from app.web.state import run_outcome, verdict
from station.store import RunStore
from station.verdict import Outcome


def _run(store, run_id, *, passed, status="done", report_verdict=None, stored_verdict=None):
    store.create_run(run_id, "iso9283", model="industrial-3100", serial="SN-1", overhaul_state="after",
                     config={}, params={})
    store.put_characteristics(run_id, [{"pose": f"P{i + 1}", "name": "RP_mm", "value": 0.1, "unit": "mm",
                                        "limit": None if p is None else 0.5, "passed": p}
                                       for i, p in enumerate(passed)])
    if report_verdict is not None:
        attempt = store.step_started(run_id, 0, "report")
        store.step_ended(run_id, 0, attempt, "done", {"report": "gone.html", "verdict": report_verdict})
    if stored_verdict is not None:
        store.put_result(run_id, "verdict", {"verdict": stored_verdict, "reasons": [], "conformant": None,
                                             "exit_code": 0})
    store.set_run_status(run_id, status)


@pytest.fixture
def store(tmp_path):
    with RunStore(tmp_path / "old.sqlite") as s:
        yield s


def test_an_old_runs_verdict_reads_from_whatever_it_stored(store, rng):
    for k in range(6):
        passed = [bool(x) for x in rng.random(int(rng.integers(1, 6))) < 0.7]
        _run(store, f"rows-{k}", passed=passed)  # no verdict, no report: its rows
        want = Outcome.PASS if all(passed) else Outcome.FAIL
        assert run_outcome(store, f"rows-{k}") is want and verdict(store, f"rows-{k}") == want.word
    for o in Outcome:
        # the report step's verdict wins over the rows (it knew the cycles and conformance), in any case
        text = str(rng.choice([str(o), o.word, o.name]))
        _run(store, f"rep-{o.name}", passed=[True], report_verdict=text)
        assert verdict(store, f"rep-{o.name}") == o.word
        # and the stored verdict over both
        _run(store, f"st-{o.name}", passed=[False], report_verdict="PASS", stored_verdict=str(o))
        assert run_outcome(store, f"st-{o.name}") is o
    # a report without a judged row said "NO LIMITS": nothing judged, no verdict
    _run(store, "none", passed=[None, None], report_verdict="NO LIMITS")
    assert verdict(store, "none") is None
    # a run that did not finish, without a stored verdict: aborted
    _run(store, "cut", passed=[True], status=str(rng.choice(["aborted", "failed"])))
    assert verdict(store, "cut") == "aborted"
