"""The verdict of a run: its limits, what its procedure says, what the acceptance asked for.

One function, :func:`decide`, reads a run from the store and gives its
:class:`RunDecision`; every front door (``station run``, ``station demo``,
the operator's page, the acceptance API) and the report use it, so they
cannot disagree.

* A run that did not finish is ``ABORTED`` (resumable), whatever it measured.
* Every stored characteristic with a limit counts: kept PASS, not kept FAIL,
  not computed (no value) NOT DECIDED (:func:`station.verdict.outcome_of`).
* The procedure's own checks (``ProcedureSpec.checks``): for ISO 9283, a
  limit configured for a characteristic the analysis did not compute, and
  fewer cycles found than asked, are NOT DECIDED; a run that is not ISO 9283
  conformant is NOT DECIDED when the acceptance requires conformance
  (``params["acceptance"]["require_conformance"]``, ``--require-iso``).
* Plant measurements (:mod:`station.measurements`) stored with the run
  count like characteristics.
* A passing characteristic within the plant's guard band of its limit is
  marginal (:func:`station.analysis.decision.marginal_reason`: within
  ``params["acceptance"]["marginal_fraction"]`` of the limit, default 10 %,
  or its U, where the procedure states one, carrying it over the limit); it
  stays PASS and is listed (``RunDecision.marginal``). A plant measurement
  keeps its own band (``marginal`` of its declaration).

Exit codes are :func:`station.verdict.exit_code`'s (the one table of every
command): 0 PASS, 1 FAIL, 3 NOT DECIDED, 4 NOT DECIDED only because
conformance was required and not met, 5 ABORTED (2, bad input, is the
command's: nothing ran).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from station.verdict import Outcome, Verdict, combine, row_outcome


@dataclass(frozen=True)
class Checks:
    """What a procedure says about one of its finished runs beyond the stored limits."""

    #: reasons no verdict can be given (fewer cycles than asked, a limit not computed, ...)
    undecided: tuple[str, ...] = ()
    #: the standard's conformance; None where the procedure has no such notion
    conformant: bool | None = None
    conformance_reasons: tuple[str, ...] = ()
    #: the expanded uncertainty U of a judged row, where the procedure states one: (pose, name) -> U
    uncertainties: dict = field(default_factory=dict)


@dataclass(frozen=True)
class RunDecision:
    """A run's verdict, its reasons, its conformance and the exit code that says it."""

    verdict: Verdict
    conformant: bool | None = None
    #: per judged row: (pose, name) -> outcome
    outcomes: dict = field(default_factory=dict)
    #: why the run is not conformant to its standard (empty where it is, or has none)
    conformance_reasons: tuple[str, ...] = ()
    #: the passing characteristics within the guard band of their limit: (pose, name, sentence)
    marginal: tuple[tuple[str, str, str], ...] = ()

    @property
    def outcome(self) -> Outcome:
        return self.verdict.outcome

    @property
    def reasons(self) -> tuple[str, ...]:
        return self.verdict.reasons

    @property
    def exit_code(self) -> int:
        return self.verdict.exit_code

    def to_dict(self) -> dict:
        return {**self.verdict.to_dict(), "conformant": self.conformant, "exit_code": self.exit_code,
                "marginal": [sentence for _, _, sentence in self.marginal]}


def _g(x) -> str:
    return f"{float(x):.4g}"


def _unit(u) -> str:
    return "" if u in (None, "", "1") else f" {u}"


def row_reason(r: dict, outcome: Outcome, U: float | None = None) -> str:
    """One sentence for a judged row: value, unit and limit ("P1 RP_mm = 0.06 mm > limit 0.05 mm"); a row not
    decided with its expanded uncertainty ``U`` known says its guard band, and when U alone is wider than the
    limit, that no run as precise as this one can prove it."""
    u = _unit(r.get("unit"))
    if r.get("value") is None:
        return f"{r['pose']} {r['name']}: limit {_g(r['limit'])}{u}, not computed"
    if outcome is Outcome.FAIL:
        return f"{r['pose']} {r['name']} = {_g(r['value'])}{u} > limit {_g(r['limit'])}{u}"
    if outcome is Outcome.NOT_DECIDED:
        head = f"{r['pose']} {r['name']} = {_g(r['value'])}{u}: not decided against limit {_g(r['limit'])}{u}"
        if U is None:
            return head
        L = float(r["limit"])
        head += (f": +/- U {U:.2g}{u} (k = 2) straddles it (guard band {_g(max(L - U, 0.0))}..{_g(L + U)}{u}, guarded rule: "
                 "neither conformance nor non-conformance proven)")
        if U >= L:
            head += (f"; U alone exceeds the limit, so no run this precise can prove conformance (measure longer, "
                     f"or a limit wider than {_g(U)}{u})")
        return head
    return f"{r['pose']} {r['name']} = {_g(r['value'])}{u} <= limit {_g(r['limit'])}{u}"


def decide(spec, store, run_id: str, *, finished: bool = False) -> RunDecision:
    """The verdict of stored run ``run_id`` of procedure ``spec`` (module docstring).

    ``finished``: the run's last step is deciding it (its report), so its
    stored status is not yet ``done``; judge what it has stored.
    """
    rec = store.run(run_id)
    if rec.status != "done" and not finished:
        err = _last_error(store, run_id)
        return RunDecision(Verdict(Outcome.ABORTED, (f"run {rec.status}" + (f": {err}" if err else "")
                                                     + "; resume it",)))
    params = rec.params or {}
    rows = store.characteristics(run_id)
    outcomes = {}
    for r in rows:
        o = row_outcome(r)
        if o is not None:
            outcomes[(r["pose"], r["name"])] = (o, r)
    checks = spec.checks(store, run_id, params) if getattr(spec, "checks", None) else Checks()
    reasons = [row_reason(r, o) for o, r in outcomes.values() if o is Outcome.FAIL]
    reasons += [row_reason(r, o, checks.uncertainties.get((r["pose"], r["name"])))
                for o, r in outcomes.values() if o is Outcome.NOT_DECIDED]
    undecided = list(checks.undecided)
    reasons += undecided
    found = [o for o, _ in outcomes.values()] + [Outcome.NOT_DECIDED] * bool(undecided)
    require = bool((params.get("acceptance") or {}).get("require_conformance"))
    conformance_only = False
    if require and checks.conformant is False:
        reasons.append("not conformant (required): " + "; ".join(checks.conformance_reasons))
        conformance_only = combine(found) is Outcome.PASS
        found.append(Outcome.NOT_DECIDED)
    elif require and checks.conformant is None:
        reasons.append(f"conformance required, but a {rec.procedure} run has no conformance to check")
        found.append(Outcome.NOT_DECIDED)
    return RunDecision(Verdict(combine(found), tuple(reasons), conformance_only), checks.conformant,
                       {k: o for k, (o, _) in outcomes.items()},
                       tuple(checks.conformance_reasons) if checks.conformant is False else (),
                       _marginal(outcomes, checks, params))


def _marginal(outcomes: dict, checks: Checks, params: dict) -> tuple[tuple[str, str, str], ...]:
    """The passing rows within the guard band of their limit (module docstring), plant measurements aside."""
    from station.analysis.decision import marginal_reason
    from station.verdict import MARGINAL_FRACTION

    acceptance = params.get("acceptance") or {}
    fraction = float(acceptance.get("marginal_fraction", MARGINAL_FRACTION))
    plant = {m.get("name") for m in acceptance.get("measurements") or ()}
    out = []
    for (pose, name), (o, r) in outcomes.items():
        if o is not Outcome.PASS or name in plant or r.get("value") is None or r.get("limit") is None:
            continue
        unit = r.get("unit") if r.get("unit") not in (None, "1") else ""
        why = marginal_reason(r["value"], r["limit"], checks.uncertainties.get((pose, name)), fraction, unit)
        if why:
            out.append((pose, name, f"{pose} {name} = {_g(r['value'])}{_unit(r.get('unit'))}: marginal, {why}"))
    return tuple(out)


#: the result entry of a run's evaluated plant measurements
MEASUREMENTS_KEY = "measurements"


def record_measurements(store, run_id: str) -> list[dict]:
    """Judge the plant's measurements stored with the run's plan (``params["acceptance"]["measurements"]``)
    against its characteristics; store them (result ``"measurements"`` with limits, marginal flag and
    outcome, and one characteristic row each, so history and the fleet see them). Idempotent."""
    from station.measurements import evaluate, parse

    params = store.run(run_id).params or {}
    ms = parse((params.get("acceptance") or {}).get("measurements"), f"run {run_id} measurements")
    if not ms:
        return []
    names = {m.name for m in ms}
    rows = [r for r in store.characteristics(run_id) if r["name"] not in names]
    judged = evaluate(ms, rows)
    store.put_result(run_id, MEASUREMENTS_KEY, judged)
    store.put_characteristics(run_id, judged)
    return judged


def _last_error(store, run_id: str) -> str | None:
    msgs = [s.message for s in store.steps(run_id) if s.status in ("failed", "aborted") and s.message]
    return msgs[-1] if msgs else None
