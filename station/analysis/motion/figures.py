"""The time figures of one approach curve along the travel (pure).

On a curve ``x(t)`` (mm along the travel, the attained position at 0,
negative short of it) from a window of :mod:`.windows`:

* ``POS_mm``: overshoot, the furthest the curve goes past the attained
  position after first coming within ``entry_mm`` of it (0 when it never
  goes past);
* ``time_to_band_s``: from first within ``entry_mm`` (0.1 mm) to first
  within ``band_mm`` (0.02 mm);
* ``PST_s``: posing stabilisation time, from first within ``band_mm`` to the
  last sample outside it (0 when it never leaves the band again);
* ``MPT_s``: from leaving the previous pose to staying within ``band_mm``
  (the end of PST).

A figure the window does not reach is None (the curve never comes that close).
"""

from __future__ import annotations

import numpy as np

#: radius where an approach counts as arriving, mm
ENTRY_MM = 0.1
#: band a stop settles into, mm
BAND_MM = 0.02


def approach_figures(t_s, x_mm, t_leave_s: float, *, entry_mm: float = ENTRY_MM, band_mm: float = BAND_MM) -> dict:
    """POS, time to band, PST and MPT of one curve (see the module's docstring)."""
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x_mm, dtype=float)
    keep = np.isfinite(t) & np.isfinite(x)
    t, x = t[keep], x[keep]
    out = {"POS_mm": None, "time_to_band_s": None, "PST_s": None, "MPT_s": None}
    near = np.flatnonzero(np.abs(x) <= entry_mm)
    if not near.size:
        return out
    i0 = int(near[0])
    out["POS_mm"] = float(max(0.0, np.max(x[i0:])))
    inb = np.flatnonzero(np.abs(x[i0:]) <= band_mm)
    if not inb.size:
        return out
    i1 = i0 + int(inb[0])
    out["time_to_band_s"] = float(t[i1] - t[i0])
    outside = np.flatnonzero(np.abs(x[i1:]) > band_mm)
    i2 = i1 if not outside.size else i1 + int(outside[-1]) + 1
    if i2 >= t.size:
        return out
    out["PST_s"] = float(t[i2] - t[i1])
    out["MPT_s"] = float(t[i2] - t_leave_s)
    return out


def mean_figures(figs: list[dict]) -> dict:
    """Per key, the mean of the figures stated (None when none is)."""
    out = {}
    for k in ("POS_mm", "time_to_band_s", "PST_s", "MPT_s"):
        v = [f[k] for f in figs if f.get(k) is not None]
        out[k] = float(np.mean(v)) if v else None
    return out
