"""Conformity decisions of one figure against its limit (ISO 14253-1).

The limits of ISO 9283 figures are upper limits (``|figure| <= limit``).

* ``simple``: the figure itself is compared with the limit (what the station
  always did; the uncertainty is shown but does not decide);
* ``guarded``: conformance is proven only when ``|figure| + U <= limit``,
  non-conformance only when ``|figure| - U > limit``; in between the figure
  lies inside the guard band ``(limit - U, limit + U]`` and the outcome is
  NOT DECIDED.

The outcome is a :class:`station.verdict.Outcome` (PASS, FAIL, NOT_DECIDED;
the run's one verdict combines them elsewhere).

A passing figure is *marginal* (:func:`marginal_reason`) when it lies within
the plant's guard band of its limit: ``|figure| >= (1 - fraction) * limit``
(default :data:`station.verdict.MARGINAL_FRACTION`), or, where its ``U`` is known, when
``|figure| + U`` exceeds the limit (under ``simple`` such a figure passes
although its interval straddles the limit; under ``guarded`` it is not
decided, never passing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from station.errors import ConfigError
from station.verdict import MARGINAL_FRACTION, Outcome

RULES = ("simple", "guarded")


@dataclass(frozen=True)
class Decision:
    """The outcome of one figure; ``guard_band`` = (acceptance limit, rejection limit) under ``guarded``."""

    outcome: Outcome
    rule: str
    value: float
    limit: float
    U: float | None
    guard_band: tuple[float, float] | None

    @property
    def passed(self) -> bool | None:
        """As the store's ``passed``: True, False, or None (not decided)."""
        return self.outcome.passed

    def explain(self) -> str:
        """One sentence: why this outcome."""
        v = abs(self.value)
        if self.rule == "simple" or self.U is None:
            return f"{v:.4g} {'<=' if self.outcome is Outcome.PASS else '>'} {self.limit:g}"
        if self.outcome is Outcome.PASS:
            return f"{v:.4g} + U {self.U:.2g} <= {self.limit:g}: conformance proven"
        if self.outcome is Outcome.FAIL:
            return f"{v:.4g} - U {self.U:.2g} > {self.limit:g}: non-conformance proven"
        lo, hi = self.guard_band
        return (f"{v:.4g} lies in the guard band {lo:.4g}..{hi:.4g} (limit {self.limit:g} -/+ U {self.U:.2g}): "
                "neither conformance nor non-conformance proven")


def check_rule(rule: str) -> str:
    if rule not in RULES:
        raise ConfigError(f"decision_rule must be one of {', '.join(RULES)}, got {rule!r}")
    return rule


def decide(value: float, limit: float, U: float | None = None, rule: str = "simple") -> Decision:
    """The decision on ``|value| <= limit`` under ``rule`` with the expanded uncertainty ``U``.

    Under ``guarded`` a missing ``U`` decides nothing (:data:`Outcome.NOT_DECIDED`).
    """
    check_rule(rule)
    v, L = float(value), float(limit)
    if not (math.isfinite(v) and math.isfinite(L)):
        raise ValueError(f"decide: value and limit must be finite, got {value!r}, {limit!r}")
    a = abs(v)
    if rule == "simple":
        return Decision(Outcome.PASS if a <= L else Outcome.FAIL, rule, v, L, U, None)
    if U is None or not math.isfinite(U):
        return Decision(Outcome.NOT_DECIDED, rule, v, L, None, None)
    U = float(U)
    if U < 0:
        raise ValueError(f"decide: U must be >= 0, got {U!r}")
    band = (L - U, L + U)
    if a + U <= L:
        out = Outcome.PASS
    elif a - U > L:
        out = Outcome.FAIL
    else:
        out = Outcome.NOT_DECIDED
    return Decision(out, rule, v, L, U, band)


def marginal_reason(value: float, limit: float, U: float | None = None,
                    fraction: float = MARGINAL_FRACTION, unit: str = "") -> str | None:
    """Why a figure that passed ``|value| <= limit`` is marginal (module docstring), or None when it is not.

    ``fraction`` is the guard band as a fraction of the limit (0 <= fraction < 1); ``U`` the figure's
    expanded uncertainty (None: not known, only the fraction counts); ``unit`` is said after the limit.
    """
    if not (0.0 <= float(fraction) < 1.0):
        raise ValueError(f"marginal fraction must lie in [0, 1), got {fraction!r}")
    a, L = abs(float(value)), float(limit)
    u = f" {unit}" if unit else ""
    if not (math.isfinite(a) and math.isfinite(L)) or a > L:
        return None
    why = []
    if fraction > 0 and a >= (1.0 - fraction) * L:
        why.append(f"within {100 * fraction:.3g} % of its limit {L:g}{u}")
    if U is not None and math.isfinite(U) and a + U > L:
        why.append(f"{a:.4g} + U {U:.2g} > limit {L:g}{u}: its interval straddles the limit")
    return "; ".join(why) or None
