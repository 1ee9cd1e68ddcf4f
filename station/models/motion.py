"""Motion profiles, joint and linear moves, and the per-axis servo response.

What a robot controller does between two targets, and how the joints follow.

Profiles
--------
A :class:`Profile` is a rest-to-rest motion over a distance ``L`` (a path
length in mm, or the normalised path parameter ``s`` from 0 to 1) made of
segments of constant jerk. Two kinds:

* ``"trapezoid"``: constant acceleration ``a_max``, cruise at ``v_max``,
  constant deceleration (the acceleration jumps; jerk is unbounded);
* ``"scurve"``: the jerk-limited double-S profile (seven segments:
  jerk ``+j, 0, -j`` / cruise / ``-j, 0, +j``), after Biagiotti & Melchiorri,
  *Trajectory Planning for Automatic Machines and Robots* (2008), sec. 3.4,
  rest-to-rest case. When ``v_max`` or ``a_max`` cannot be reached within
  ``L`` the phases shrink (triangular velocity, or no constant-acceleration
  phase).

Both end exactly at ``L`` with zero velocity (the last sample is set to the
target, not integrated to it).

Moves as piecewise cubics in time
---------------------------------
Every joint reference is a :class:`PiecewiseCubic`: segments of a cubic
polynomial in time per joint, ``r(tau) = c0 + c1 tau + c2 tau^2 + c3 tau^3``.

* **Joint moves** (:func:`plan_joint_move`): all six axes follow one profile
  of the normalised parameter ``s`` (``q = q0 + (q1 - q0) s``), so they start
  and finish together; the profile's limits are the tightest over the axes
  (``v_s = min_i v_i / |dq_i|`` and the same for acceleration and jerk), so
  no axis exceeds its own limit. Each profile segment is one cubic, exactly.
* **Linear moves** (:func:`plan_linear_move`): the TCP moves on a straight
  line at the path profile (mm, mm/s, mm/s^2) while the orientation turns
  uniformly (slerp) from the start to the target orientation (so it stays
  fixed when both are equal). Like a controller's interpolator, the path is
  sampled every ``ipo_period_s`` (default 20 ms), inverse kinematics
  (``kinematics.ik``, vectorised over all knots, seeded by joint-space
  interpolation) gives the joint angles at the knots, and a C2 cubic spline
  in time through them (zero velocity at both ends) is the joint reference.
  Between knots the TCP leaves the line by much less than a micrometre at
  industrial speeds (fourth order in the knot spacing; tests check the
  midpoints). If the resulting joint speeds or accelerations exceed the
  robot's limits, the whole move is slowed by time scaling (factor
  ``k >= max(v_ratio, sqrt(a_ratio))``), as a controller does near
  singularities; :attr:`LinearMovePlan.time_scale` reports it.

Servo response
--------------
Each axis follows its reference ``r(t)`` through a second-order position loop
with velocity feed-forward and no acceleration feed-forward. With the
tracking error ``e = q - r``::

    e'' + 2 zeta omega e' + omega^2 e = -r''                    (S1)

(``q'' + 2 zeta omega q' + omega^2 q = omega^2 r + 2 zeta omega r'``). While
accelerating the joint lags by about ``-r''/omega^2``; when the acceleration
stops the error rings out, so a stop can overshoot and settle (seed 000
sec. 3.2, Figs. 5-6). For a step of ``r''`` the error overshoots its new
steady value by the fraction ``exp(-pi zeta / sqrt(1 - zeta^2))``.

(S1) is solved **exactly** in closed form: on each cubic segment ``r''`` is
linear in time, so ``e`` is a linear particular solution plus the free
response of the damped oscillator (under-, critically or over-damped);
:func:`propagate_servo` carries the state ``(e, e')`` from knot to knot (a
loop over segments, never over samples) and :func:`evaluate_servo` evaluates
any number of sample times at once.

Units: rad, rad/s, rad/s^2, rad/s^3 for joints; mm, mm/s, mm/s^2, mm/s^3 for
paths; seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from station.errors import ConfigError, DataError
from station.numeric import finite_number

__all__ = [
    "PROFILE_KINDS",
    "Profile",
    "trapezoid_profile",
    "scurve_profile",
    "make_profile",
    "PiecewiseCubic",
    "hold",
    "trajectory_from_profile",
    "plan_joint_move",
    "JointMovePlan",
    "plan_linear_move",
    "LinearMovePlan",
    "stop_trajectory",
    "spline_trajectory",
    "UnreachableTarget",
    "ServoParams",
    "servo_step",
    "propagate_servo",
    "evaluate_servo",
]

#: profile kinds understood by :func:`make_profile`
PROFILE_KINDS = ("trapezoid", "scurve")

N_AXES = 6


class UnreachableTarget(DataError):
    """A linear move's target or path cannot be reached inside the joint limits."""


# --------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------
def _fraction(value, name: str) -> float:
    v = finite_number(value, name, positive=True, error=DataError)
    if v > 1.0:
        raise DataError(f"`{name}` must be in (0, 1] (a fraction of the rated value), got {value!r}")
    return v


def _axis_vector(x, name: str, error=DataError, positive: bool = False) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise error(f"`{name}` must be a numeric array of 6 values: {exc}") from exc
    if arr.shape != (N_AXES,):
        raise error(f"`{name}` must have shape (6,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise error(f"`{name}` contains non-finite values: {arr.tolist()}")
    if positive and np.any(arr <= 0):
        j = int(np.nonzero(arr <= 0)[0][0])
        raise error(f"`{name}` must be > 0 for every axis; joint {j + 1} is {arr[j]!r}")
    return arr


def _times(t, name: str = "t") -> tuple[np.ndarray, bool]:
    arr = np.asarray(t, dtype=float)
    scalar = arr.ndim == 0
    arr = np.atleast_1d(arr)
    if arr.ndim != 1:
        raise DataError(f"`{name}` must be a scalar or a 1-D array of times, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"`{name}` contains non-finite times")
    return arr, scalar


# --------------------------------------------------------------------------
# 1-D profiles
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Profile:
    """A rest-to-rest motion over ``distance`` made of constant-jerk segments.

    Attributes
    ----------
    kind : str
        ``"trapezoid"`` or ``"scurve"``.
    distance : float
        Total travel (path units).
    t_knots : ndarray, shape (K + 1,)
        Segment boundaries, s; ``t_knots[0] == 0``.
    pos0, vel0, acc0, jerk : ndarray, shape (K,)
        Position, velocity and acceleration at each segment's start, and its
        constant jerk. The acceleration may jump between segments
        (trapezoid); position and velocity are continuous.
    """

    kind: str
    distance: float
    t_knots: np.ndarray
    pos0: np.ndarray
    vel0: np.ndarray
    acc0: np.ndarray
    jerk: np.ndarray

    @property
    def duration_s(self) -> float:
        """Time from start to rest, s."""
        return float(self.t_knots[-1])

    @property
    def n_segments(self) -> int:
        return int(self.pos0.size)

    def evaluate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration at times ``t`` (s from the start).

        Parameters
        ----------
        t : array_like, shape (N,)
            Times; before 0 the profile is at rest at 0, after the end at rest
            at ``distance`` (exactly).

        Returns
        -------
        s, v, a : ndarray, shape (N,)
        """
        tt, scalar = _times(t)
        out_s = np.zeros_like(tt)
        out_v = np.zeros_like(tt)
        out_a = np.zeros_like(tt)
        if self.n_segments:
            inside = (tt > 0) & (tt < self.duration_s)
            ti = tt[inside]
            k = np.clip(np.searchsorted(self.t_knots, ti, side="right") - 1, 0, self.n_segments - 1)
            tau = ti - self.t_knots[k]
            j, a0, v0, s0 = self.jerk[k], self.acc0[k], self.vel0[k], self.pos0[k]
            out_a[inside] = a0 + j * tau
            out_v[inside] = v0 + tau * (a0 + 0.5 * j * tau)
            out_s[inside] = s0 + tau * (v0 + tau * (0.5 * a0 + j * tau / 6.0))
        out_s[tt >= self.duration_s] = self.distance
        if scalar:
            return float(out_s[0]), float(out_v[0]), float(out_a[0])  # type: ignore[return-value]
        return out_s, out_v, out_a

    def time_scaled(self, factor: float) -> "Profile":
        """The same path ``factor`` times slower (velocities / k, accelerations / k^2)."""
        k = finite_number(factor, "factor", positive=True, error=DataError)
        return Profile(
            kind=self.kind,
            distance=self.distance,
            t_knots=self.t_knots * k,
            pos0=self.pos0.copy(),
            vel0=self.vel0 / k,
            acc0=self.acc0 / k**2,
            jerk=self.jerk / k**3,
        )

    @property
    def peak_velocity(self) -> float:
        """Largest velocity reached (analytic, at segment boundaries)."""
        if not self.n_segments:
            return 0.0
        return float(np.max(np.abs(self.vel0)))

    @property
    def peak_acceleration(self) -> float:
        """Largest |acceleration| (the profile's acceleration is piecewise linear)."""
        if not self.n_segments:
            return 0.0
        dt = np.diff(self.t_knots)
        a_end = self.acc0 + self.jerk * dt
        return float(max(np.max(np.abs(self.acc0)), np.max(np.abs(a_end))))


def _build_profile(kind: str, distance: float, durations, acc_start, jerks) -> Profile:
    """Integrate segment durations / start accelerations / jerks into a Profile."""
    d = np.asarray(durations, dtype=float)
    a = np.asarray(acc_start, dtype=float)
    j = np.asarray(jerks, dtype=float)
    keep = d > 0
    d, a, j = d[keep], a[keep], j[keep]
    k = d.size
    pos0 = np.zeros(k)
    vel0 = np.zeros(k)
    s = v = 0.0
    for i in range(k):  # at most 7 segments
        pos0[i], vel0[i] = s, v
        tau = d[i]
        s = s + tau * (v + tau * (0.5 * a[i] + j[i] * tau / 6.0))
        v = v + tau * (a[i] + 0.5 * j[i] * tau)
    t_knots = np.concatenate([[0.0], np.cumsum(d)])
    return Profile(kind=kind, distance=float(distance), t_knots=t_knots, pos0=pos0, vel0=vel0, acc0=a, jerk=j)


def trapezoid_profile(distance: float, v_max: float, a_max: float) -> Profile:
    """Trapezoidal (bang-coast-bang) rest-to-rest profile.

    Parameters
    ----------
    distance : float
        Travel >= 0 (path units).
    v_max, a_max : float
        Velocity and acceleration limits (> 0).

    Returns
    -------
    Profile
        Three segments (two when ``v_max`` is not reached: triangular
        velocity with peak ``sqrt(distance * a_max)``); none for zero distance.
    """
    L = float(distance)
    if not (math.isfinite(L) and L >= 0):
        raise DataError(f"`distance` must be finite and >= 0, got {distance!r}")
    v = finite_number(v_max, "v_max", positive=True, error=DataError)
    a = finite_number(a_max, "a_max", positive=True, error=DataError)
    if L == 0:
        return _build_profile("trapezoid", 0.0, [], [], [])
    ta = v / a
    if L >= v * ta:
        tv = L / v - ta
    else:
        ta = math.sqrt(L / a)
        tv = 0.0
    alim = a
    return _build_profile("trapezoid", L, [ta, tv, ta], [alim, 0.0, -alim], [0.0, 0.0, 0.0])


def scurve_profile(distance: float, v_max: float, a_max: float, j_max: float) -> Profile:
    """Jerk-limited double-S rest-to-rest profile (Biagiotti & Melchiorri 3.4).

    Parameters
    ----------
    distance : float
        Travel >= 0 (path units).
    v_max, a_max, j_max : float
        Velocity, acceleration and jerk limits (> 0).

    Returns
    -------
    Profile
        Up to seven segments; zero for zero distance. Three cases: both
        limits reached; ``v_max`` not reached (no cruise); neither ``v_max``
        nor ``a_max`` reached (``T_j = (L / 2 j)^(1/3)``).
    """
    L = float(distance)
    if not (math.isfinite(L) and L >= 0):
        raise DataError(f"`distance` must be finite and >= 0, got {distance!r}")
    v = finite_number(v_max, "v_max", positive=True, error=DataError)
    a = finite_number(a_max, "a_max", positive=True, error=DataError)
    j = finite_number(j_max, "j_max", positive=True, error=DataError)
    if L == 0:
        return _build_profile("scurve", 0.0, [], [], [])
    # acceleration phase reaching v_max
    if v * j >= a * a:
        tj = a / j
        ta = tj + v / a
    else:
        tj = math.sqrt(v / j)
        ta = 2.0 * tj
    tv = L / v - ta
    if tv < 0:
        tv = 0.0
        tj = a / j
        ta = (a * a / j + math.sqrt(a**4 / j**2 + 4.0 * L * a)) / (2.0 * a)
        if ta < 2.0 * tj:
            tj = (L / (2.0 * j)) ** (1.0 / 3.0)
            ta = 2.0 * tj
    t_const = max(ta - 2.0 * tj, 0.0)
    alim = j * tj
    durations = [tj, t_const, tj, tv, tj, t_const, tj]
    acc_start = [0.0, alim, alim, 0.0, 0.0, -alim, -alim]
    jerks = [j, 0.0, -j, 0.0, -j, 0.0, j]
    return _build_profile("scurve", L, durations, acc_start, jerks)


def make_profile(kind: str, distance: float, v_max: float, a_max: float, j_max: float | None = None) -> Profile:
    """Build a profile by kind name (``"trapezoid"`` or ``"scurve"``).

    ``j_max`` is required for ``"scurve"`` and ignored for ``"trapezoid"``.
    """
    if kind == "trapezoid":
        return trapezoid_profile(distance, v_max, a_max)
    if kind == "scurve":
        if j_max is None:
            raise DataError("`j_max` is required for an 'scurve' profile")
        return scurve_profile(distance, v_max, a_max, j_max)
    raise DataError(f"`profile` must be one of {PROFILE_KINDS}, got {kind!r}")


# --------------------------------------------------------------------------
# piecewise-cubic joint references
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class PiecewiseCubic:
    """Joint reference: a cubic polynomial in time per segment and axis.

    Attributes
    ----------
    t_knots : ndarray, shape (K + 1,)
        Segment boundaries in s, relative to the move's start (``t_knots[0] == 0``).
    coeffs : ndarray, shape (K, 4, 6)
        ``coeffs[k, p, i]`` multiplies ``tau^p`` (``tau`` = time since the
        segment's start) for axis ``i``.
    q_end : ndarray, shape (6,)
        Exact value after the last segment (the move's target).
    """

    t_knots: np.ndarray
    coeffs: np.ndarray
    q_end: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.t_knots[-1])

    @property
    def n_segments(self) -> int:
        return int(self.coeffs.shape[0])

    @property
    def q_start(self) -> np.ndarray:
        return self.coeffs[0, 0].copy() if self.n_segments else self.q_end.copy()

    def evaluate(self, t, deriv: int = 0) -> np.ndarray:
        """Reference (or its first/second derivative) at times ``t``.

        Parameters
        ----------
        t : array_like, shape (N,)
            Times relative to the move's start, s. Outside ``[0, duration]``
            the axes rest at the start or end.
        deriv : {0, 1, 2}

        Returns
        -------
        ndarray, shape (N, 6)
        """
        if deriv not in (0, 1, 2):
            raise DataError(f"`deriv` must be 0, 1 or 2, got {deriv!r}")
        tt, scalar = _times(t)
        out = np.zeros((tt.size, N_AXES))
        if deriv == 0:
            out[tt <= 0] = self.q_start
            out[tt >= self.duration_s] = self.q_end
        if self.n_segments:
            inside = (tt > 0) & (tt < self.duration_s)
            ti = tt[inside]
            k = np.clip(np.searchsorted(self.t_knots, ti, side="right") - 1, 0, self.n_segments - 1)
            out[inside] = _poly_eval(self.coeffs[k], ti - self.t_knots[k], deriv)
        return out[0] if scalar else out


def _poly_eval(c: np.ndarray, tau: np.ndarray, deriv: int) -> np.ndarray:
    """Evaluate cubic coefficient rows ``c`` (N, 4, 6) at ``tau`` (N,)."""
    tau = tau[:, None]
    if deriv == 0:
        return c[:, 0] + tau * (c[:, 1] + tau * (c[:, 2] + tau * c[:, 3]))
    if deriv == 1:
        return c[:, 1] + tau * (2.0 * c[:, 2] + 3.0 * tau * c[:, 3])
    return 2.0 * c[:, 2] + 6.0 * tau * c[:, 3]


def hold(q_rad, duration_s: float = 0.0) -> PiecewiseCubic:
    """A dwell: the reference rests at ``q_rad`` for ``duration_s``."""
    q = _axis_vector(q_rad, "q_rad")
    d = float(duration_s)
    if not (math.isfinite(d) and d >= 0):
        raise DataError(f"`duration_s` must be finite and >= 0, got {duration_s!r}")
    if d == 0:
        return PiecewiseCubic(np.zeros(1), np.zeros((0, 4, N_AXES)), q)
    c = np.zeros((1, 4, N_AXES))
    c[0, 0] = q
    return PiecewiseCubic(np.array([0.0, d]), c, q)


def trajectory_from_profile(profile: Profile, q_start, q_end) -> PiecewiseCubic:
    """``q(t) = q_start + (q_end - q_start) * s(t) / L`` as exact cubic segments.

    Parameters
    ----------
    profile : Profile
        Profile of the path parameter (any distance ``L > 0``; normalised).
    q_start, q_end : array_like, shape (6,)
    """
    q0 = _axis_vector(q_start, "q_start")
    q1 = _axis_vector(q_end, "q_end")
    if profile.n_segments == 0 or profile.distance == 0:
        return PiecewiseCubic(np.zeros(1), np.zeros((0, 4, N_AXES)), q1)
    dq = (q1 - q0) / profile.distance
    c = np.empty((profile.n_segments, 4, N_AXES))
    c[:, 0] = q0 + profile.pos0[:, None] * dq
    c[:, 1] = profile.vel0[:, None] * dq
    c[:, 2] = 0.5 * profile.acc0[:, None] * dq
    c[:, 3] = profile.jerk[:, None] * dq / 6.0
    return PiecewiseCubic(profile.t_knots.copy(), c, q1)


def spline_trajectory(t_knots: np.ndarray, q_knots: np.ndarray) -> PiecewiseCubic:
    """C2 cubic spline through ``(t_knots, q_knots)`` with zero end velocities.

    Parameters
    ----------
    t_knots : ndarray, shape (K + 1,)
        Increasing knot times, s.
    q_knots : ndarray, shape (K + 1, 6)
        Joint angles at the knots.

    Returns
    -------
    PiecewiseCubic
        Times relative to ``t_knots[0]``.
    """
    cs = CubicSpline(t_knots, q_knots, axis=0, bc_type="clamped")
    # cs.c: (4, K, 6), highest power first
    c = np.ascontiguousarray(cs.c[::-1].transpose(1, 0, 2))
    c[0, 0] = q_knots[0]
    return PiecewiseCubic(t_knots - t_knots[0], c, q_knots[-1].copy())


# --------------------------------------------------------------------------
# joint moves
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class JointMovePlan:
    """A synchronised joint move.

    Attributes
    ----------
    trajectory : PiecewiseCubic
        Joint reference (exact cubics of the profile).
    profile : Profile
        Profile of the normalised path parameter ``s`` in [0, 1].
    """

    trajectory: PiecewiseCubic
    profile: Profile

    @property
    def duration_s(self) -> float:
        return self.trajectory.duration_s


def plan_joint_move(
    q_start,
    q_end,
    joint_speed_limits_rad_s,
    joint_accel_limits_rad_s2,
    *,
    speed_frac: float = 1.0,
    accel_frac: float = 1.0,
    jerk_time_s: float = 0.1,
    profile: str = "scurve",
) -> JointMovePlan:
    """Synchronised point-to-point joint move (all axes finish together).

    Parameters
    ----------
    q_start, q_end : array_like, shape (6,)
        Joint angles, rad.
    joint_speed_limits_rad_s, joint_accel_limits_rad_s2 : array_like, shape (6,)
        Rated (100 %) limits per axis.
    speed_frac, accel_frac : float
        Fractions of the rated speed and acceleration, in (0, 1].
    jerk_time_s : float
        Jerk limit as the time to ramp up to the (scaled) acceleration limit:
        ``j_i = accel_frac * a_i / jerk_time_s`` (scurve only).
    profile : {"scurve", "trapezoid"}

    Returns
    -------
    JointMovePlan
        Every axis ``i`` moves ``dq_i * s(t)``, so its speed, acceleration
        and jerk stay within ``speed_frac * v_i``, ``accel_frac * a_i`` and
        ``j_i``; the limiting axis reaches its limit.
    """
    q0 = _axis_vector(q_start, "q_start")
    q1 = _axis_vector(q_end, "q_end")
    v_lim = _axis_vector(joint_speed_limits_rad_s, "joint_speed_limits_rad_s", positive=True)
    a_lim = _axis_vector(joint_accel_limits_rad_s2, "joint_accel_limits_rad_s2", positive=True)
    fv = _fraction(speed_frac, "speed_frac")
    fa = _fraction(accel_frac, "accel_frac")
    tj = finite_number(jerk_time_s, "jerk_time_s", positive=True, error=DataError)
    if profile not in PROFILE_KINDS:
        raise DataError(f"`profile` must be one of {PROFILE_KINDS}, got {profile!r}")
    dq = np.abs(q1 - q0)
    moving = dq > 0
    if not np.any(moving):
        prof = _build_profile(profile, 0.0, [], [], [])
        return JointMovePlan(PiecewiseCubic(np.zeros(1), np.zeros((0, 4, N_AXES)), q1), prof)
    v_s = float(np.min(fv * v_lim[moving] / dq[moving]))
    a_s = float(np.min(fa * a_lim[moving] / dq[moving]))
    j_s = float(np.min(fa * a_lim[moving] / tj / dq[moving]))
    prof = make_profile(profile, 1.0, v_s, a_s, j_s)
    return JointMovePlan(trajectory_from_profile(prof, q0, q1), prof)


# --------------------------------------------------------------------------
# linear moves
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class LinearMovePlan:
    """A straight-line TCP move, as a joint reference.

    Attributes
    ----------
    trajectory : PiecewiseCubic
        Cubic spline through the IK knots (joint reference).
    profile : Profile
        Path profile (mm) after time scaling.
    t_knots : ndarray, shape (K + 1,)
        Interpolation knots, s.
    s_knots : ndarray, shape (K + 1,)
        Normalised path parameter at the knots (0..1).
    q_knots : ndarray, shape (K + 1, 6)
        IK solutions at the knots (nominal model).
    time_scale : float
        Slow-down factor applied to respect joint limits (1 = none).
    ik_residual_mm : float
        Largest IK position residual over the knots.
    """

    trajectory: PiecewiseCubic
    profile: Profile
    t_knots: np.ndarray
    s_knots: np.ndarray
    q_knots: np.ndarray
    time_scale: float
    ik_residual_mm: float

    @property
    def duration_s(self) -> float:
        return self.trajectory.duration_s


def _as_pose(target, R_default: np.ndarray) -> np.ndarray:
    arr = np.asarray(target, dtype=float)
    if arr.shape == (3,):
        T = np.eye(4)
        T[:3, :3] = R_default
        T[:3, 3] = arr
    elif arr.shape == (4, 4):
        T = arr.copy()
    else:
        raise DataError(f"`target` must be a (4, 4) pose or a (3,) position in mm, got shape {arr.shape}")
    if not np.all(np.isfinite(T)):
        raise DataError("`target` contains non-finite values")
    return T


def plan_linear_move(
    dh,
    q_start,
    target,
    *,
    speed_mm_s: float,
    accel_mm_s2: float,
    joint_limits_rad,
    joint_speed_limits_rad_s,
    joint_accel_limits_rad_s2,
    jerk_time_s: float = 0.1,
    profile: str = "scurve",
    ipo_period_s: float = 0.02,
    orientation_radius_mm: float = 500.0,
    orientation_speed_rad_s: float | None = None,
    orientation_accel_rad_s2: float | None = None,
    ik_tol_mm: float = 1e-5,
) -> LinearMovePlan:
    """Straight-line TCP move from the pose at ``q_start`` to ``target``.

    Parameters
    ----------
    dh : array_like, shape (7, 5)
        The controller's kinematic model (normally ``robot.dh_nominal``).
    q_start : array_like, shape (6,)
        Joint angles at the start, rad.
    target : array_like, shape (4, 4) or (3,)
        Target TCP pose, or a position (mm) keeping the start orientation.
    speed_mm_s, accel_mm_s2 : float
        Path speed and acceleration (TCP, along the line).
    joint_limits_rad : array_like, shape (6, 2)
    joint_speed_limits_rad_s, joint_accel_limits_rad_s2 : array_like, shape (6,)
        The move is slowed down (time-scaled) until no axis exceeds them.
    jerk_time_s : float
        Path jerk limit ``accel_mm_s2 / jerk_time_s`` (scurve).
    profile : {"scurve", "trapezoid"}
    ipo_period_s : float
        Interpolation knot spacing before time scaling, s.
    orientation_radius_mm : float
        Without an orientation speed: the tool turns at ``speed_mm_s /
        orientation_radius_mm`` rad/s, accelerating at ``accel_mm_s2 /
        orientation_radius_mm`` rad/s^2.
    orientation_speed_rad_s, orientation_accel_rad_s2 : float, optional
        The programmed speed (and acceleration) of the tool's turn (RAPID
        ``speeddata``'s ``v_ori``, KRL ``$VEL.ORI1``). Without an
        acceleration the turn reaches its speed in the time the path
        reaches its own. The turn has its own profile (angle, rad/s,
        rad/s^2, the same jerk time) and the line its own; the slower of the
        two times the move and the other follows it in proportion, like a
        controller's. A move that only turns (the TCP held) is timed by its
        turn alone: the TCP stays put at every knot while the tool slerps.
    ik_tol_mm : float
        IK tolerance at the knots.

    Returns
    -------
    LinearMovePlan

    Raises
    ------
    DataError
        Bad arguments.
    UnreachableTarget
        A target (or a knot of the line) that IK cannot reach inside the
        joint limits (the knot's position is named), or a branch change.
    """
    from station.models import kinematics as kin

    dh = kin.validate_dh(dh)
    q0 = _axis_vector(q_start, "q_start")
    v = finite_number(speed_mm_s, "speed_mm_s", positive=True, error=DataError)
    a = finite_number(accel_mm_s2, "accel_mm_s2", positive=True, error=DataError)
    tj = finite_number(jerk_time_s, "jerk_time_s", positive=True, error=DataError)
    dt_ipo = finite_number(ipo_period_s, "ipo_period_s", positive=True, error=DataError)
    r_rot = finite_number(orientation_radius_mm, "orientation_radius_mm", positive=True, error=DataError)
    lim = kin.validate_joint_limits(joint_limits_rad)
    v_lim = _axis_vector(joint_speed_limits_rad_s, "joint_speed_limits_rad_s", positive=True)
    a_lim = _axis_vector(joint_accel_limits_rad_s2, "joint_accel_limits_rad_s2", positive=True)
    if profile not in PROFILE_KINDS:
        raise DataError(f"`profile` must be one of {PROFILE_KINDS}, got {profile!r}")

    T0 = kin.fk(dh, q0)
    T1 = _as_pose(target, T0[:3, :3])
    p0, p1 = T0[:3, 3], T1[:3, 3]
    rots = Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]]))
    angle = float((rots[1] * rots[0].inv()).magnitude())
    w = v / r_rot if orientation_speed_rad_s is None else finite_number(
        orientation_speed_rad_s, "orientation_speed_rad_s", positive=True, error=DataError)
    alpha = a * w / v if orientation_accel_rad_s2 is None else finite_number(
        orientation_accel_rad_s2, "orientation_accel_rad_s2", positive=True, error=DataError)
    dist = float(np.linalg.norm(p1 - p0))
    length = max(dist, angle)  # 0 only when the move neither moves nor turns

    # the end pose first, seeded from the start, to stay on its branch
    end = kin.ik(dh, T1[None], q0[None], lim, tol_mm=ik_tol_mm)
    if not end.all_success:
        raise UnreachableTarget(
            f"linear move target {np.round(p1, 3).tolist()} mm is not reachable inside the joint limits "
            f"(IK residual {float(end.residual_mm[0]):.3g} mm)"
        )
    q1 = end.q_rad[0]
    if length == 0.0:
        prof = _build_profile(profile, 0.0, [], [], [])
        traj = PiecewiseCubic(np.zeros(1), np.zeros((0, 4, N_AXES)), q1)
        return LinearMovePlan(traj, prof, np.zeros(1), np.ones(1), q1[None].copy(), 1.0, float(end.residual_mm[0]))

    # the line's profile (mm) and the turn's (rad): the slower one times the move
    profs = [(make_profile(profile, d, vv, aa, aa / tj), d) for d, vv, aa in ((dist, v, a), (angle, w, alpha)) if d > 0]
    prof, length = max(profs, key=lambda pr: pr[0].duration_s)
    n_k = max(int(math.ceil(prof.duration_s / dt_ipo)), 2)
    t_k = np.linspace(0.0, prof.duration_s, n_k + 1)
    s_k = prof.evaluate(t_k)[0] / length
    s_k[0], s_k[-1] = 0.0, 1.0
    slerp = Slerp([0.0, 1.0], rots)
    poses = np.zeros((t_k.size, 4, 4))
    poses[:, :3, :3] = slerp(s_k).as_matrix()
    poses[:, :3, 3] = p0 + s_k[:, None] * (p1 - p0)
    poses[:, 3, 3] = 1.0
    seed_q = q0 + s_k[:, None] * (q1 - q0)
    sol = kin.ik(dh, poses[1:-1], seed_q[1:-1], lim, tol_mm=ik_tol_mm, n_restarts=0)
    q_k = np.concatenate([q0[None], sol.q_rad, q1[None]])
    residual = float(max(np.max(sol.residual_mm, initial=0.0), end.residual_mm[0]))
    if not sol.all_success:
        bad = int(np.nonzero(~sol.success)[0][0]) + 1
        raise UnreachableTarget(
            f"linear move leaves the reachable space at {np.round(poses[bad, :3, 3], 3).tolist()} mm "
            f"(knot {bad} of {t_k.size - 1}, IK residual {float(sol.residual_mm[bad - 1]):.3g} mm)"
        )
    jumps = np.max(np.abs(np.diff(q_k, axis=0)), axis=0)
    if np.any(jumps > 0.5):
        j = int(np.argmax(jumps))
        raise UnreachableTarget(
            f"linear move crosses a singularity or a branch change: joint {j + 1} jumps "
            f"{math.degrees(float(jumps[j])):.1f} deg between two interpolation knots"
        )

    traj = spline_trajectory(t_k, q_k)
    # time scaling to respect the joint limits (checked on a 4x finer grid)
    t_chk = np.linspace(0.0, traj.duration_s, 4 * n_k + 1)
    v_ratio = float(np.max(np.abs(traj.evaluate(t_chk, 1)) / v_lim))
    a_ratio = float(np.max(np.abs(traj.evaluate(t_chk, 2)) / a_lim))
    k = max(1.0, v_ratio, math.sqrt(a_ratio))
    if k > 1.0:
        k *= 1.0 + 1e-9
        t_k = t_k * k
        prof = prof.time_scaled(k)
        traj = spline_trajectory(t_k, q_k)
    return LinearMovePlan(traj, prof, t_k, s_k, q_k, k, residual)


def stop_trajectory(q_rad, qd_rad_s, joint_accel_limits_rad_s2, decel_frac: float = 1.0) -> PiecewiseCubic:
    """Protective stop: every axis decelerates uniformly to rest, all at once.

    The joint velocity vector keeps its direction and shrinks linearly to zero
    over ``T = max_i |qd_i| / (decel_frac * a_i)``, so no axis exceeds its
    deceleration limit (a stop category 2 ramp; the TCP path deviates
    slightly from a straight line during linear moves).

    Parameters
    ----------
    q_rad, qd_rad_s : array_like, shape (6,)
        Reference position and velocity at the moment of the stop.
    joint_accel_limits_rad_s2 : array_like, shape (6,)
    decel_frac : float
        Fraction of the acceleration limits used to stop, in (0, 1].

    Returns
    -------
    PiecewiseCubic
        One segment (none if already at rest).
    """
    q = _axis_vector(q_rad, "q_rad")
    qd = _axis_vector(qd_rad_s, "qd_rad_s")
    a_lim = _axis_vector(joint_accel_limits_rad_s2, "joint_accel_limits_rad_s2", positive=True)
    f = _fraction(decel_frac, "decel_frac")
    T = float(np.max(np.abs(qd) / (f * a_lim)))
    if T <= 0:
        return PiecewiseCubic(np.zeros(1), np.zeros((0, 4, N_AXES)), q)
    c = np.zeros((1, 4, N_AXES))
    c[0, 0] = q
    c[0, 1] = qd
    c[0, 2] = -qd / (2.0 * T)
    return PiecewiseCubic(np.array([0.0, T]), c, q + 0.5 * qd * T)


# --------------------------------------------------------------------------
# servo
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class ServoParams:
    """Per-axis position-loop dynamics of equation (S1).

    Attributes
    ----------
    omega_rad_s : ndarray, shape (6,)
        Natural frequency of each axis' closed loop, rad/s (> 0).
    zeta : ndarray, shape (6,)
        Damping ratio (> 0; < 1 rings and overshoots).
    """

    omega_rad_s: np.ndarray
    zeta: np.ndarray

    def __post_init__(self) -> None:
        w = _axis_vector(self.omega_rad_s, "omega_rad_s", ConfigError, positive=True)
        z = _axis_vector(self.zeta, "zeta", ConfigError, positive=True)
        object.__setattr__(self, "omega_rad_s", w)
        object.__setattr__(self, "zeta", z)

    @classmethod
    def uniform(cls, omega_rad_s: float, zeta: float) -> "ServoParams":
        """The same loop on every axis."""
        return cls(np.full(N_AXES, float(omega_rad_s)), np.full(N_AXES, float(zeta)))

    def overshoot_fraction(self) -> np.ndarray:
        """``exp(-pi zeta / sqrt(1 - zeta^2))`` per axis (0 when zeta >= 1)."""
        z = np.minimum(self.zeta, 1.0 - 1e-12)
        out = np.exp(-np.pi * z / np.sqrt(1.0 - z * z))
        return np.where(self.zeta >= 1.0, 0.0, out)

    def to_dict(self) -> dict:
        return {"omega_rad_s": self.omega_rad_s.tolist(), "zeta": self.zeta.tolist()}


def _free_response(h0, hd0, tau, omega, zeta):
    """Free response of ``h'' + 2 zeta omega h' + omega^2 h = 0``.

    ``h0, hd0, tau`` broadcast to (N, 6); ``omega, zeta`` are (6,). Handles
    under-, critically and over-damped axes without overflow.
    """
    sigma = zeta * omega
    big_omega = omega * omega * (1.0 - zeta * zeta)  # signed omega_d^2
    tol = 1e-12 * omega * omega
    under = big_omega > tol
    over = big_omega < -tol
    wd = np.sqrt(np.where(under, big_omega, 1.0))
    kk = np.sqrt(np.where(over, -big_omega, 1.0))
    env = np.exp(-sigma * tau)
    # under-damped: e^{-sigma t} cos, e^{-sigma t} sin / wd
    c_u = env * np.cos(wd * tau)
    s_u = env * np.sin(wd * tau) / wd
    # over-damped: e^{-sigma t} cosh(k t), e^{-sigma t} sinh(k t) / k, stably
    ep = np.exp((kk - sigma) * tau)
    em = np.exp(-(kk + sigma) * tau)
    c_o = 0.5 * (ep + em)
    s_o = 0.5 * (ep - em) / kk
    # critically damped
    c_c = env
    s_c = env * tau
    C = np.where(under, c_u, np.where(over, c_o, c_c))
    S = np.where(under, s_u, np.where(over, s_o, s_c))
    h = h0 * C + (hd0 + sigma * h0) * S
    hd = hd0 * C - (omega * omega * h0 + sigma * hd0) * S
    return h, hd


def servo_step(e0, ed0, u0, u1, tau, servo: ServoParams):
    """Exact solution of (S1) over a segment where ``-r'' = u0 + u1 tau``.

    Parameters
    ----------
    e0, ed0 : array_like, shape (N, 6) or (6,)
        Error and its rate at the segment start (rad, rad/s).
    u0, u1 : array_like, shape (N, 6) or (6,)
        Forcing ``-r''`` at the start and its slope (rad/s^2, rad/s^3).
    tau : array_like, shape (N,) or scalar
        Time since the segment start, s (>= 0).
    servo : ServoParams

    Returns
    -------
    e, ed : ndarray, shape (N, 6)
        Error and error rate at ``tau``.
    """
    w = servo.omega_rad_s
    z = servo.zeta
    tau = np.asarray(tau, dtype=float)
    if tau.ndim == 1:
        tau = tau[:, None]
    c1 = np.asarray(u1) / (w * w)
    c0 = (np.asarray(u0) - 2.0 * z * w * c1) / (w * w)
    h, hd = _free_response(np.asarray(e0) - c0, np.asarray(ed0) - c1, tau, w, z)
    return h + c0 + c1 * tau, hd + c1


def propagate_servo(traj: PiecewiseCubic, e0, ed0, servo: ServoParams) -> tuple[np.ndarray, np.ndarray]:
    """Servo error state at every knot of ``traj``, starting from ``(e0, ed0)``.

    Parameters
    ----------
    traj : PiecewiseCubic
    e0, ed0 : array_like, shape (6,)
        Error state at ``traj``'s start.
    servo : ServoParams

    Returns
    -------
    E, Ed : ndarray, shape (K + 1, 6)
        Error and rate at each knot (row ``k`` = start of segment ``k``;
        the last row is the state at the end of the move).
    """
    K = traj.n_segments
    E = np.empty((K + 1, N_AXES))
    Ed = np.empty((K + 1, N_AXES))
    E[0] = e0
    Ed[0] = ed0
    dt = np.diff(traj.t_knots)
    for k in range(K):  # one step per segment, never per sample
        u0 = -2.0 * traj.coeffs[k, 2]
        u1 = -6.0 * traj.coeffs[k, 3]
        e, ed = servo_step(E[k][None], Ed[k][None], u0[None], u1[None], np.array([dt[k]]), servo)
        E[k + 1], Ed[k + 1] = e[0], ed[0]
    return E, Ed


def evaluate_servo(traj: PiecewiseCubic, E, Ed, t, servo: ServoParams) -> tuple[np.ndarray, np.ndarray]:
    """Actual joint angles and rates ``q = r + e`` at times ``t`` (vectorised).

    Parameters
    ----------
    traj : PiecewiseCubic
    E, Ed : ndarray, shape (K + 1, 6)
        From :func:`propagate_servo`.
    t : array_like, shape (N,)
        Times relative to the move's start (>= 0). After the end the
        reference rests and the error rings out freely.
    servo : ServoParams

    Returns
    -------
    q, qd : ndarray, shape (N, 6)
    """
    tt, _ = _times(t)
    if np.any(tt < 0):
        raise DataError("`t` must be >= 0 (relative to the move's start)")
    K = traj.n_segments
    k = np.searchsorted(traj.t_knots, tt, side="right") - 1
    k = np.clip(k, 0, K)
    tau = tt - traj.t_knots[k]
    coeffs = np.concatenate([traj.coeffs, np.zeros((1, 4, N_AXES))])
    coeffs[K, 0] = traj.q_end
    c = coeffs[k]
    e, ed = servo_step(E[k], Ed[k], -2.0 * c[:, 2], -6.0 * c[:, 3], tau, servo)
    return _poly_eval(c, tau, 0) + e, _poly_eval(c, tau, 1) + ed
