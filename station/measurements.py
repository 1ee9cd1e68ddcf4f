"""A plant's own measurements, declared per procedure and judged like the standard's characteristics.

In the manner of OpenHTF's measurements: each has a name, a unit, limits
(``low`` and/or ``high``), an optional marginal band (a PASS that lies within
``marginal`` of a limit is flagged marginal) and what it measures:

* ``of``: a characteristic the procedure stores (``"RP_mm"``, ``"AP_mm"``,
  ``"mean_test_error_mm"``, ...);
* ``pose``: one pose (``"P1"``), every pose (``"each"``: one row per pose),
  or the whole run (``None``: the worst over the poses, i.e. the largest
  value when only ``high`` is given, the smallest when only ``low``, else
  the value nearest a limit).

Declared in the config (``[[measurements.iso9283]]`` tables, or under a
robot: ``[[robots.r1.measurements.iso9283]]``) or in a script
(:class:`Measurement`). :func:`evaluate` judges them against a run's stored
characteristics (pure: rows in, rows out); each judged row has ``pose``,
``name``, ``value``, ``unit``, ``low``, ``high``, ``limit`` (the high limit,
or the low one when only that is given), ``marginal`` (bool), ``outcome``
(:class:`station.verdict.Outcome` text) and ``passed``. A characteristic not
computed gives NOT DECIDED, never PASS.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass

from station.errors import ConfigError
from station.verdict import Outcome

#: ``pose`` value that makes one row per pose of the characteristic
EACH = "each"


@dataclass(frozen=True)
class Measurement:
    """One declared measurement (module docstring)."""

    name: str
    of: str
    unit: str = "mm"
    low: float | None = None
    high: float | None = None
    marginal: float = 0.0
    pose: str | None = None
    description: str = ""

    def __post_init__(self) -> None:
        where = f"measurement {self.name!r}"
        if not self.name or not str(self.name).strip():
            raise ConfigError("a measurement needs a name")
        if not self.of:
            raise ConfigError(f"{where}: `of` names the characteristic it measures (e.g. 'RP_mm')")
        for k in ("low", "high"):
            v = getattr(self, k)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ConfigError(f"{where}: `{k}` must be a finite number, got {v!r}")
        if self.name == self.of:
            raise ConfigError(f"{where}: name it apart from the characteristic it measures ({self.of!r})")
        if self.low is None and self.high is None:
            raise ConfigError(f"{where}: give a limit (`low` and/or `high`, in {self.unit})")
        if self.low is not None and self.high is not None and self.low > self.high:
            raise ConfigError(f"{where}: low {self.low:g} > high {self.high:g}")
        if not (isinstance(self.marginal, (int, float)) and math.isfinite(self.marginal) and self.marginal >= 0):
            raise ConfigError(f"{where}: `marginal` must be a finite number >= 0 ({self.unit}), got {self.marginal!r}")

    @classmethod
    def from_dict(cls, d: Mapping, where: str = "measurement") -> "Measurement":
        """From a config table or JSON; an unknown key is refused, naming it and ``where``."""
        known = set(cls.__dataclass_fields__)
        extra = sorted(set(d) - known)
        if extra:
            raise ConfigError(f"{where}: unknown key(s) {', '.join(extra)} (known: {', '.join(sorted(known))})")
        try:
            return cls(**dict(d))
        except TypeError as exc:
            raise ConfigError(f"{where}: {exc}") from None

    def to_dict(self) -> dict:
        return asdict(self)


def _outcome(m: Measurement, value: float | None) -> tuple[Outcome, bool]:
    if value is None or not math.isfinite(value):
        return Outcome.NOT_DECIDED, False
    if (m.low is not None and value < m.low) or (m.high is not None and value > m.high):
        return Outcome.FAIL, False
    near = ((m.low is not None and value - m.low < m.marginal) or
            (m.high is not None and m.high - value < m.marginal))
    return Outcome.PASS, bool(near and m.marginal > 0)


def _worst(m: Measurement, values: list[float]) -> float:
    if m.low is None:
        return max(values)
    if m.high is None:
        return min(values)
    mid = 0.5 * (m.low + m.high)
    return max(values, key=lambda v: abs(v - mid))


def evaluate(measurements: Iterable[Measurement], rows: Iterable[Mapping]) -> list[dict]:
    """Judge each measurement against a run's characteristic rows (``pose``, ``name``, ``value``)."""
    rows = list(rows)
    out = []
    for m in measurements:
        mine = [r for r in rows if r["name"] == m.of]
        if m.pose == EACH:
            targets = [(r["pose"], r["value"]) for r in mine] or [("-", None)]
        elif m.pose is not None:
            targets = [(m.pose, next((r["value"] for r in mine if r["pose"] == m.pose), None))]
        else:
            vals = [r["value"] for r in mine]
            value = None if (not vals or any(v is None for v in vals)) else _worst(m, [float(v) for v in vals])
            targets = [("run", value)]
        for pose, value in targets:
            value = None if value is None else float(value)
            outcome, marginal = _outcome(m, value)
            out.append({"pose": pose, "name": m.name, "of": m.of, "value": value, "unit": m.unit,
                        "low": m.low, "high": m.high, "limit": m.high if m.high is not None else m.low,
                        "marginal": marginal, "outcome": outcome.value,
                        "passed": outcome.passed,
                        "description": m.description})
    return out


def parse(entries, where: str) -> list[Measurement]:
    """Measurements from config entries (a list of tables); names must be unique."""
    if entries is None:
        return []
    if not isinstance(entries, (list, tuple)):
        raise ConfigError(f"{where}: a list of measurement tables expected, got {type(entries).__name__}")
    ms = [e if isinstance(e, Measurement) else Measurement.from_dict(e, f"{where}[{i}]") for i, e in enumerate(entries)]
    seen = set()
    for m in ms:
        if m.name in seen:
            raise ConfigError(f"{where}: measurement {m.name!r} declared twice")
        seen.add(m.name)
    return ms


__all__ = ["Measurement", "evaluate", "parse", "EACH"]
