"""Exit codes of ``station analyze iso9283`` that a pipeline can trust.

==== ==========================================================================
code meaning
==== ==========================================================================
0    every asked limit was decided and passed (or none was asked), and nothing
     below applies
1    a limit failed
2    bad input (a malformed file, an unknown option value): nothing analysed
3    not decided: a limit could not be decided (characteristic not computed),
     a pose has no attained pose, or a stop lies far from every commanded pose
     (a wrong frame, a pose missing from the poses file; via points are
     accepted with ``--allow-other-stops``)
4    ``--require-iso`` was given and the run is not ISO 9283 conformant
==== ==========================================================================

A failed limit wins over not decided, which wins over not conformant;
every reason that applies is printed on stderr. The codes and the outcomes
are :mod:`station.verdict`'s (the same table as ``station run``'s, whose 5
is a run that did not finish).
"""

from __future__ import annotations

from station.verdict import Outcome, Verdict


def _g(x) -> str:
    return "-" if x is None else f"{float(x):.4g}"


def decide(res, *, require_iso: bool, far_stops: list[str], allow_far: bool = False) -> Verdict:
    """The verdict (its ``exit_code`` the command's) and its reasons for a result of the stream or the stop-list
    analysis.

    ``far_stops``: one sentence per group of stops that no commanded pose
    explains (empty when there are none); ``allow_far``: they are expected
    (via points), listed but not a reason.
    """
    failed = [f"{v.characteristic} {v.subject} = {_g(v.value)} exceeds the limit {v.limit:g}"
              for v in res.verdicts if v.outcome is Outcome.FAIL]
    undecided = [f"{v.characteristic} {v.subject} not decided" + (f" ({v.note})" if v.note else "")
                 for v in res.verdicts if v.outcome is Outcome.NOT_DECIDED]
    not_computed = sorted(set(res.limits) - {v.characteristic for v in res.verdicts})
    if not_computed:
        undecided.append("limit(s) given for characteristics this analysis did not compute: " + ", ".join(not_computed))
    empty = [name for name, pr in res.poses.items() if pr.n_cycles == 0]
    if empty:
        undecided.append(f"no attained pose at {', '.join(empty)}")
    if far_stops and not allow_far:
        undecided += far_stops
    reasons = failed + undecided
    outcome = Outcome.FAIL if failed else (Outcome.NOT_DECIDED if undecided else Outcome.PASS)
    conformance_only = False
    if require_iso and not res.iso_conformant:
        reasons.append("not ISO 9283 conformant (--require-iso): " + "; ".join(res.iso_reasons))
        if outcome is Outcome.PASS:
            outcome, conformance_only = Outcome.NOT_DECIDED, True
    return Verdict(outcome, tuple(reasons), conformance_only)
