"""The path figures of ISO 9283 (clauses 8.2-8.5 and 11): their rows of the characteristics table
(:mod:`station.characteristics`, programme ``path``), and what only the path analysis needs of them.

The JSON key of a figure is its name (the unit is its suffix).
"""

from __future__ import annotations

from station import characteristics as table

#: the path test's figures, in the table's order
NAMES = tuple(c.key for c in table.characteristics("path"))

#: figures whose sign matters (a limit bounds their magnitude)
SIGNED = frozenset({"AV_percent", "WS_percent", "WF_percent"})
