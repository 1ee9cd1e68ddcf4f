"""The order the suite's tests are handed to its xdist workers: the long ones first.

pytest-xdist's work stealing gives each worker a contiguous share of the
collection and lets a worker out of tests take the tail of another's queue.
Collected in file order, the long end-to-end files (``tests/ur``,
``tests/web``: real-time clients paced in wall time, a browser) came last,
and the run ended with one long test at a time (a fresh-clone run here:
the last 7 % of the tests took a third of the wall time, the two cores
1.5 busy on average). Sorted longest first, the long tests of one worker's
share run beside the short tests of the other's, and the run ends on short
tests that balance (longest processing time first).

The weights are the mean seconds per test of each file in a fresh-clone run
on this 2-core machine (``--junitxml``, 2026-11-27); a file not listed
weighs 0 and keeps its place among the short ones. A stale weight costs
only speed, never a result: the order of tests does not change what they
assert (every test draws from its own seed, ``tests/seeding.py``).
"""

from __future__ import annotations

#: mean wall seconds per test of the files whose tests take over 1.5 s each
FILE_WEIGHT_S = {
    "tests/station/test_newcomer_path.py": 23.4,
    "tests/web/test_every_procedure.py": 16.8,
    "tests/station/test_resume_anywhere.py": 16.6,
    "tests/station/test_signal_resume.py": 16.1,
    "tests/ur/test_arm_calibration.py": 15.6,
    "tests/ur/test_procedure_faults.py": 14.5,
    "tests/station/test_iso_resume.py": 12.7,
    "tests/web/test_browser.py": 11.7,
    "tests/web/test_operator_clicks.py": 7.7,
    "tests/ur/test_iso_procedure.py": 7.6,
    "acceptance/test_verdicts.py": 6.9,
    "tests/station/test_progress_terminal.py": 6.8,
    "acceptance/test_after_overhaul.py": 6.8,
    "tests/web/test_http.py": 6.7,
    "tests/station/test_run_verdict.py": 5.8,
    "tests/station/test_iso_uncertainty_run.py": 5.2,
    "tests/station/test_trailer_run.py": 4.8,
    "tests/ur/test_web.py": 4.5,
    "tests/calibration/test_real_pose_sets.py": 2.5,
    "tests/station/test_fake_conditions.py": 2.3,
    "tests/ur/test_cli.py": 2.0,
    "tests/web/test_armed.py": 1.9,
    "tests/station/test_iso_procedure.py": 1.8,
    "tests/store/test_reanalysis.py": 1.8,
    "tests/station/test_arm_calibration_procedure.py": 1.8,
}


def weight_s(nodeid: str) -> float:
    """The expected seconds of the test ``nodeid`` (its file's weight)."""
    return FILE_WEIGHT_S.get(nodeid.split("::", 1)[0], 0.0)


def pytest_collection_modifyitems(session, config, items):
    # stable: within a weight (and among the unlisted files) the collection's own order stays
    items.sort(key=lambda item: -weight_s(item.nodeid))
