"""Per-pose reflector lists: a file per pose of lines ``reflector, x, y, z`` (mm), as a tracker's point-group
export writes them.

* no header; comma or whitespace separated; ``#`` and ``//`` lines are comments;
* the reflector ids (e.g. ``1, 2, 3``) repeat once per cycle, one block per cycle:
  a cycle ends where an id comes again that the block already holds;
* every cycle carries the same reflectors; a cycle lacking one is refused with its lines.

The pose is named by the caller (``--pose``) or from the file name
(:func:`pose_from_file_name`). The reader returns a
:class:`~station.readers.stop_list.StopList`, one stop per cycle, so a set of
such files is analysed as a stop list with a ``reflector`` column would be.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.stop_list import StopList
from station.readers.text import MAX_ROWS, is_number, numbered_lines, parse_number


def _is_comment(s: str) -> bool:
    return s.startswith("#") or s.startswith("//")


def _cells(s: str) -> list[str]:
    return [c.strip() for c in s.split(",")] if "," in s else s.split()


def looks_like_reflector_list(head: list[str]) -> bool:
    """The first data line is ``id, x, y, z``: four fields, all numbers, the first a whole number."""
    for line in head:
        s = line.strip()
        if not s or _is_comment(s):
            continue
        c = _cells(s)
        return len(c) == 4 and all(is_number(x) for x in c) and c[0].lstrip("+-").isdigit()
    return False


def pose_from_file_name(path) -> str:
    """The pose a file holds, from its name: the last part holding a digit (``reflector_list_pose1.txt`` -> ``pose1``,
    ``P3.txt`` -> ``P3``), else the whole name without its extension."""
    stem = Path(str(path)).stem
    parts = [x for x in re.split(r"[^A-Za-z0-9]+", stem) if x]
    digits = [x for x in parts if any(ch.isdigit() for ch in x)]
    return digits[-1] if digits else stem


def _order(ids) -> list[str]:
    return sorted(ids, key=lambda r: (0, int(r), r) if r.lstrip("+-").isdigit() else (1, 0, r))


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_reflector_list(path, pose: str) -> StopList:
    """One pose's reflector list as a :class:`StopList` of one stop per cycle; DataError naming file and line."""
    p = Path(path)
    blocks: list[dict[str, tuple[list[float], int]]] = []
    cur: dict[str, tuple[list[float], int]] = {}
    nrows = 0
    for ln, line in numbered_lines(p):
        s = line.strip()
        if not s or _is_comment(s):
            continue
        c = _cells(s)
        if len(c) != 4:
            raise DataError(f"{p}: line {ln}: {len(c)} fields; a reflector list has reflector, x, y, z")
        rid = c[0]
        if not rid.lstrip("+-").isdigit():
            raise DataError(f"{p}: line {ln}, column 'reflector': {rid[:40]!r} is not a reflector number")
        rid = str(int(rid))
        xyz = [parse_number(c[k], p, ln, a) for k, a in ((1, "x"), (2, "y"), (3, "z"))]
        if rid in cur:
            blocks.append(cur)
            cur = {}
        cur[rid] = (xyz, ln)
        nrows += 1
        if nrows > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} rows")
    if cur:
        blocks.append(cur)
    if not blocks:
        raise DataError(f"{p}: no reflector rows (reflector, x, y, z)")
    ids = _order(blocks[0])
    for k, b in enumerate(blocks):
        if set(b) != set(ids):
            lines = [v[1] for v in b.values()]
            lack = [r for r in ids if r not in b]
            extra = [r for r in _order(b) if r not in ids]
            what = ("lacks reflector(s) " + ", ".join(lack)) if lack else ("has reflector(s) " + ", ".join(extra)
                                                                            + " the first cycle has not")
            raise DataError(f"{p}: lines {min(lines)}-{max(lines)}: cycle {k + 1} {what} (the first cycle has "
                            f"{', '.join(ids)}; the ids repeat once per cycle)")
    pts = np.array([[b[r][0] for r in ids] for b in blocks], dtype=float)
    lines = np.array([[b[r][1] for r in ids] for b in blocks], dtype=np.int64)
    return StopList(pose=(pose,) * len(blocks), cycle=np.arange(1, len(blocks) + 1, dtype=np.int64),
                    points_mm=pts, reflectors=tuple(ids), approach=None, lines=lines, source=str(p))


def combine_stop_lists(lists: list[StopList]) -> StopList:
    """Several poses' stop lists as one (same reflectors in each; a pose in one file only)."""
    if len(lists) == 1:
        return lists[0]
    first = lists[0]
    seen: dict[str, str] = {}
    for sl in lists:
        if sl.reflectors != first.reflectors:
            raise DataError(f"{sl.source}: reflectors {', '.join(sl.reflectors)}, but {first.source} has "
                            f"{', '.join(first.reflectors)}: every pose must be measured with the same reflectors")
        if (sl.approach is None) != (first.approach is None):
            raise DataError(f"{sl.source}: approach labels in some files and not in others")
        for p in dict.fromkeys(sl.pose):
            if p in seen:
                raise DataError(f"{sl.source}: pose {p!r} is also in {seen[p]}: name each file's pose with "
                                "--pose (one per file, in order)")
            seen[p] = sl.source
    return StopList(pose=sum((sl.pose for sl in lists), ()), cycle=np.concatenate([sl.cycle for sl in lists]),
                    points_mm=np.concatenate([sl.points_mm for sl in lists]), reflectors=first.reflectors,
                    approach=None if first.approach is None else sum((sl.approach for sl in lists), ()),
                    lines=np.concatenate([sl.lines for sl in lists]),
                    source=", ".join(sl.source for sl in lists))
