"""A weaving pattern (ISO 9283 clause 11) as blended linear moves: the polyline whose rounded path weaves a sine.

Clause 11 asks for the weaving stroke error WS and frequency error WF of a
robot weaving across a straight base path with a commanded amplitude (half
the stroke) and frequency. Amplitude, frequency and the speed along the base
are parameters here; the defaults of
:func:`station.programs.path_builders.iso_path_tests` are the station's choice,
not values taken from the standard.
The analysis (:mod:`station.analysis.path.weaving`) fits a sine of free
amplitude and frequency to each cycle's displacement across the base line in
time, so the commanded pattern is that sine's amplitude ``A_c`` and frequency
``F_c``.

A controller without a weaving function (a plain RAPID, KRL or URScript
programme) weaves through corner-zoned linear moves. Along the base at ``x``
and across it at ``y``, a period ``lambda = v_base / F_c`` long:

* ``N`` vertices a period (a multiple of 4: the zero crossings and the peaks
  are vertices), vertex ``k`` at ``x = k lambda / N``,
  ``y = P sin(2 pi k / N)`` (rounded to the micrometre the texts carry);
* each vertex has the corner zone ``z_k`` = :data:`ZONE_SHARE` of the shorter
  of its two segments: the interpolator rounds it by the quadratic Bezier from
  ``z_k`` before the vertex to ``z_k`` after it (the vertex its control
  point), and every segment keeps a straight middle (no controller shrinks a
  zone of a third of its segment or less; a UR refuses overlapping blends);
  where the two segments are collinear (the zero crossings of ``N = 4``) there
  is nothing to round;
* every move has the same path speed ``v = S F_c``, ``S`` the length of one
  period of the rounded path: at cruise a period takes ``1 / F_c``;
* ``P`` is solved (Brent) so that the fundamental of the rounded path's
  displacement across the base, traversed at the constant path speed, has
  amplitude ``A_c``: ``sqrt(a1^2 + b1^2)`` with
  ``b1 = (2 / S) int_0^S y(s) sin(2 pi s / S) ds`` (and ``a1`` with the
  cosine), ``s`` the arc length. ``P`` comes out 5-45 % above ``A_c``: the
  corners cut the crests, the straight flanks and the constant path speed
  (slow across the base where the path is steep) make the wave squarer.

The lateral acceleration in the rounded corners, ``v^2 kappa`` with a Bezier's
curvature ``kappa = |B' x B''| / |B'|^3``, must stay under the path
acceleration the interpolator may use, or it would slow there and the
frequency would no longer be the commanded one: :func:`design_weave` refuses
such a pattern by name. The path speed is constant, not the base speed: a
steep weave (much amplitude over a short wavelength) needs the path speed of
its flanks on its crests too, and is refused sooner than a weaving function
that keeps the base speed would be. Lengths mm, times s, frequencies Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from station.errors import ConfigError

__all__ = ["WeaveDesign", "design_weave", "rounded_period"]

#: a vertex's zone is this share of the shorter of its two segments (a third at most: a segment keeps a
#: straight middle however its two ends are rounded, and no controller shrinks the zone)
ZONE_SHARE = 0.32
#: the crests' lateral acceleration may use at most this share of the path acceleration
ACCEL_SHARE = 0.8
#: samples of each rounded corner and of each straight piece when a period is integrated
N_SAMPLES = 400


@dataclass(frozen=True)
class WeaveDesign:
    """The polyline that weaves ``amplitude_mm`` at ``frequency_Hz`` along a base at ``base_speed_mm_s``.

    ``offsets_mm`` (N,): the targets' offsets across the base at the N vertices of a period (the first at a
    zero crossing, rising), each ``wavelength_mm / N`` further along; ``zones_mm`` (N,): their corner zones;
    ``path_speed_mm_s``: every move's programmed speed; ``crest_accel_mm_s2``: the largest lateral
    acceleration on the rounded corners at that speed; ``peak_mm``: the vertices' largest offset.
    """

    amplitude_mm: float
    frequency_Hz: float
    base_speed_mm_s: float
    points_per_period: int
    peak_mm: float
    offsets_mm: tuple
    zones_mm: tuple
    path_speed_mm_s: float
    wavelength_mm: float
    crest_accel_mm_s2: float


def _vertices(wavelength_mm: float, peak_mm: float, n: int) -> np.ndarray:
    """(n + 1, 2): the vertices of one period, along and across the base (the last is the next period's first)."""
    k = np.arange(n + 1)
    y = np.round(peak_mm * np.sin(2 * np.pi * k / n), 3)
    y[np.abs(y) < 5e-4] = 0.0
    return np.column_stack([k * wavelength_mm / n, y])


def _zones(v: np.ndarray) -> np.ndarray:
    """Zone of each vertex of a period (periodic: vertex 0's neighbours are the previous period's last)."""
    seg = np.linalg.norm(np.diff(v, axis=0), axis=1)  # seg[k]: from vertex k to k + 1
    shorter = np.minimum(seg, np.roll(seg, 1))  # vertex k between seg[k - 1] and seg[k]
    return np.floor(ZONE_SHARE * shorter * 1000.0) / 1000.0  # the micrometre the programme texts carry


def rounded_period(wavelength_mm: float, peak_mm: float, n: int):
    """One period of the rounded polyline (the interpolator's path at cruise), by arc length.

    Returns ``(s, x, y, kappa_max, zones)``: arc lengths from the period's first vertex (mm), the points along
    and across the base, the largest curvature of its rounded corners (1/mm) and the vertices' zones (mm).
    Each vertex ``V`` with zone ``z`` between directions ``u_in``, ``u_out`` is rounded by the quadratic Bezier
    from ``V - z u_in`` to ``V + z u_out`` controlled by ``V`` (curvature ``|B' x B''| / |B'|^3``)."""
    v = _vertices(wavelength_mm, peak_mm, n)
    z = _zones(v)
    d = np.diff(v, axis=0)
    u = d / np.linalg.norm(d, axis=1)[:, None]
    t = np.linspace(0.0, 1.0, N_SAMPLES)[:, None]
    pieces, kappa = [], 0.0
    for k in range(n + 1):  # loop over the vertices (the last closes the period: half its corner)
        u_in, u_out = u[k - 1] if k > 0 else u[n - 1], u[k] if k < n else u[0]
        zk = z[k % n]
        A, C, B = v[k] - zk * u_in, v[k], v[k] + zk * u_out
        bez = (1 - t) ** 2 * A + 2 * t * (1 - t) * C + t ** 2 * B
        d1 = 2 * (1 - t) * (C - A) + 2 * t * (B - C)
        d2 = 2.0 * (A - 2 * C + B)
        cross = np.abs(d1[:, 0] * d2[1] - d1[:, 1] * d2[0])
        kappa = max(kappa, float(np.max(cross / np.linalg.norm(d1, axis=1) ** 3)))
        if k == 0:
            pieces.append(bez[N_SAMPLES // 2:])  # the period starts at its first vertex's apex
        elif k == n:
            pieces.append(bez[:N_SAMPLES // 2 + 1])
        else:
            pieces.append(bez)
        if k < n:  # the straight middle of the segment to the next vertex
            a, b = v[k] + zk * u[k], v[k + 1] - z[(k + 1) % n] * u[k]
            pieces.append(a + t * (b - a))
    pts = np.concatenate(pieces)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return s, pts[:, 0], pts[:, 1], kappa, z


def _fundamental(wavelength_mm: float, peak_mm: float, n: int) -> tuple[float, float, float]:
    """``(fundamental amplitude, period length S, largest curvature)`` of the rounded polyline at constant
    speed: ``b1 = (2 / S) int_0^S y(s) sin(2 pi s / S) ds`` (the wave is odd about its first vertex's apex,
    which is not exactly on the base: its cosine term ``a1`` counts in the amplitude too)."""
    s, _, y, kappa, _ = rounded_period(wavelength_mm, peak_mm, n)
    S = float(s[-1])
    w = np.diff(s)
    integ = lambda f: float(np.sum(0.5 * (f[1:] + f[:-1]) * w))  # noqa: E731
    b1 = 2.0 / S * integ(y * np.sin(2 * np.pi * s / S))
    a1 = 2.0 / S * integ(y * np.cos(2 * np.pi * s / S))
    return math.hypot(a1, b1), S, kappa


def design_weave(amplitude_mm: float, frequency_Hz: float, base_speed_mm_s: float, *,
                 path_accel_mm_s2: float, points_per_period: int = 8) -> WeaveDesign:
    """The polyline whose rounded path weaves ``amplitude_mm`` at ``frequency_Hz`` (see the module's text).

    ConfigError naming the parameters when the corners would need more lateral acceleration than
    ``ACCEL_SHARE`` x ``path_accel_mm_s2``."""
    A, F, vb = float(amplitude_mm), float(frequency_Hz), float(base_speed_mm_s)
    for name, val in (("weave_amplitude_mm", A), ("weave_frequency_Hz", F), ("weave_speed_mm_s", vb)):
        if not (math.isfinite(val) and val > 0):
            raise ConfigError(f"{name} must be a finite number > 0, got {val!r}")
    n = points_per_period
    if not (isinstance(n, int) and n >= 4 and n % 4 == 0 and n <= 64):
        raise ConfigError(f"weave_points_per_period must be a multiple of 4 from 4 to 64, got {n!r}")
    lam = vb / F
    P = brentq(lambda p: _fundamental(lam, p, n)[0] - A, 0.5 * A, 3.0 * A, xtol=1e-6 * A)
    P = round(P, 3)
    _, S, kappa = _fundamental(lam, P, n)
    v = S * F
    accel = v * v * kappa
    if accel > ACCEL_SHARE * path_accel_mm_s2:
        raise ConfigError(
            f"a weave of weave_amplitude_mm {A:g} at weave_frequency_Hz {F:g} along weave_speed_mm_s {vb:g} needs "
            f"{accel:.0f} mm/s^2 across its corners, more than {ACCEL_SHARE:.0%} of the path acceleration "
            f"{path_accel_mm_s2:.0f} mm/s^2: weave slower, wider apart or narrower")
    verts = _vertices(lam, P, n)
    return WeaveDesign(A, F, vb, n, P, tuple(float(y) for y in verts[:n, 1]), tuple(float(z) for z in _zones(verts)),
                       v, lam, accel)
