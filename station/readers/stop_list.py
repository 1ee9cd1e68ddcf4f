"""Stop lists: one averaged point per stop (and per reflector), ``pose,cycle,x,y,z[,reflector][,approach]``.

* ``pose``: the commanded pose's name; ``cycle``: an integer;
* ``x, y, z``: mm (in the tracker frame, or the base frame when no registration is given);
* ``reflector`` (optional): with several reflectors on the flange, one row per
  reflector and stop; every stop must carry the same set of reflectors;
* ``approach`` (optional): a label of the direction the stop was approached
  from (e.g. ``+x``); a stop is one pose, cycle and approach (the
  multi-directional test approaches each pose from three sides per cycle).

The rows of one stop need not be adjacent. Stops keep the order of their first row.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.text import MAX_ROWS, csv_records, parse_number

REQUIRED = ("pose", "cycle", "x", "y", "z")
OPTIONAL = ("reflector", "approach")
#: largest cycle number (ISO 9283 runs 30 cycles; a long-term test some thousands)
MAX_CYCLE = 1_000_000


@dataclass(frozen=True)
class StopList:
    """Stops of a stop list, shape (K,) each; ``points_mm`` (K, R, 3) with R reflectors (1 without the column).

    ``reflectors`` names the R reflectors (sorted; ``("",)`` without the column);
    ``approach`` is None without the column; ``lines`` (K, R) are the file lines.
    """

    pose: tuple[str, ...]
    cycle: np.ndarray
    points_mm: np.ndarray
    reflectors: tuple[str, ...]
    approach: tuple[str, ...] | None
    lines: np.ndarray
    source: str

    @property
    def n(self) -> int:
        return len(self.pose)

    @property
    def centroid_mm(self) -> np.ndarray:
        """(K, 3): the reflectors' centroid of each stop (the stop's position)."""
        return self.points_mm.mean(axis=1)


def _stop_name(pose: str, cycle: int, approach: str | None) -> str:
    return f"pose {pose} cycle {cycle}" + ("" if approach is None else f" approach {approach}")


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_stop_list(path) -> StopList:
    """Read a stop list CSV; DataError naming file, line and column for anything malformed."""
    p = Path(path)
    rows = []
    for ln, c in csv_records(p, REQUIRED, what="a stop list", optional=OPTIONAL):
        if not c["pose"]:
            raise DataError(f"{p}: line {ln}, column 'pose': empty")
        try:
            cyc = int(c["cycle"][:40])
        except ValueError:
            raise DataError(f"{p}: line {ln}, column 'cycle': {c['cycle'][:40]!r} is not an integer") from None
        if not 0 <= cyc <= MAX_CYCLE:
            raise DataError(f"{p}: line {ln}, column 'cycle': {cyc} is not a cycle number (0 to {MAX_CYCLE})")
        xyz = [parse_number(c[k], p, ln, k) for k in ("x", "y", "z")]
        for k in OPTIONAL:
            if k in c and not c[k]:
                raise DataError(f"{p}: line {ln}, column {k!r}: empty")
        rows.append((c["pose"], cyc, c.get("reflector", ""), c.get("approach"), xyz, ln))
        if len(rows) > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} rows")
    if not rows:
        raise DataError(f"{p}: no stops after the header")
    stops: dict[tuple[str, int, str | None], dict] = {}
    for pose, cyc, refl, app, xyz, ln in rows:
        s = stops.setdefault((pose, cyc, app), {"refl": {}, "line0": ln})
        if refl in s["refl"]:
            raise DataError(f"{p}: line {ln}: {_stop_name(pose, cyc, app)}"
                            + (f" reflector {refl}" if refl else "")
                            + f" appears twice (first on line {s['refl'][refl][1]})")
        s["refl"][refl] = (xyz, ln)
    all_refl = sorted({r for s in stops.values() for r in s["refl"]})
    for (pose, cyc, app), s in stops.items():
        lack = [r for r in all_refl if r not in s["refl"]]
        if lack:
            lines = ", ".join(str(v[1]) for v in s["refl"].values())
            raise DataError(f"{p}: {_stop_name(pose, cyc, app)} (line(s) {lines}) has no row for reflector(s) "
                            f"{', '.join(lack)}; every stop must carry every reflector ({', '.join(all_refl)})")
    keys = list(stops)
    pts = np.array([[stops[k]["refl"][r][0] for r in all_refl] for k in keys], dtype=float)
    lines = np.array([[stops[k]["refl"][r][1] for r in all_refl] for k in keys], dtype=np.int64)
    has_app = rows[0][3] is not None  # the approach column is there (its cells are never empty)
    return StopList(pose=tuple(k[0] for k in keys), cycle=np.array([k[1] for k in keys], dtype=np.int64),
                    points_mm=pts, reflectors=tuple(all_refl),
                    approach=tuple(k[2] for k in keys) if has_app else None,
                    lines=lines, source=str(p))
