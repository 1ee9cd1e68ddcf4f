"""The simulated arm's temperature rise, driven by its joints' motion (the thermal drift's ``dT``).

A moving joint heats its motor, brake and reducer; an arm at rest cools to
the cell's air. The rise ``T`` (K) of the links follows one first-order
balance (eq. (H1))::

    tau dT/dt = dT_max h(t) / H_REF - T                                  (H1)

``h(t)`` the heat input: the mean over the joints of ``|qdot_j| / qdot_max_j``
(each joint's speed over its rated speed), taken constant over each move at
the move's mean (its joints' travel over their rated speeds and the move's
duration); 0 at rest, so a resting arm cools with ``exp(-t / tau)``.
``dT_max`` and ``tau`` are the arm's ``thermal_drift`` parameters
(:class:`station.models.effects.ThermalDrift`): ``dT_max`` is the steady rise
of an arm that keeps moving at the heat input :data:`H_REF` (an ISO 9283
pose cycle at rated speed, moves and fine-stop dwells one after the other:
its mean input is about that), ``tau`` its time constant. Between knots the
input is constant, so ``T`` is exact there::

    T(t) = K h_k + (T_k - K h_k) exp(-(t - t_k) / tau),   K = dT_max / H_REF     (H2)

The knots are the starts and ends of the moves the arm queued, in time
order; a protective stop cuts them (:meth:`ArmHeat.cut`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["H_REF", "ArmHeat", "heat_input"]

#: the heat input at which an arm's steady rise is its ``dT_max``: the mean normalised joint speed of ISO 9283
#: pose and vAP cycles at rated speed on the simulated large arm, moves and fine-stop dwells one after the other
#: (0.064 and 0.065 on two drawn arms, 5 pose and 2 vAP cycles)
H_REF = 0.065


def heat_input(travel_rad, duration_s: float, speed_limits_rad_s) -> float:
    """A move's mean heat input ``h``: the mean over the joints of travel / (rated speed x duration) (H1)."""
    if duration_s <= 0:
        return 0.0
    v = np.asarray(travel_rad, dtype=float) / np.asarray(speed_limits_rad_s, dtype=float)
    return float(np.mean(v) / duration_s)


class ArmHeat:
    """The rise (H1) from ``t0_s`` on, ``rise0_K`` then, the input 0 until a move is added."""

    def __init__(self, dT_max_K: float, tau_s: float, t0_s: float, rise0_K: float = 0.0) -> None:
        if not (math.isfinite(tau_s) and tau_s > 0 and math.isfinite(dT_max_K) and dT_max_K >= 0):
            raise ValueError(f"heat: dT_max_K >= 0 and tau_s > 0, got {dT_max_K!r}, {tau_s!r}")
        self.gain_K = float(dT_max_K) / H_REF
        self.tau_s = float(tau_s)
        self._t = [float(t0_s)]
        self._T = [float(rise0_K)]
        self._h = [0.0]

    def cooled_from(self, t_s: float, rise_K: float) -> "ArmHeat":
        """This arm's heat from its start on, ``rise_K`` at ``t_s`` before it (cooled at rest since, H2)."""
        t0 = self._t[0]
        return ArmHeat(self.gain_K * H_REF, self.tau_s, t0, rise_K * math.exp(-max(t0 - t_s, 0.0) / self.tau_s))

    def rise_K(self, t) -> np.ndarray:
        """The rise at times ``t`` (N,), K (at its start's value before ``t0_s``) (H2)."""
        tt = np.asarray(t, dtype=float).reshape(-1)
        knots = np.asarray(self._t)
        k = np.clip(np.searchsorted(knots, tt, side="right") - 1, 0, None)
        steady = self.gain_K * np.asarray(self._h)[k]
        dt = np.maximum(tt - knots[k], 0.0)
        return steady + (np.asarray(self._T)[k] - steady) * np.exp(-dt / self.tau_s)

    def _at(self, t: float) -> float:
        return float(self.rise_K(t)[0])

    def add_move(self, t_start: float, t_end: float, h: float) -> None:
        """A move over ``[t_start, t_end]`` with the heat input ``h``; then rest (a move at or after the last
        knot: the arm's queue is in time order)."""
        if t_start < self._t[-1]:
            self.cut(t_start)
        T0 = self._at(t_start)
        if t_start == self._t[-1]:
            self._T[-1], self._h[-1] = T0, float(h)
        else:
            self._knot(t_start, T0, h)
        if t_end > t_start:
            self._knot(t_end, self._at(t_end), 0.0)
        else:
            self._h[-1] = 0.0

    def _knot(self, t: float, T: float, h: float) -> None:
        self._t.append(float(t))
        self._T.append(float(T))
        self._h.append(float(h))

    def cut(self, t: float) -> None:
        """The motion after ``t`` did not happen (a protective stop): rest from ``t`` on."""
        T = self._at(t)
        keep = int(np.searchsorted(np.asarray(self._t), t, side="right"))
        del self._t[keep:], self._T[keep:], self._h[keep:]
        if self._t and self._t[-1] == t:
            self._T[-1], self._h[-1] = T, 0.0
        else:
            self._knot(t, T, 0.0)
