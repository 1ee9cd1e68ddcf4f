"""A lab's motion program, minimal form (JSON or TOML): what ``station diagnose motion --program`` needs.

Keys (all optional but one of them):

* ``poses``: the pose names in the order the program visits them;
* ``move``: ``"joint"`` or ``"linear"``;
* ``speed`` and ``acceleration``: deg/s and deg/s^2 for joint moves, mm/s and mm/s^2 for linear ones;
* ``dwell_s``: the wait at each stop, s (lets the clock be checked against the dwells);
* ``cycles``: cycles of the program;
* ``rate_hz``: the tracker's sampling rate, Hz (``--rate-hz`` overrides).

Kept in this one module so that it can be unified with the program grammar of
``station simulate iso9283 --program`` later. Unknown keys are refused, naming them.
"""

from __future__ import annotations

import json
import math
import tomllib

from station.errors import DataError
from station.readers.once import read_text, shown_name
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

#: largest program file, bytes
MAX_BYTES = 1 << 20
#: (lowest, highest) of each number
RANGES = {"speed": (1e-3, 1e5), "acceleration": (1e-3, 1e6), "dwell_s": (0.0, 600.0), "cycles": (1, 100000),
          "rate_hz": TRACKER_RATE_RANGE_HZ}
KEYS = ("poses", "move", "speed", "acceleration", "dwell_s", "cycles", "rate_hz")


def parse_motion_program(doc, where: str) -> dict:
    """The checked program (a dict of the keys given); DataError naming the key."""
    if not isinstance(doc, dict):
        raise DataError(f"{where}: a program is a table of keys ({', '.join(KEYS)})")
    unknown = sorted(set(doc) - set(KEYS))
    if unknown:
        raise DataError(f"{where}: unknown key(s) {', '.join(repr(k)[:40] for k in unknown[:5])}; "
                        f"a program has {', '.join(KEYS)}")
    if not doc:
        raise DataError(f"{where}: the program is empty")
    out: dict = {}
    for key, (lo, hi) in RANGES.items():
        if key not in doc:
            continue
        v = doc[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise DataError(f"{where}: {key!r} must be a number, got {str(v)[:40]!r}")
        if key == "cycles" and not isinstance(v, int):
            raise DataError(f"{where}: 'cycles' must be a whole number, got {v!r}")
        if not lo <= v <= hi:
            raise DataError(f"{where}: {key!r} = {v!r} is outside {lo:g}-{hi:g}")
        out[key] = v
    if "move" in doc:
        if doc["move"] not in ("joint", "linear"):
            raise DataError(f"{where}: 'move' must be 'joint' or 'linear', got {str(doc['move'])[:40]!r}")
        out["move"] = doc["move"]
    if "poses" in doc:
        p = doc["poses"]
        if not (isinstance(p, list) and p and all(isinstance(x, str) and x for x in p)):
            raise DataError(f"{where}: 'poses' must be a list of pose names")
        out["poses"] = list(p)
    if "dwell_s" in out and out["dwell_s"] <= 0.05:
        raise DataError(f"{where}: 'dwell_s' = {out['dwell_s']!r}: the stops' wait must be more than 0.05 s")
    return out


def read_motion_program(path) -> dict:
    """Read a program file (JSON, or TOML when it does not start with ``{``)."""
    where = shown_name(path)
    text = read_text(path, MAX_BYTES, "a program file")
    try:
        doc = json.loads(text) if text.lstrip().startswith("{") else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise DataError(f"{where}: not a JSON or TOML program: {exc}") from None
    return parse_motion_program(doc, where)
