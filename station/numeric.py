"""Numbers in and out, in one place: parameter checks and JSON numbers.

:func:`finite_number` checks a parameter (a real number, finite, optionally
positive, non-negative, bounded above or integral) and names it in the error;
:func:`finite_or_none` / :func:`finite_list` turn floats into JSON numbers
(non-finite values become ``null``); :func:`json_default` and :func:`dumps`
write numpy values and paths as JSON.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from station.errors import ConfigError

_REAL = (int, float, np.integer, np.floating)


def short_repr(value, most: int = 40) -> str:
    """``value`` as a message shows it: cut after ``most`` characters (with the length), never thousands of digits."""
    try:
        text = repr(value)
    except ValueError:  # an integer too long to print
        return "an integer of thousands of digits"
    return text if len(text) <= most else f"{text[:most - 8]}... ({len(text)} characters)"


def finite_number(value, name: str, *, positive: bool = False, nonneg: bool = False, hi: float | None = None,
                  integer: bool = False, error: type[Exception] = ConfigError):
    """``value`` as a float (an int with ``integer``) after checking it; ``error`` naming ``name`` otherwise.

    Only real numbers pass (not strings, not booleans); the value must be
    finite, ``> 0`` with ``positive``, ``>= 0`` with ``nonneg``, ``<= hi``
    when given, and whole with ``integer``.
    """
    kind = "an integer" if integer else "a finite number"
    bound = " > 0" if positive else " >= 0" if nonneg else ""
    if hi is not None:
        bound += f"{' and' if bound else ''} <= {hi:g}"
    ok = isinstance(value, _REAL) and not isinstance(value, (bool, np.bool_))
    if ok:
        v = float(value)
        ok = math.isfinite(v) and not (positive and v <= 0) and not (nonneg and v < 0) \
            and not (hi is not None and v > hi) and not (integer and v != int(v))
    if not ok:
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        raise error(f"`{name}` must be {kind}{bound}, got {shown}")
    return int(value) if integer else float(value)


def finite_or_none(x, nd: int | None = None):
    """A JSON number: ``None`` for None, NaN or infinity; rounded to ``nd`` decimals when given."""
    if x is None:
        return None
    x = float(x)
    if not math.isfinite(x):
        return None
    return round(x, nd) if nd is not None else x


#: arrays from this size on are rounded by :func:`finite_list` in numpy (below, one ``round`` each is faster)
_ROUND_IN_ARRAYS = 24


def finite_list(a, nd: int | None = 6) -> list:
    """An array as a flat list of JSON numbers (:func:`finite_or_none` of each, to the last digit)."""
    arr = np.asarray(a, dtype=float).ravel()
    if nd is not None and 0 <= nd <= 15 and arr.size >= _ROUND_IN_ARRAYS:
        return _rounded_list(arr, nd)
    xs = arr.tolist()  # Python floats: no numpy scalar per element
    isfinite = math.isfinite
    if nd is None:
        return [x if isfinite(x) else None for x in xs]
    return [round(x, nd) if isfinite(x) else None for x in xs]


def _rounded_list(x: np.ndarray, nd: int) -> list:
    """``[finite_or_none(v, nd) for v in x]`` computed in arrays, to the last digit.

    Python's ``round(v, nd)`` is the double nearest the decimal ``N 10**-nd``, ``N`` the integer nearest
    ``v 10**nd`` taken exactly. ``y = v * 10**nd`` in doubles is within half a unit in its last place of
    that product, so ``rint(y)`` is ``N`` wherever ``y`` is farther than a few units in its last place from
    a half-integer; then ``N / 10**nd``, one correctly rounded division of two exact doubles, is that
    nearest double too. The few numbers near a half (or huge, or not finite) go through ``round`` itself.
    """
    scale = 10.0 ** nd  # exact for nd <= 22
    with np.errstate(over="ignore", invalid="ignore"):
        y = x * scale
        r = np.rint(y)
        ay = np.abs(y)
        sure = (ay < 2.0 ** 50) & (np.abs(np.abs(y - r) - 0.5) > 4.0 * np.spacing(ay))
    out = (r / scale).tolist()
    if not sure.all():
        finite = np.isfinite(x)
        for i in np.flatnonzero(~finite).tolist():  # loop over the numbers not finite
            out[i] = None
        for i in np.flatnonzero(~sure & finite).tolist():  # loop over the numbers near a half or huge
            out[i] = round(float(x[i]), nd)
    return out


def json_default(obj):
    """``json.dumps(default=...)`` for numpy arrays and scalars and paths."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def dumps(value) -> str:
    """Canonical JSON text (sorted keys) of ``value``, numpy values included."""
    return json.dumps(value, default=json_default, sort_keys=True)
