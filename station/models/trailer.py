"""Kinematics of the two-link nonholonomic trailer robot (seed 003, Fig. 3).

Geometry
--------
Link 1 (length ``L1``) runs from the front wheel axle ``C1`` back to the joint
``P``; link 2 (length ``L2``) runs from ``P`` back to the rear wheel axle
``C2``. Both axles roll without slipping sideways (the nonholonomic
constraints of seed 003 para. [0080]). The front unit is driven at speed
``v`` (m/s, the speed of ``C1``) along a path of curvature ``kappa`` (1/m,
``kappa = 1/R``, para. [0089]); ``psi`` (rad) is the joint angle, the heading
of link 1 minus the heading of link 2.

Time dynamics of the joint angle (derived here; the seed only gives its
steady state)
-----------------------------------------------------------------------------
Let ``theta1``, ``theta2`` be the headings of the links, ``e_i`` their unit
vectors, ``n_i`` the left normals, and ``psi = theta1 - theta2``.

* Constraint of the front axle: ``dC1/dt = v e1`` and ``dtheta1/dt = v kappa``.
* The joint: ``P = C1 - L1 e1``, so ``dP/dt = v e1 - L1 (v kappa) n1``.
* Constraint of the rear axle: ``C2 = P - L2 e2`` must move along ``e2``,
  i.e. ``(dC2/dt) . n2 = 0``. With ``dC2/dt = dP/dt - L2 (dtheta2/dt) n2``,
  ``e1 . n2 = sin(psi)`` and ``n1 . n2 = cos(psi)``::

      L2 dtheta2/dt = v sin(psi) - L1 v kappa cos(psi)

* Hence the joint-angle ODE::

      dpsi/dt = v kappa - dtheta2/dt
              = (v / L2) * [kappa (L2 + L1 cos(psi)) - sin(psi)]        (D)

  whose right-hand side is ``-(v/L2)`` times the left-hand side of seed
  eq. (23). Its equilibria are exactly eq. (23),
  ``sin(psi) - kappa (L2 + L1 cos(psi)) = 0`` (which the seed obtains from
  the triangles of Fig. 3, eq. (22)). The joint angle relaxes towards it over
  a distance of about ``L2`` travelled (time constant ``L2 / v`` near
  ``psi = 0``), so with a curvature that changes in time the measured joint
  angle lags its steady state. ``d(rhs)/dpsi = -(v/L2) sqrt(1 + kappa^2 L1^2)
  cos(psi - atan(kappa L1))`` is negative on the branch computed by
  :func:`steady_state_psi`: that branch is the stable one for forward motion.

Steady state in closed form
---------------------------
Eq. (23) is ``sin(psi) - kappa L1 cos(psi) = kappa L2``, i.e.
``sqrt(1 + kappa^2 L1^2) sin(psi - atan(kappa L1)) = kappa L2``::

    psi = atan(kappa L1) + asin(kappa L2 / sqrt(1 + kappa^2 L1^2))

which has a real solution exactly when ``kappa^2 (L2^2 - L1^2) <= 1``: the
curvature bound of eq. (25), ``kappa^2 < 1 / (L2^2 - L1^2)`` (beyond it the
trailer jackknifes; there is no steady state).

Commands (para. [0127], period of 0.1 t in seconds)
--------------------------------------------------
``H``: ``kappa = M sin(0.1 t)``; ``C``: ``kappa = M tanh(0.1 t)``;
``L``: ``kappa = M (0.1 t / pi - 1)``.

Units: lengths m, curvature 1/m, angles rad, time s, speed m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import ConfigError, DataError, InsufficientDataError

#: link lengths of the seed's simulations (para. [0132]), m
DEFAULT_L1_M = 1.25
DEFAULT_L2_M = 2.48
#: joint-angle limit chosen by the seed (para. after eq. (25)): |psi| < 45 deg
PSI_LIMIT_RAD = math.pi / 4
#: angular rate of the seed's command signals (para. [0127]), rad/s
COMMAND_OMEGA_RAD_S = 0.1
#: command kinds of para. [0127]
COMMAND_KINDS = ("H", "C", "L")
#: the seed's sensor noise "amplitude" (para. [0130])
PATENT_NOISE_AMPLITUDE = 0.03
#: the standard deviation that reproduces the seed's figures: 0.03 / sqrt(3)
#: (the variance of a uniform noise of amplitude 0.03; see tests/trailer)
PATENT_NOISE_SIGMA = PATENT_NOISE_AMPLITUDE / math.sqrt(3.0)


class CurvatureBoundError(DataError):
    """A curvature at or beyond the jackknife bound of eq. (25)."""


class JointAngleLimitError(DataError):
    """A joint angle beyond the 45 degree limit of the seed."""


class DegenerateCommandError(InsufficientDataError):
    """The curvature does not vary enough to separate the parameters."""


def check_lengths(L1_m: float, L2_m: float) -> tuple[float, float]:
    """Validate link lengths: finite, ``0 <= L1 < L2`` (seed: "L2 > L1").

    Returns
    -------
    (float, float)
        The lengths as floats.
    """
    try:
        L1, L2 = float(L1_m), float(L2_m)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"L1_m and L2_m must be numbers, got {L1_m!r}, {L2_m!r}") from exc
    if not math.isfinite(L1) or L1 < 0:
        raise ConfigError(f"L1_m must be finite and >= 0, got {L1_m!r}")
    if not math.isfinite(L2) or L2 <= L1:
        raise ConfigError(f"L2_m must be finite and > L1_m ({L1}), got {L2_m!r} "
                          "(seed 003: the rear link is the longer one)")
    return L1, L2


def curvature_bound(L1_m: float, L2_m: float) -> float:
    """Largest steady-state curvature, eq. (25): ``1 / sqrt(L2^2 - L1^2)``, 1/m."""
    L1, L2 = check_lengths(L1_m, L2_m)
    return 1.0 / math.sqrt(L2 * L2 - L1 * L1)


def steady_state_psi(kappa, L1_m: float = DEFAULT_L1_M, L2_m: float = DEFAULT_L2_M) -> np.ndarray:
    """Steady-state joint angle of eq. (23) on its stable branch.

    Parameters
    ----------
    kappa : array_like, shape (...)
        Curvature, 1/m; ``|kappa|`` must be below the bound of eq. (25).

    Returns
    -------
    ndarray, shape (...)
        Joint angle, rad.

    Raises
    ------
    CurvatureBoundError
        If any curvature reaches eq. (25) (no steady state exists).
    """
    L1, L2 = check_lengths(L1_m, L2_m)
    k = np.asarray(kappa, dtype=float)
    if not np.all(np.isfinite(k)):
        raise DataError("kappa contains NaN or infinite values")
    bound = 1.0 / math.sqrt(L2 * L2 - L1 * L1)
    over = np.abs(k) >= bound
    if np.any(over):
        raise CurvatureBoundError(
            f"{int(over.sum())} curvature value(s) reach the bound of eq. (25) "
            f"|kappa| < {bound:.6g} 1/m for L1={L1} m, L2={L2} m (max |kappa| "
            f"{float(np.max(np.abs(k))):.6g} 1/m): the trailer has no steady state")
    r = np.sqrt(1.0 + (k * L1) ** 2)
    return np.arctan(k * L1) + np.arcsin(k * L2 / r)


def steady_state_kappa(psi, L1_m: float = DEFAULT_L1_M, L2_m: float = DEFAULT_L2_M) -> np.ndarray:
    """Curvature whose steady state is ``psi``: eq. (23) solved for kappa.

    ``kappa = sin(psi) / (L2 + L1 cos(psi))``, shape of ``psi``.
    """
    L1, L2 = check_lengths(L1_m, L2_m)
    p = np.asarray(psi, dtype=float)
    return np.sin(p) / (L2 + L1 * np.cos(p))


def steady_state_residual(kappa, psi, L1_m, L2_m) -> np.ndarray:
    """Left-hand side of eq. (23): ``sin(psi) - kappa (L2 + L1 cos(psi))``.

    ``L1_m``, ``L2_m`` may be arrays broadcasting with ``kappa`` and ``psi``.
    """
    k = np.asarray(kappa, dtype=float)
    p = np.asarray(psi, dtype=float)
    return np.sin(p) - k * (np.asarray(L2_m) + np.asarray(L1_m) * np.cos(p))


def psi_rate(psi, kappa, v_m_s, L1_m, L2_m) -> np.ndarray:
    """Joint-angle rate of the nonholonomic dynamics (D), rad/s.

    ``dpsi/dt = (v/L2) [kappa (L2 + L1 cos psi) - sin psi]``; all arguments
    broadcast (lengths may be arrays of parameter sets).
    """
    p = np.asarray(psi, dtype=float)
    L1 = np.asarray(L1_m, dtype=float)
    L2 = np.asarray(L2_m, dtype=float)
    return np.asarray(v_m_s) / L2 * (np.asarray(kappa) * (L2 + L1 * np.cos(p)) - np.sin(p))


def command_curvature(kind: str, M: float, t_s, omega_rad_s: float = COMMAND_OMEGA_RAD_S) -> np.ndarray:
    """The curvature commands of para. [0127].

    Parameters
    ----------
    kind : {"H", "C", "L"}
        Harmonic ``M sin(w t)``, curve ``M tanh(w t)``, linear ``M (w t / pi - 1)``.
    M : float
        Amplitude, 1/m.
    t_s : array_like, shape (N,)
        Time since the start of the command, s.
    omega_rad_s : float
        ``w``; the seed uses 0.1 rad/s.

    Returns
    -------
    ndarray, shape (N,)
        Commanded curvature, 1/m.
    """
    if kind not in COMMAND_KINDS:
        raise ConfigError(f"command kind must be one of {COMMAND_KINDS}, got {kind!r}")
    if not (isinstance(M, (int, float)) and math.isfinite(M)):
        raise ConfigError(f"command amplitude M must be a finite number, got {M!r}")
    if not (isinstance(omega_rad_s, (int, float)) and math.isfinite(omega_rad_s) and omega_rad_s > 0):
        raise ConfigError(f"omega_rad_s must be a finite number > 0, got {omega_rad_s!r}")
    t = np.asarray(t_s, dtype=float)
    if not np.all(np.isfinite(t)):
        raise DataError("t_s contains NaN or infinite values")
    wt = omega_rad_s * t
    if kind == "H":
        return M * np.sin(wt)
    if kind == "C":
        return M * np.tanh(wt)
    return M * (wt / math.pi - 1.0)


def check_curvature_command(kappa, L1_m: float, L2_m: float,
                            psi_limit_rad: float = PSI_LIMIT_RAD) -> float:
    """Refuse curvatures beyond eq. (25) or whose steady joint angle passes the limit.

    Parameters
    ----------
    kappa : array_like
        Curvatures to be commanded, 1/m.

    Returns
    -------
    float
        The largest steady-state ``|psi|`` of the command, rad.

    Raises
    ------
    CurvatureBoundError, JointAngleLimitError
    """
    psi = steady_state_psi(kappa, L1_m, L2_m)
    worst = float(np.max(np.abs(psi))) if psi.size else 0.0
    if worst >= psi_limit_rad:
        k = np.asarray(kappa, dtype=float)
        raise JointAngleLimitError(
            f"curvature up to {float(np.max(np.abs(k))):.6g} 1/m drives the joint angle to "
            f"{math.degrees(worst):.2f} deg, beyond the limit of "
            f"{math.degrees(psi_limit_rad):.1f} deg (seed 003)")
    return worst


#: how sampled curvature and speed stand for the continuous inputs
INPUT_SAMPLINGS = ("interval", "point")

#: the link-length estimators by name (:func:`station.analysis.trailer.estimate.estimate_trailer`, which
#: holds them; a station config names one): seed 003 Table 3's combined methods M1..M24, the orthogonal
#: distance fit and the dynamic fit of (D)
ESTIMATORS = tuple(f"M{n}" for n in range(1, 25)) + ("odr", "dynamic")


def integrate_psi(t_s, kappa, v_m_s, psi0_rad, L1_m, L2_m, *, sensitivities: bool = False,
                  substeps: int = 1, sampling: str = "interval"):
    """Integrate the joint-angle dynamics (D) along sampled inputs (RK4).

    ``sampling="interval"``: sample ``i`` is the average over
    ``(t_{i-1}, t_i]`` (what an odometry unit reports: heading change over
    distance), held over that interval; ``"point"``: samples are values at
    ``t_i``, interpolated linearly. The loop runs over time steps (the ODE is
    sequential); every step is vectorised over the leading axes, i.e. over
    runs and parameter sets.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Strictly increasing sample times, s.
    kappa : array_like, shape (..., N)
        Curvature at the samples, 1/m.
    v_m_s : float or array_like, shape (..., N)
        Speed at the samples, m/s.
    psi0_rad, L1_m, L2_m : float or array_like, shape (...)
        Initial joint angle at ``t_s[0]`` and link lengths.
    sensitivities : bool
        Also integrate ``d psi / d (L1, L2, psi0)`` (forward sensitivity
        equations), for Gauss-Newton fits.
    substeps : int
        RK4 steps per sample interval.
    sampling : {"interval", "point"}
        Meaning of the input samples (see above).

    Returns
    -------
    psi : ndarray, shape (..., N)
    sens : ndarray, shape (..., N, 3), only if ``sensitivities``
    """
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InsufficientDataError(f"t_s must be 1-D with >= 2 samples, got shape {t.shape}")
    dt_all = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(dt_all <= 0):
        raise DataError("t_s must be finite and strictly increasing")
    if not isinstance(substeps, int) or substeps < 1:
        raise ConfigError(f"substeps must be an integer >= 1, got {substeps!r}")
    if sampling not in INPUT_SAMPLINGS:
        raise ConfigError(f"sampling must be one of {INPUT_SAMPLINGS}, got {sampling!r}")
    held = sampling == "interval"
    k = np.asarray(kappa, dtype=float)
    if k.shape[-1] != t.size:
        raise DataError(f"kappa has {k.shape[-1]} samples along its last axis, t_s has {t.size}")
    v = np.broadcast_to(np.asarray(v_m_s, dtype=float), np.broadcast_shapes(np.shape(v_m_s), (t.size,)))
    batch = np.broadcast_shapes(k.shape[:-1], v.shape[:-1], np.shape(psi0_rad), np.shape(L1_m),
                                np.shape(L2_m))
    k = np.broadcast_to(k, batch + (t.size,))
    v = np.broadcast_to(v, batch + (t.size,))
    L1 = np.broadcast_to(np.asarray(L1_m, dtype=float), batch)
    L2 = np.broadcast_to(np.asarray(L2_m, dtype=float), batch)
    psi = np.array(np.broadcast_to(np.asarray(psi0_rad, dtype=float), batch))
    out = np.empty(batch + (t.size,))
    out[..., 0] = psi
    if sensitivities:
        s = np.zeros(batch + (3,))
        s[..., 2] = 1.0
        sens = np.empty(batch + (t.size, 3))
        sens[..., 0, :] = s

    def rhs(p, kk, vv):
        c, sn = np.cos(p), np.sin(p)
        f = vv / L2 * (kk * (L2 + L1 * c) - sn)
        if not sensitivities:
            return f, None
        return f, (c, sn)

    def sens_rhs(p, kk, vv, trig, sv):
        c, sn = trig
        dfdp = -vv / L2 * (kk * L1 * sn + c)
        dfdL1 = vv * kk * c / L2
        dfdL2 = vv / (L2 * L2) * (sn - kk * L1 * c)
        ds = dfdp[..., None] * sv
        ds[..., 0] += dfdL1
        ds[..., 1] += dfdL2
        return ds

    for i in range(t.size - 1):
        h = dt_all[i] / substeps
        k1, v1 = k[..., i + 1], v[..., i + 1]
        k0, v0 = (k1, v1) if held else (k[..., i], v[..., i])
        for j in range(substeps):
            a0 = j / substeps
            am = (j + 0.5) / substeps
            a1 = (j + 1) / substeps
            ka, kb, kc = k0 + a0 * (k1 - k0), k0 + am * (k1 - k0), k0 + a1 * (k1 - k0)
            va, vb, vc = v0 + a0 * (v1 - v0), v0 + am * (v1 - v0), v0 + a1 * (v1 - v0)
            f1, g1 = rhs(psi, ka, va)
            p2 = psi + 0.5 * h * f1
            f2, g2 = rhs(p2, kb, vb)
            p3 = psi + 0.5 * h * f2
            f3, g3 = rhs(p3, kb, vb)
            p4 = psi + h * f3
            f4, g4 = rhs(p4, kc, vc)
            if sensitivities:
                d1 = sens_rhs(psi, ka, va, g1, s)
                d2 = sens_rhs(p2, kb, vb, g2, s + 0.5 * h * d1)
                d3 = sens_rhs(p3, kb, vb, g3, s + 0.5 * h * d2)
                d4 = sens_rhs(p4, kc, vc, g4, s + h * d3)
                s = s + h / 6.0 * (d1 + 2 * d2 + 2 * d3 + d4)
            psi = psi + h / 6.0 * (f1 + 2 * f2 + 2 * f3 + f4)
        out[..., i + 1] = psi
        if sensitivities:
            sens[..., i + 1, :] = s
    if sensitivities:
        return out, sens
    return out


@dataclass(frozen=True)
class SensorModel:
    """Curvature and joint-angle sensors: ``gain * true + offset + noise``.

    Parameters
    ----------
    kappa_sigma, psi_sigma : float
        Standard deviation of the Gaussian noise, 1/m and rad.
    kappa_offset, psi_offset : float
        Constant offsets, 1/m and rad.
    kappa_gain, psi_gain : float
        Scale factors (1 = ideal).
    """

    kappa_sigma: float = 0.0
    psi_sigma: float = 0.0
    kappa_offset: float = 0.0
    psi_offset: float = 0.0
    kappa_gain: float = 1.0
    psi_gain: float = 1.0

    def __post_init__(self) -> None:
        for name in ("kappa_sigma", "psi_sigma", "kappa_offset", "psi_offset", "kappa_gain", "psi_gain"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ConfigError(f"SensorModel.{name} must be a finite number, got {value!r}")
        if self.kappa_sigma < 0 or self.psi_sigma < 0:
            raise ConfigError("SensorModel.kappa_sigma and psi_sigma must be >= 0")
        if self.kappa_gain <= 0 or self.psi_gain <= 0:
            raise ConfigError("SensorModel gains must be > 0")

    @classmethod
    def from_noise(cls, noise) -> "SensorModel":
        """``None`` -> ideal; a number -> that sigma on both; a SensorModel as is."""
        if noise is None:
            return cls()
        if isinstance(noise, SensorModel):
            return noise
        if isinstance(noise, (int, float)):
            return cls(kappa_sigma=float(noise), psi_sigma=float(noise))
        raise ConfigError(f"noise must be a number, a SensorModel or None, got {noise!r}")

    def measure(self, kappa, psi, rng: np.random.Generator | None):
        """Measured ``(kappa_m, psi_m)`` of true values (same shapes)."""
        k = np.asarray(kappa, dtype=float)
        p = np.asarray(psi, dtype=float)
        km = self.kappa_gain * k + self.kappa_offset
        pm = self.psi_gain * p + self.psi_offset
        if self.kappa_sigma > 0 or self.psi_sigma > 0:
            if rng is None:
                raise ConfigError("a SensorModel with noise needs an rng")
            km = km + rng.normal(0.0, self.kappa_sigma, size=np.shape(km)) if self.kappa_sigma > 0 else km
            pm = pm + rng.normal(0.0, self.psi_sigma, size=np.shape(pm)) if self.psi_sigma > 0 else pm
        return km, pm


__all__ = [
    "DEFAULT_L1_M", "DEFAULT_L2_M", "PSI_LIMIT_RAD", "COMMAND_OMEGA_RAD_S", "COMMAND_KINDS",
    "PATENT_NOISE_AMPLITUDE", "PATENT_NOISE_SIGMA",
    "CurvatureBoundError", "JointAngleLimitError", "DegenerateCommandError",
    "check_lengths", "curvature_bound", "steady_state_psi", "steady_state_kappa",
    "steady_state_residual", "psi_rate", "command_curvature", "check_curvature_command",
    "INPUT_SAMPLINGS", "integrate_psi", "SensorModel",
]
