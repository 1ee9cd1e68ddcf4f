"""The path figures of ISO 9283 (clauses 8.2-8.5 and 11): name, unit and meaning, one row each.

Kept as one small list so that they become rows of the characteristics table
(level ``path``) when the two are merged. The JSON key of a figure is its name
(the unit is its suffix).
"""

from __future__ import annotations

#: (name, unit, clause, meaning)
FIGURES: tuple[tuple[str, str, str, str], ...] = (
    ("AT_mm", "mm", "8.2", "path accuracy: largest distance of a normal plane's barycentre from the commanded point"),
    ("RT_mm", "mm", "8.2", "path repeatability: largest l_bar + 3 S_l over the normal planes"),
    ("CR_mm", "mm", "8.4", "cornering round-off error: least distance of the attained path from the corner point "
                           "(largest over corners and cycles)"),
    ("CO_mm", "mm", "8.4", "cornering overshoot: largest deviation outward of the second edge after the corner "
                           "(largest over corners and cycles)"),
    ("AV_percent", "%", "8.5", "path velocity accuracy: (mean attained speed - commanded) / commanded"),
    ("RV_percent", "%", "8.5", "path velocity repeatability: 3 S of the cycles' mean speeds / commanded"),
    ("FV_percent", "%", "8.5", "path velocity fluctuation: largest max - min of the speed within one cycle / commanded"),
    ("WS_percent", "%", "11", "weaving stroke error: (mean attained amplitude - commanded) / commanded"),
    ("WF_percent", "%", "11", "weaving frequency error: (mean attained frequency - commanded) / commanded"),
)

NAMES = tuple(f[0] for f in FIGURES)

#: figures that rest on the clock (refused on a clock that failed its check, or across a jump)
TIME_FIGURES = frozenset({"AV_percent", "RV_percent", "FV_percent", "WF_percent"})

#: figures whose sign matters (a limit bounds their magnitude)
SIGNED = frozenset({"AV_percent", "WS_percent", "WF_percent"})
