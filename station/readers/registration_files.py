"""Files that tie the tracker frame to the robot base frame.

* frame JSON (``--frame``): the transform as the ``register base frame`` step of
  ``station run`` journals it, ``{"R": [[3x3]], "t_mm": [3], ...}`` with
  ``p_tracker = R @ p_base + t_mm``; the object may also sit under a key
  ``"register base frame"`` or ``"frame"``. Further keys (``rms_mm``,
  ``method``, ...) are kept as information. ``station run`` writes its frame in
  this form beside the report (:func:`write_frame_json`).
* registration CSV (``--register``): point pairs measured in both frames,
  ``name,base_x,base_y,base_z,tracker_x,tracker_y,tracker_z`` (mm), at least three.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from station.errors import DataError
from station.readers.once import reads_once
from station.readers.text import MAX_ABS_MM, csv_records, parse_number, read_small_text

#: largest frame file read, bytes (the step's JSON with its figures is a few hundred)
MAX_FRAME_BYTES = 1 << 20
#: most brackets in a frame file (deep nesting is refused before the parser recurses)
MAX_FRAME_BRACKETS = 10_000
#: most point pairs of a registration (a few dozen in practice)
MAX_PAIRS = 10_000
PAIR_COLUMNS = ("name", "base_x", "base_y", "base_z", "tracker_x", "tracker_y", "tracker_z")


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_frame_json(path) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(R (3,3), t_mm (3,), the JSON object)`` of a frame file; DataError naming the key that is wrong."""
    p = Path(path)
    text = read_small_text(p, MAX_FRAME_BYTES, str(p), "a frame file holds a 3x3 matrix and 3 numbers")
    if text.count("[") + text.count("{") > MAX_FRAME_BRACKETS:
        raise DataError(f"{p}: more than {MAX_FRAME_BRACKETS} brackets; a frame file nests a few levels deep")
    try:
        # integers read as floats: a 400-digit integer is a number too large (refused below), not an overflow
        obj = json.loads(text, parse_int=float)
    except json.JSONDecodeError as exc:
        raise DataError(f"{p}: line {exc.lineno}: not JSON ({exc.msg})") from None
    except (ValueError, RecursionError) as exc:
        raise DataError(f"{p}: not JSON ({str(exc)[:80]})") from None
    if isinstance(obj, dict):
        for key in ("register base frame", "frame"):
            if isinstance(obj.get(key), dict):
                obj = obj[key]
                break
    if not isinstance(obj, dict) or "R" not in obj or "t_mm" not in obj:
        raise DataError(f"{p}: expected an object with keys 'R' (3x3) and 't_mm' (3 numbers), "
                        "p_tracker = R @ p_base + t_mm")
    try:
        R = np.array(obj["R"], dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise DataError(f"{p}: key 'R': not a 3x3 array of numbers") from None
    try:
        t = np.array(obj["t_mm"], dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise DataError(f"{p}: key 't_mm': not 3 numbers") from None
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise DataError(f"{p}: key 'R': need a finite 3x3 array, got shape {R.shape}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise DataError(f"{p}: key 't_mm': need 3 finite numbers, got shape {t.shape}")
    if np.abs(t).max() > MAX_ABS_MM:
        raise DataError(f"{p}: key 't_mm': {float(np.abs(t).max()):.6g} mm is beyond {MAX_ABS_MM:g} mm, "
                        "more than any instrument measures")
    return R, t, obj


@reads_once(one_pass=True)  # read front to back once: a pipe needs no copy
def read_registration_csv(path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """``(names, base (N,3) mm, tracker (N,3) mm)``; DataError naming file, line and column; N >= 3."""
    p = Path(path)
    names, base, trk, seen = [], [], [], set()
    for ln, c in csv_records(p, PAIR_COLUMNS, what="a registration file"):
        if not c["name"]:
            raise DataError(f"{p}: line {ln}, column 'name': empty")
        if c["name"] in seen:
            raise DataError(f"{p}: line {ln}, column 'name': duplicate point {c['name'][:40]!r}")
        if len(names) >= MAX_PAIRS:
            raise DataError(f"{p}: line {ln}: more than {MAX_PAIRS} point pairs")
        names.append(c["name"])
        seen.add(c["name"])
        base.append([parse_number(c[f"base_{a}"], p, ln, f"base_{a}") for a in "xyz"])
        trk.append([parse_number(c[f"tracker_{a}"], p, ln, f"tracker_{a}") for a in "xyz"])
    if len(names) < 3:
        raise DataError(f"{p}: a registration needs at least 3 point pairs (not on one line), got {len(names)}")
    return names, np.array(base), np.array(trk)


def write_frame_json(path, frame: dict) -> Path:
    """Write a registered frame (the ``register base frame`` step's output: ``R``, ``t_mm`` and its figures) in
    the form :func:`read_frame_json` reads (``--frame``); atomically, UTF-8. Returns the path."""
    p = Path(path)
    R = np.asarray(frame["R"], dtype=float)
    t = np.asarray(frame["t_mm"], dtype=float)
    if R.shape != (3, 3) or t.shape != (3,):
        raise DataError(f"{p}: a frame needs R (3x3) and t_mm (3), got shapes {R.shape} and {t.shape}")
    obj = {"R": R.tolist(), "t_mm": t.tolist(), "convention": "p_tracker = R @ p_base + t_mm",
           **{k: v for k, v in frame.items() if k not in ("R", "t_mm")}}
    from station.readers.out_files import write_output

    return write_output(p, json.dumps(obj, indent=1, default=_plain) + "\n", "frame file")


def _plain(x):
    """numpy numbers and arrays in a frame's figures as JSON."""
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"{type(x).__name__} is not JSON")


def frame_info_text(obj: dict) -> str:
    """One line about a frame file's own figures (method, rms), when it has them."""
    parts = []
    if isinstance(obj.get("method"), str):
        parts.append(f"method {obj['method']}")
    rms = obj.get("rms_mm")
    if isinstance(rms, (int, float)) and math.isfinite(rms):
        parts.append(f"rms {float(rms):.3f} mm")
    return ", ".join(parts)
