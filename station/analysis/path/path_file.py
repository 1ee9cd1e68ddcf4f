"""The path file: the commanded paths of a path test (JSON, or TOML by the ``.toml`` suffix).

Lengths mm, angles degrees, velocity mm/s, frequency Hz, times s. See the
README, "File formats". ``{"paths": [ {...}, ... ]}``; each path has a unique
``name`` and a ``kind``:

* ``line``: ``start_mm``, ``end_mm``;
* ``arc``: ``points_mm`` (three points: start, through, end), ``full`` (bool,
  the whole circle from the first point; default false);
* ``rectangle``: ``corners_mm`` (four, in the order driven, the first where
  each cycle starts), ``blend_mm`` (commanded blend radius, default 0);
* ``weaving``: ``start_mm``, ``end_mm`` (the base line), ``direction_mm``
  (across it; normalised), ``amplitude_mm``, ``frequency_Hz``;
* ``reorientation``: ``point_mm``, ``start_abc_deg``, ``end_abc_deg``.

Optional on every path: ``velocity_mm_s`` (the commanded speed: AV, RV, FV on
lines and arcs), ``planes`` (normal planes, default 50), ``end_margin``
(fraction of the length left without planes at either end, 0.05),
``velocity_window`` ([from, to] fractions of the length, [0.25, 0.75]),
``tube_mm`` (samples farther from the path do not belong to it, 5), ``window_s``
([t0, t1]: the stream's span that belongs to this path, when paths overlap).
"""

from __future__ import annotations

import json

import numpy as np

from station.analysis.path.commanded import (
    MIN_PLANES,
    Arc,
    Line,
    PathSpec,
    Rectangle,
    Reorientation,
    Weaving,
    _unit,
    _vec,
)
from station.errors import ConfigError

_COMMON = {"name", "kind", "velocity_mm_s", "planes", "end_margin", "velocity_window", "tube_mm", "window_s"}
_KINDS = {
    "line": {"start_mm", "end_mm"},
    "arc": {"points_mm", "full"},
    "rectangle": {"corners_mm", "blend_mm"},
    "weaving": {"start_mm", "end_mm", "direction_mm", "amplitude_mm", "frequency_Hz"},
    "reorientation": {"point_mm", "start_abc_deg", "end_abc_deg"},
}
_REQUIRED = {"line": {"start_mm", "end_mm"}, "arc": {"points_mm"}, "rectangle": {"corners_mm"},
             "weaving": {"start_mm", "end_mm", "direction_mm", "amplitude_mm", "frequency_Hz"},
             "reorientation": {"point_mm", "start_abc_deg", "end_abc_deg"}}


def _num(d, key, where, *, positive=True, default=None):
    v = d.get(key, default)
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: {key} must be a number, got {v!r}") from None
    if not np.isfinite(x) or (positive and x <= 0):
        raise ConfigError(f"{where}: {key} must be a finite number{' > 0' if positive else ''}, got {v!r}")
    return x


def _pair(d, key, where, default):
    v = d.get(key, default)
    if v is None:
        return None
    try:
        a, b = (float(x) for x in v)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: {key} must be two numbers [from, to], got {v!r}") from None
    if not (np.isfinite(a) and np.isfinite(b) and a < b):
        raise ConfigError(f"{where}: {key} must be [from, to] with from < to, got {v!r}")
    return a, b


def _geometry(kind, d, where):
    v = lambda key: _vec(d[key], f"{where}: {key}")  # noqa: E731
    if kind == "line":
        return Line(v("start_mm"), v("end_mm"))
    if kind == "arc":
        pts = d["points_mm"]
        if not isinstance(pts, list) or len(pts) != 3:
            raise ConfigError(f"{where}: points_mm must be three points [x, y, z], got {pts!r}")
        return Arc(*(_vec(p, f"{where}: points_mm[{i}]") for i, p in enumerate(pts)), full=bool(d.get("full", False)))
    if kind == "rectangle":
        c = d["corners_mm"]
        if not isinstance(c, list) or len(c) != 4:
            raise ConfigError(f"{where}: corners_mm must be four points [x, y, z], got {c!r}")
        return Rectangle(np.stack([_vec(p, f"{where}: corners_mm[{i}]") for i, p in enumerate(c)]),
                         _num(d, "blend_mm", where, positive=False, default=0.0))
    if kind == "weaving":
        return Weaving(Line(v("start_mm"), v("end_mm")), _unit(v("direction_mm"), f"{where}: direction_mm"),
                       _num(d, "amplitude_mm", where), _num(d, "frequency_Hz", where))
    return Reorientation(v("point_mm"), v("start_abc_deg"), v("end_abc_deg"))


def parse_paths(doc) -> list[PathSpec]:
    """The paths of a parsed path file (a dict); ConfigError naming the path and key that is wrong."""
    if not isinstance(doc, dict) or not isinstance(doc.get("paths"), list) or not doc["paths"]:
        raise ConfigError("a path file needs a non-empty list 'paths'")
    extra = set(doc) - {"paths"}
    if extra:
        raise ConfigError(f"path file: unknown keys {sorted(extra)} (only 'paths')")
    specs, names = [], set()
    for i, d in enumerate(doc["paths"]):  # loop over paths
        where = f"paths[{i}]"
        if not isinstance(d, dict):
            raise ConfigError(f"{where} must be a table/object")
        name, kind = d.get("name"), d.get("kind")
        if not isinstance(name, str) or not name or "." in name:
            raise ConfigError(f"{where}: name must be a non-empty string without '.', got {name!r}")
        where = f"path {name!r}"
        if name in names:
            raise ConfigError(f"{where} is named twice")
        names.add(name)
        if kind not in _KINDS:
            raise ConfigError(f"{where}: kind must be one of {sorted(_KINDS)}, got {kind!r}")
        unknown = set(d) - _COMMON - _KINDS[kind]
        if unknown:
            raise ConfigError(f"{where}: unknown keys {sorted(unknown)} for a {kind}")
        missing = _REQUIRED[kind] - set(d)
        if missing:
            raise ConfigError(f"{where}: a {kind} needs {sorted(missing)}")
        planes = d.get("planes", 50)
        if not isinstance(planes, int) or planes < MIN_PLANES:
            raise ConfigError(f"{where}: planes must be an integer >= {MIN_PLANES}, got {planes!r}")
        margin = _num(d, "end_margin", where, positive=False, default=0.05)
        if not 0 <= margin < 0.5:
            raise ConfigError(f"{where}: end_margin must be in [0, 0.5), got {margin}")
        vw = _pair(d, "velocity_window", where, (0.25, 0.75))
        if not (0 <= vw[0] and vw[1] <= 1):
            raise ConfigError(f"{where}: velocity_window must lie within [0, 1], got {list(vw)}")
        specs.append(PathSpec(name, _geometry(kind, d, where), _num(d, "velocity_mm_s", where), planes, margin, vw,
                              _num(d, "tube_mm", where, default=5.0), _pair(d, "window_s", where, None)))
    return specs


def parse_path_text(text: str, source: str = "path file") -> list[PathSpec]:
    """Parse a path file's text: TOML when ``source`` ends in ``.toml``, JSON otherwise."""
    try:
        if source.lower().endswith(".toml"):
            import tomllib

            doc = tomllib.loads(text)
        else:
            doc = json.loads(text)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{source}: not a valid {'TOML' if source.lower().endswith('.toml') else 'JSON'} "
                          f"path file: {exc}") from None
    try:
        return parse_paths(doc)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
