"""What every stream reader returns: :class:`PointStream`, one row per measured point in file order."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PointStream:
    """Points of one file, in file order.

    Attributes
    ----------
    xyz_mm : ndarray, shape (N, 3)
        Positions, mm (converted from the file's units). Rows flagged invalid may hold NaN.
    t_s : ndarray, shape (N,), or None
        Time stamps as the file gives them, s (relative to the first row for date-time
        stamps); None when the file has no time.
    valid : ndarray of bool, shape (N,)
        False for rows the instrument flagged (status column).
    line : ndarray of int, shape (N,)
        File line of each row (1-based), for messages.
    abc_deg : ndarray, shape (N, 3), or None
        Orientation a, b, c of 6-DOF data, deg.
    names : tuple of str, or None
        Point names or ids, when the file has them.
    fmt : str
        The format read: ``csv`` (the project's stream CSV), ``sa`` (SpatialAnalyzer point
        export) or ``points`` (plain point list).
    source : str
        The file.
    group : str or None
        The group the points came from (SpatialAnalyzer).
    frame : str or None
        The coordinate frame the file says its points are relative to.
    units : str
        The file's length unit (converted to mm).
    notes : tuple of str
        What was read but left out (e.g. a stray group), one sentence each.
    """

    xyz_mm: np.ndarray
    t_s: np.ndarray | None
    valid: np.ndarray
    line: np.ndarray
    abc_deg: np.ndarray | None = None
    names: tuple[str, ...] | None = None
    fmt: str = "csv"
    source: str = ""
    group: str | None = None
    frame: str | None = None
    units: str = "mm"
    notes: tuple[str, ...] = field(default=())

    @property
    def n(self) -> int:
        return int(self.xyz_mm.shape[0])
