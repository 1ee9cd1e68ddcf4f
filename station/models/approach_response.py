"""The end of a move along its travel, in closed form: the command, a second-order loop, a creep, a mode.

Shared by the motion diagnosis (:mod:`station.analysis.motion`), which fits
these curves to a measured approach, and by :mod:`station.models.motion_effects`,
which adds the fitted effects to a simulated approach. Pure functions of
arrays; time ``tau`` is measured from the end of the command (``tau = t -
T_c``), positions along the travel in mm with the target at 0 (negative:
short of it).

* The command ends on a deceleration ``a`` (mm/s^2, > 0) that falls
  linearly to zero over ``tj`` s (a jerk-limited end, jerk ``a / tj``;
  ``tj = 0`` is the trapezoid's abrupt end): :func:`command_position`.
* A second-order system ``y'' + 2 zeta omega y' + omega^2 y = omega^2 u``
  with ``u`` the deceleration level (1 before the ramp, 0 after) responds
  as :func:`ramp_response`: 1 before, a (possibly ringing) decay to 0 after.
  A position loop's error follows it with the gain ``a / omega^2``
  (the error equation ``e'' + 2 zeta omega e' + omega^2 e = -r''``); a
  structural mode driven by the deceleration with a gain per unit
  deceleration ``G`` (s^2).
* A creep: the arm stands short by ``A`` while it moves and creeps in after
  the command's end as ``exp(-tau / tau_c)``: :func:`creep`.
"""

from __future__ import annotations

import functools
import math

import numpy as np

__all__ = ["free_decay", "ramp_response", "decel_response", "command_position", "creep", "servo_position",
           "mode_response"]

#: a jerk time below this is a step (its ramp's effect is below 1e-4 of the deceleration's lag), s
STEP_TJ_S = 1e-5
#: damping ratios within this of 1 are moved off it (the closed form divides by the roots' difference)
_CRITICAL_EPS = 1e-6


def _decay_after(tp: np.ndarray, omega: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """``g`` and ``g'`` at ``tp >= 0`` (real arithmetic: ringing below critical damping, two exponentials above)."""
    z = float(zeta)
    if abs(z - 1.0) < _CRITICAL_EPS:
        z = 1.0 + _CRITICAL_EPS
    if z < 1.0:
        wd = omega * np.sqrt(1.0 - z * z)
        e = np.exp(-z * omega * tp)
        c, s = np.cos(wd * tp), np.sin(wd * tp)
        return e * (c + z * omega / wd * s), -(omega * omega / wd) * e * s
    r = omega * np.sqrt(z * z - 1.0)
    l1, l2 = -z * omega + r, -z * omega - r
    e1, e2 = np.exp(l1 * tp), np.exp(l2 * tp)
    return (l2 * e1 - l1 * e2) / (l2 - l1), l1 * l2 * (e1 - e2) / (l2 - l1)


def free_decay(tau, omega: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """``(g, G)``: the free decay ``g`` from ``g(0) = 1, g'(0) = 0`` (``g = 1`` for ``tau < 0``) and its
    integral ``G`` from 0 (``G = tau`` for ``tau < 0``), from ``g' + 2 zeta omega g + omega^2 G = 2 zeta omega``."""
    tau = np.asarray(tau, dtype=float)
    g = np.ones_like(tau)
    G = tau.copy()
    after = tau >= 0.0
    if after.any():
        ga, gd = _decay_after(tau[after], omega, zeta)
        zw = 2.0 * float(zeta) * omega
        g[after] = ga
        G[after] = (zw - gd - zw * ga) / omega ** 2
    return g, G


def ramp_response(tau, omega: float, zeta: float, tj: float) -> np.ndarray:
    """The response to an input falling linearly from 1 to 0 over ``[-tj, 0]`` (a step at 0 when ``tj = 0``)."""
    if tj <= STEP_TJ_S:
        return free_decay(tau, omega, zeta)[0]
    _, G1 = free_decay(np.asarray(tau, dtype=float) + tj, omega, zeta)
    _, G0 = free_decay(tau, omega, zeta)
    return (G1 - G0) / tj


def _mode_poles(omega_s: float, zeta_s: float, omega_m: float, zeta_m: float):
    """Poles and residues of a mode (``omega_m``, ``zeta_m``, unit static gain) driven by the acceleration of a
    loop (``omega_s``, ``zeta_s``) that follows its command: ``Hm(p) Hs(p)``, both of unit static gain
    (the same four numbers recur in every evaluation of a fit's step: kept, read-only)."""
    return _mode_poles_cached(float(omega_s), float(zeta_s), float(omega_m), float(zeta_m))


@functools.lru_cache(maxsize=256)
def _mode_poles_cached(omega_s: float, zeta_s: float, omega_m: float, zeta_m: float):
    if abs(zeta_s - 1.0) < _CRITICAL_EPS:  # a critically damped loop's double pole: the residues need it split
        zeta_s = 1.0 + _CRITICAL_EPS
    if abs(zeta_m - 1.0) < _CRITICAL_EPS:
        zeta_m = 1.0 + _CRITICAL_EPS
    if abs(omega_s - omega_m) < 1e-6 * omega_m and abs(zeta_s - zeta_m) < 1e-6:
        omega_m *= 1.0 + 1e-5  # coincident poles: the closed form needs them distinct
    num = np.polymul([omega_m ** 2], [2.0 * zeta_s * omega_s, omega_s ** 2])
    den = np.polymul([1.0, 2.0 * zeta_s * omega_s, omega_s ** 2], [1.0, 2.0 * zeta_m * omega_m, omega_m ** 2])
    p = np.roots(den).astype(complex)
    R = np.polyval(num, p) / np.polyval(np.polyder(den), p)
    # a conjugate pair's terms are each other's conjugates: one of each, doubled, with the real poles once
    keep = p.imag >= 0.0
    poles, residues = p[keep], np.where(p[keep].imag > 0.0, 2.0, 1.0) * R[keep]
    poles.flags.writeable = residues.flags.writeable = False
    return poles, residues


def _pr_decay(tau, p, R) -> np.ndarray:
    """The free decay ``g = -sum R e^(p tau) / p`` after a unit step down at 0 (1 before it)."""
    tau = np.asarray(tau, dtype=float)
    g = np.ones_like(tau)
    after = tau >= 0.0
    if after.any():
        ta = tau[after]
        g[after] = -sum((Ri * np.exp(pi * ta) / pi).real for pi, Ri in zip(p, R))
    return g


def _pr_integral(tau, p, R) -> np.ndarray:
    """``G``: the integral from 0 of the free decay ``g = -sum R e^(p tau) / p`` after a unit step down at 0
    (``g = 1``, ``G = tau`` before it)."""
    tau = np.asarray(tau, dtype=float)
    G = tau.copy()
    after = tau >= 0.0
    if after.any():
        ta = tau[after]
        G[after] = -sum((Ri * (np.exp(pi * ta) - 1.0) / pi ** 2).real for pi, Ri in zip(p, R))
    return G


def mode_response(tau, a, v, D, tj: float, loop: tuple[float, float], mode: tuple[float, float]) -> np.ndarray:
    """A mode (``mode`` = omega rad/s, zeta; unit static gain) driven by the acceleration of the loop (``loop``
    = omega, zeta) that follows the command (:func:`_edges`): 0 at cruise, 1 while decelerating steadily,
    ringing out after the end."""
    p, R = _mode_poles(loop[0], loop[1], mode[0], mode[1])
    tj = float(tj)
    tau = np.asarray(tau, dtype=float)
    fast = _ShiftedEdges.of(tau, a, v, D, tj, [abs(float(pi.real)) for pi in p])
    if fast is not None:
        return fast.mode(p, R)

    def ramp(x):  # unit level falling over [-tj, 0] (a step below STEP_TJ_S)
        if tj <= STEP_TJ_S:
            return _pr_decay(x, p, R)
        return (_pr_integral(x + tj, p, R) - _pr_integral(x, p, R)) / tj

    return _edges(tau, a, v, D, tj, ramp)


def command_position(tau, a, tj: float, v=None) -> np.ndarray:
    """The command near its end: deceleration ``a`` (mm/s^2) falling to 0 over ``[-tj, 0]``, at 0 from ``tau = 0``;
    with the cruise speed ``v``, a straight line at ``v`` before the deceleration set in (at ``-tj - v / a``)."""
    a = np.asarray(a, dtype=float)
    if v is not None:
        tau = np.asarray(tau, dtype=float)
        onset = -tj - np.asarray(v, dtype=float) / a
        tc = np.maximum(tau, onset)
        return command_position(tc, a, tj) + np.asarray(v, dtype=float) * (tau - tc)
    tau = np.asarray(tau, dtype=float)
    s = tau + tj
    r0, v0 = -a * tj * tj / 6.0, a * tj / 2.0
    if tj > 1e-9:
        ramp = r0 + v0 * s - a * (s * s / 2.0 - s ** 3 / (6.0 * tj))
    else:
        ramp = np.zeros_like(s)
    before = r0 + v0 * s - a * s * s / 2.0
    return np.where(tau >= 0.0, 0.0, np.where(s >= 0.0, ramp, before))


def creep(tau, amplitude_mm: float, tau_s: float) -> np.ndarray:
    """Short by ``amplitude_mm`` while moving, creeping in as ``exp(-tau / tau_s)`` after the command's end."""
    tau = np.asarray(tau, dtype=float)
    return -amplitude_mm * np.where(tau >= 0.0, np.exp(-np.maximum(tau, 0.0) / tau_s), 1.0)


def _edges(tau, a, v, D, tj: float, ramp) -> np.ndarray:
    """A system's response to the whole trapezoid's acceleration (``ramp(x)``: its response to a unit level
    falling over ``[-tj, 0]``): speed ``v`` reached after ``v / a``, cruise over ``D / v - v / a`` (none on a
    triangle), deceleration ending at ``tau = 0``; level +1 while decelerating, -1 while accelerating."""
    tau = np.asarray(tau, dtype=float)
    a = np.asarray(a, dtype=float)
    t_dec = np.asarray(v, dtype=float) / a
    t_cr = np.maximum(np.asarray(D, dtype=float) / np.asarray(v, dtype=float) - t_dec, 0.0)
    return ramp(tau) - ramp(tau + t_dec) - ramp(tau + t_dec + t_cr) + ramp(tau + 2.0 * t_dec + t_cr)


def decel_response(tau, a, v, D, tj: float, omega: float, zeta: float) -> np.ndarray:
    """A second-order system (unit static gain) driven by the level of :func:`_edges`."""
    fast = _ShiftedEdges.of(tau, a, v, D, tj, _decay_rates(omega, zeta))
    if fast is not None:
        return fast.servo(omega, zeta)
    return _edges(tau, a, v, D, tj, lambda x: ramp_response(x, omega, zeta, tj))


def servo_position(tau, a, tj: float, omega: float, zeta: float, v=None, D=None) -> np.ndarray:
    """Where a second-order position loop (``omega`` rad/s, ``zeta``) following the command is, near the end of
    the deceleration; with the peak speed ``v`` and the move's length ``D`` the loop's transients of the
    earlier edges of the profile are included (:func:`_edges`)."""
    a = np.asarray(a, dtype=float)
    resp = ramp_response(tau, omega, zeta, tj) if v is None else decel_response(tau, a, v, D, tj, omega, zeta)
    return command_position(tau, a, tj, v) + a / omega ** 2 * resp


# --------------------------------------------------------------------------
# the same responses with one evaluation of exp, cos and sin per call
# --------------------------------------------------------------------------
#: the shifted evaluation multiplies exp(-r t) by exp(-r s); it is used while r (t + s) stays below this
_SHIFT_EXP_MAX = 600.0


def _decay_rates(omega: float, zeta: float) -> list[float]:
    """The decay rates (1/s, >= 0) of :func:`_decay_after`'s exponentials."""
    z = float(zeta)
    if abs(z - 1.0) < _CRITICAL_EPS:
        z = 1.0 + _CRITICAL_EPS
    if z < 1.0:
        return [z * omega]
    return [abs(-z * omega - omega * np.sqrt(z * z - 1.0))]


class _ShiftedEdges:
    """:func:`_edges` of a response evaluated at ``tau + s`` for the eight shifts ``s`` of the four edges (each
    at ``x`` and ``x + tj``), with ``exp``, ``cos`` and ``sin`` computed once at ``tau`` and moved to each
    shift by ``e^(p (t + s)) = e^(p t) e^(p s)`` (the angle-sum formulas): the same values to rounding, an
    eighth of the transcendental functions (they are most of the motion fit's time). The positions ``x``
    (``tau + shift``, formed as :func:`_edges` forms them) decide before/after, as there."""

    def __init__(self, tau, xs, shifts, tj):
        self.tau, self.xs, self.shifts, self.tj = tau, xs, shifts, tj
        # times before every edge are used by none: the base starts at the largest shift back
        with np.errstate(invalid="ignore"):
            self.tb = np.maximum(tau, -(shifts[-1] + tj))

    @classmethod
    def of(cls, tau, a, v, D, tj: float, rates) -> "_ShiftedEdges | None":
        """The shifts of ``tau`` (None where an exponential of ``rates`` over the span would leave the floats:
        the direct evaluation is used there)."""
        tau = np.asarray(tau, dtype=float)
        a = np.asarray(a, dtype=float)
        t_dec = np.asarray(v, dtype=float) / a
        t_cr = np.maximum(np.asarray(D, dtype=float) / np.asarray(v, dtype=float) - t_dec, 0.0)
        x1 = tau + t_dec
        x2 = x1 + t_cr  # as _edges: ((tau + t_dec) + t_cr)
        x3 = tau + 2.0 * t_dec + t_cr
        zero = np.zeros_like(t_dec)
        shifts = (zero, t_dec, t_dec + t_cr, 2.0 * t_dec + t_cr)
        if tau.size == 0 or not all(np.all(np.isfinite(s)) for s in shifts):
            return None
        with np.errstate(invalid="ignore"):
            t_hi = float(np.nanmax(tau)) if np.any(np.isfinite(tau)) else 0.0
        span = float(np.max(shifts[-1])) + tj + max(t_hi, 0.0)
        if not math.isfinite(span) or max(rates, default=0.0) * span > _SHIFT_EXP_MAX:
            return None
        return cls(tau, (tau, x1, x2, x3), shifts, tj)

    def _combine(self, value) -> np.ndarray:
        """``ramp(x0) - ramp(x1) - ramp(x2) + ramp(x3)`` with ``value(x, s, integral)`` the response (``integral``:
        its integral, for the ramp of a jerk time) at ``x = tau + s``."""
        tj = self.tj
        out = []
        for x, s in zip(self.xs, self.shifts):
            if tj <= STEP_TJ_S:
                out.append(value(x, s, False))
            else:
                out.append((value(x + tj, s + tj, True) - value(x, s, True)) / tj)
        return out[0] - out[1] - out[2] + out[3]

    def servo(self, omega: float, zeta: float) -> np.ndarray:
        """:func:`decel_response`."""
        z = float(zeta)
        if abs(z - 1.0) < _CRITICAL_EPS:
            z = 1.0 + _CRITICAL_EPS
        zw = 2.0 * float(zeta) * omega
        tb = self.tb
        with np.errstate(invalid="ignore"):
            if z < 1.0:
                wd = omega * np.sqrt(1.0 - z * z)
                E = np.exp(-z * omega * tb)
                Zr, Zi = E * np.cos(wd * tb), E * np.sin(wd * tb)  # e^(p tb), p = -z w + i wd
                k, q = z * omega / wd, omega * omega / wd
                pole = complex(-z * omega, wd)

                def decay(s):
                    # e^(p (tb + s)) = Z W with W = e^(p s) per move: the cosine and sine of the decaying
                    # oscillation at tb + s are Re(Z W) and Im(Z W), two products of the whole arrays each
                    W = np.exp(pole * np.asarray(s, dtype=float))
                    wr, wi = W.real, W.imag
                    return Zr * (wr + k * wi) + Zi * (k * wr - wi), -q * (Zr * wi + Zi * wr)
            else:
                r = omega * np.sqrt(z * z - 1.0)
                l1, l2 = -z * omega + r, -z * omega - r
                E1, E2 = np.exp(l1 * tb), np.exp(l2 * tb)

                def decay(s):
                    e1, e2 = E1 * np.exp(l1 * s), E2 * np.exp(l2 * s)
                    return (l2 * e1 - l1 * e2) / (l2 - l1), l1 * l2 * (e1 - e2) / (l2 - l1)

            def value(x, s, integral):
                ga, gd = decay(s)
                after = x >= 0.0
                if integral:
                    return np.where(after, (zw - gd - zw * ga) / omega ** 2, x)
                return np.where(after, ga, 1.0)

            return self._combine(value)

    def mode(self, p, R) -> np.ndarray:
        """:func:`mode_response` of the poles ``p`` and residues ``R`` of :func:`_mode_poles`."""
        tb = self.tb
        with np.errstate(invalid="ignore"):
            base = []  # e^(p tb) of each pole, as its real and imaginary parts
            for pi in p:
                E = np.exp(pi.real * tb)
                base.append((E * np.cos(pi.imag * tb), E * np.sin(pi.imag * tb)))

            def value(x, s, integral):
                # Re(c e^(p (tb + s))) = Re(Z (c W)), W = e^(p s) per move: two products of the whole arrays
                total, const = 0.0, 0.0
                s = np.asarray(s, dtype=float)
                for pi, Ri, (Zr, Zi) in zip(p, R, base):
                    c = Ri / pi ** 2 if integral else Ri / pi
                    cW = c * np.exp(pi * s)
                    total = total + (Zr * cW.real - Zi * cW.imag)
                    const += c.real
                if integral:
                    total = total - const
                after = x >= 0.0
                return np.where(after, -total, x if integral else 1.0)

            return self._combine(value)
