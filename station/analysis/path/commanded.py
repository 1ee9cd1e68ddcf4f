"""The commanded path: its kinds, its points by arc length, its normal planes (ISO 9283 clause 8.2).

Every kind gives ``point_at(s)`` and ``tangent_at(s)`` for arc lengths ``s``
(mm from its start, vectorised) and its length; a closed path (full circle,
rectangle) starts again where it began. Kinds:

* :class:`Line`: start to end;
* :class:`Arc`: the circle through three points, from the first through the
  second to the third (``full``: the whole circle, from the first point in the
  sense the second gives);
* :class:`Rectangle`: four corners in order, closed, optionally commanded with
  a blend radius (the commanded path for CR and CO is the sharp corner; the
  blend is what the robot was told, kept for the report);
* :class:`Weaving`: a sine pattern of amplitude and frequency across a base
  line, in a direction normal to it (clause 11);
* :class:`Reorientation`: the tool's point held while its orientation turns
  from one set of angles to another (clause 8.3); its "arc length" is the
  turned angle, degrees.

Lengths mm, angles degrees, velocity mm/s, frequency Hz.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.errors import ConfigError

#: fewest normal planes along a path
MIN_PLANES = 3


def _vec(x, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{what} must be three finite numbers, got {x!r}")
    return a


def _unit(v, what: str) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-9:
        raise ConfigError(f"{what} has no length")
    return v / n


@dataclass(frozen=True)
class Line:
    start_mm: np.ndarray
    end_mm: np.ndarray
    closed = False

    def __post_init__(self):
        _unit(self.end_mm - self.start_mm, "a line from its start to its end")

    @property
    def length_mm(self) -> float:
        return float(np.linalg.norm(self.end_mm - self.start_mm))

    def tangent_at(self, s) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return np.broadcast_to((self.end_mm - self.start_mm) / self.length_mm, (s.size, 3)).copy()

    def point_at(self, s) -> np.ndarray:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return self.start_mm[None] + s[:, None] * self.tangent_at(s)


@dataclass(frozen=True)
class Arc:
    """The circle through ``p1``, ``p2``, ``p3``: centre, radius, plane; the arc p1 -> p2 -> p3, or the whole circle."""

    p1_mm: np.ndarray
    p2_mm: np.ndarray
    p3_mm: np.ndarray
    full: bool = False
    centre_mm: np.ndarray = field(init=False)
    radius_mm: float = field(init=False)
    _e1: np.ndarray = field(init=False)
    _e2: np.ndarray = field(init=False)
    _sweep: float = field(init=False)

    def __post_init__(self):
        a, b = self.p2_mm - self.p1_mm, self.p3_mm - self.p1_mm
        nrm = np.cross(a, b)
        if float(np.linalg.norm(nrm)) < 1e-6 * max(float(np.dot(a, a)), float(np.dot(b, b)), 1e-12):
            raise ConfigError("an arc's three points lie on one line (or two coincide)")
        # centre = p1 + (|a|^2 (b x n) + |b|^2 (n x a)) / (2 |n|^2)  (the circumcentre)
        c = self.p1_mm + (np.dot(a, a) * np.cross(b, nrm) + np.dot(b, b) * np.cross(nrm, a)) / (2 * np.dot(nrm, nrm))
        r = float(np.linalg.norm(self.p1_mm - c))
        e1 = (self.p1_mm - c) / r
        e2 = np.cross(_unit(nrm, "the arc's normal"), e1)  # sense p1 -> p2 (n = a x b)
        ang3 = float(np.arctan2(np.dot(self.p3_mm - c, e2), np.dot(self.p3_mm - c, e1))) % (2 * np.pi)
        object.__setattr__(self, "centre_mm", c)
        object.__setattr__(self, "radius_mm", r)
        object.__setattr__(self, "_e1", e1)
        object.__setattr__(self, "_e2", e2)
        object.__setattr__(self, "_sweep", 2 * np.pi if self.full else ang3)

    @property
    def closed(self) -> bool:
        return self.full

    @property
    def length_mm(self) -> float:
        return self.radius_mm * self._sweep

    def point_at(self, s) -> np.ndarray:
        phi = np.atleast_1d(np.asarray(s, dtype=float)) / self.radius_mm
        return self.centre_mm[None] + self.radius_mm * (np.cos(phi)[:, None] * self._e1 + np.sin(phi)[:, None] * self._e2)

    def tangent_at(self, s) -> np.ndarray:
        phi = np.atleast_1d(np.asarray(s, dtype=float)) / self.radius_mm
        return -np.sin(phi)[:, None] * self._e1 + np.cos(phi)[:, None] * self._e2


@dataclass(frozen=True)
class Rectangle:
    """Four corners in order (closed); ``blend_mm`` the commanded blend radius (0: a stop-free sharp corner)."""

    corners_mm: np.ndarray
    blend_mm: float = 0.0
    closed = True

    def __post_init__(self):
        c = np.asarray(self.corners_mm, dtype=float)
        if c.shape != (4, 3) or not np.all(np.isfinite(c)):
            raise ConfigError(f"a rectangle needs four finite corners [x, y, z], got shape {c.shape}")
        for i in range(4):
            _unit(c[(i + 1) % 4] - c[i], f"the rectangle's edge {i + 1}")
        if not (np.isfinite(self.blend_mm) and self.blend_mm >= 0):
            raise ConfigError(f"blend_mm must be >= 0, got {self.blend_mm}")

    @property
    def _cum(self) -> np.ndarray:
        c = np.asarray(self.corners_mm, dtype=float)
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(c[[1, 2, 3, 0]] - c, axis=1))])

    @property
    def length_mm(self) -> float:
        return float(self._cum[-1])

    @property
    def corner_s_mm(self) -> np.ndarray:
        """Arc length of each corner (the first at 0 and again at the length)."""
        return self._cum[:4]

    @property
    def edges_mm(self) -> np.ndarray:
        """Length of each edge (4,), from each corner to the next."""
        return np.diff(self._cum)

    def _edge(self, s):
        s = np.atleast_1d(np.asarray(s, dtype=float)) % self.length_mm
        k = np.clip(np.searchsorted(self._cum, s, side="right") - 1, 0, 3)
        return s, k

    def tangent_at(self, s) -> np.ndarray:
        _, k = self._edge(s)
        c = np.asarray(self.corners_mm, dtype=float)
        d = c[[1, 2, 3, 0]] - c
        return (d / np.linalg.norm(d, axis=1)[:, None])[k]

    def point_at(self, s) -> np.ndarray:
        s, k = self._edge(s)
        c = np.asarray(self.corners_mm, dtype=float)
        return c[k] + (s - self._cum[k])[:, None] * self.tangent_at(s)


@dataclass(frozen=True)
class Weaving:
    """A sine weave across the base line ``base``: ``amplitude_mm`` (half the stroke) along ``direction``."""

    base: Line
    direction: np.ndarray
    amplitude_mm: float
    frequency_Hz: float
    closed = False

    def __post_init__(self):
        if not (np.isfinite(self.amplitude_mm) and self.amplitude_mm > 0):
            raise ConfigError(f"weaving amplitude_mm must be > 0, got {self.amplitude_mm}")
        if not (np.isfinite(self.frequency_Hz) and self.frequency_Hz > 0):
            raise ConfigError(f"weaving frequency_Hz must be > 0, got {self.frequency_Hz}")
        t = self.base.tangent_at(0.0)[0]
        if abs(float(np.dot(self.direction, t))) > 1e-6:
            raise ConfigError("the weaving direction must be normal to its base line")

    @property
    def length_mm(self) -> float:
        return self.base.length_mm

    def point_at(self, s):
        return self.base.point_at(s)

    def tangent_at(self, s):
        return self.base.tangent_at(s)


@dataclass(frozen=True)
class Reorientation:
    """The point ``point_mm`` held while the angles (a, b, c) go from ``start_abc_deg`` to ``end_abc_deg``.

    Progress along it is the angle turned, measured along the straight line between the two angle sets
    (degrees; small turns, each angle unwrapped about the start).
    """

    point_mm: np.ndarray
    start_abc_deg: np.ndarray
    end_abc_deg: np.ndarray
    closed = False

    def __post_init__(self):
        _unit(self.turn_deg, "a reorientation from its start angles to its end angles")

    @property
    def turn_deg(self) -> np.ndarray:
        return (self.end_abc_deg - self.start_abc_deg + 180.0) % 360.0 - 180.0

    @property
    def length_mm(self) -> float:  # the "length" of its parameter: the turn, degrees
        return float(np.linalg.norm(self.turn_deg))

    def progress_deg(self, abc_deg) -> np.ndarray:
        d = (np.asarray(abc_deg, dtype=float) - self.start_abc_deg + 180.0) % 360.0 - 180.0
        return d @ (self.turn_deg / self.length_mm)

    def point_at(self, s):
        s = np.atleast_1d(np.asarray(s, dtype=float))
        return np.broadcast_to(self.point_mm, (s.size, 3)).copy()


@dataclass(frozen=True)
class PathSpec:
    """One path of a test: its name, its geometry and what was commanded along it."""

    name: str
    geometry: object
    velocity_mm_s: float | None = None
    planes: int = 50
    #: fraction of the length at either end left without planes (the accelerations)
    end_margin: float = 0.05
    #: part of the length (fractions) where the speed is taken as the commanded one (clause 8.5)
    velocity_window: tuple[float, float] = (0.25, 0.75)
    #: half-width of the tube around the path whose samples belong to it, mm
    tube_mm: float = 5.0
    #: the time span of the stream that belongs to this path (None: anywhere)
    window_s: tuple[float, float] | None = None

    @property
    def kind(self) -> str:
        return type(self.geometry).__name__.lower()

    def plane_s_mm(self) -> np.ndarray:
        """Arc lengths of the normal planes."""
        L = self.geometry.length_mm
        if getattr(self.geometry, "closed", False):
            return L * (np.arange(self.planes) + 0.5) / self.planes
        return np.linspace(self.end_margin * L, (1.0 - self.end_margin) * L, self.planes)
