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
from itertools import repeat
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.text import MAX_ABS_MM, MAX_ROWS, csv_columns, parse_number

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
    """Read a stop list CSV; DataError naming file, line and column for anything malformed.

    The columns are checked and grouped whole (:func:`_whole`); anything they do not pass is checked again
    row by row (:func:`_by_row`), which names the first fault as a reading row by row would.
    """
    p = Path(path)
    got = csv_columns(p, REQUIRED, what="a stop list", optional=OPTIONAL)
    sl = None if got.error is not None or not got.lines else _whole(got, p)
    if sl is None:
        rows = _by_row(got, p)
        if got.error is not None:
            raise got.error
        sl = _grouped(rows, p)
    return sl


def _whole(got, p: Path) -> StopList | None:
    """The stop list from its columns, checked in arrays; None when any check fails (:func:`_by_row` says which)."""
    c = got.cells
    n = len(got.lines)
    pose, cycle = c["pose"], c["cycle"]
    if "" in pose or max(map(len, cycle)) > 40 or any("" in c[k] for k in OPTIONAL if k in c):
        return None
    try:
        cyc = list(map(int, cycle))
        xyz = np.array([list(map(float, c[k])) for k in ("x", "y", "z")]).T  # (n, 3)
    except ValueError:
        return None
    if not (0 <= min(cyc) and max(cyc) <= MAX_CYCLE and np.all(np.isfinite(xyz))
            and np.all(np.abs(xyz) <= MAX_ABS_MM)):
        return None
    refl = c.get("reflector")
    app = c.get("approach")
    index: dict[tuple, int] = {}  # stop (pose, cycle, approach) -> its number, in order of first row
    keys = zip(pose, cyc, app) if app is not None else zip(pose, cyc, repeat(None))
    stop = np.array([index.setdefault(k, len(index)) for k in keys], dtype=np.int64)
    K = len(index)
    all_refl = sorted(set(refl)) if refl is not None else [""]
    R = len(all_refl)
    if refl is None:
        ri = np.zeros(n, np.int64)
    else:
        at = {r: j for j, r in enumerate(all_refl)}
        ri = np.array([at[r] for r in refl], dtype=np.int64)
    # every stop has every reflector once: no (stop, reflector) twice, and R rows per stop
    if K * R != n or np.unique(stop * R + ri).size != n:
        return None
    pts = np.empty((K, R, 3))
    pts[stop, ri] = xyz
    lines = np.empty((K, R), dtype=np.int64)
    lines[stop, ri] = got.lines
    keys = list(index)
    return StopList(pose=tuple(k[0] for k in keys), cycle=np.array([k[1] for k in keys], dtype=np.int64),
                    points_mm=pts, reflectors=tuple(all_refl),
                    approach=tuple(k[2] for k in keys) if app is not None else None,
                    lines=lines, source=str(p))


def _by_row(got, p: Path) -> list[tuple]:
    """The rows checked one by one: the first fault a DataError naming its line and column."""
    c = got.cells
    rows = []
    refl, app = c.get("reflector"), c.get("approach")
    for i, ln in enumerate(got.lines):  # loop over rows
        if not c["pose"][i]:
            raise DataError(f"{p}: line {ln}, column 'pose': empty")
        cell = c["cycle"][i]
        try:
            cyc = int(cell[:40])
        except ValueError:
            raise DataError(f"{p}: line {ln}, column 'cycle': {cell[:40]!r} is not an integer") from None
        if not 0 <= cyc <= MAX_CYCLE:
            raise DataError(f"{p}: line {ln}, column 'cycle': {cyc} is not a cycle number (0 to {MAX_CYCLE})")
        xyz = [parse_number(c[k][i], p, ln, k) for k in ("x", "y", "z")]
        for k in OPTIONAL:
            if k in c and not c[k][i]:
                raise DataError(f"{p}: line {ln}, column {k!r}: empty")
        rows.append((c["pose"][i], cyc, "" if refl is None else refl[i], None if app is None else app[i], xyz, ln))
        if len(rows) > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} rows")
    return rows


def _grouped(rows: list[tuple], p: Path) -> StopList:
    """The stops of checked rows, grouped one row at a time: the first duplicate or missing reflector named."""
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
