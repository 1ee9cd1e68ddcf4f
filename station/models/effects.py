"""Error effects: named, composable, pure extensions of the nominal arm model.

The controller believes the nominal model (``robot.dh_nominal``, the encoder
angles). The real arm differs by a handful of physical effects; each one here
is a pure function of its own parameter vector::

    effect.apply(params, dh, q_rad, ctx) -> (dh_eff, q_eff)

vectorised over N samples (``q_rad`` (N, 6); ``dh`` (7, 5) or (N, 7, 5)).
The same functions serve the simulation (draw parameters, switch effects on)
and the analysis (fit the parameters to measured data).

Effects
-------
``geometric``
    Deviations of the 35 DH + Hayati parameters (seed 002 eq. (3), (8)):
    ``dh_eff = dh + delta`` with ``delta`` in the row-major order of
    ``dh.ravel()`` (``a1, alpha1, d1, theta1, beta1, ..., beta_TCP``; mm, rad).
``thermal_drift``
    Link lengths ``a`` and ``d`` of every row (tool included) grow with the
    temperature rise: ``x_eff = x (1 + alpha_per_K dT)``. ``dT`` is the
    context's measured ``temperature_rise_K`` when given, otherwise a
    first-order warm-up ``dT(t) = dT_max (1 - exp(-t / tau))`` of the
    context's ``warmup_s``. Parameters ``[dT_max_K, tau_s]``; the expansion
    coefficient ``alpha_per_K`` is a fixed property (default
    :data:`STEEL_ALPHA_PER_K`, steel and cast iron; aluminium castings are
    ~2.3e-5 /K).
``encoder_eccentricity``
    First harmonic of the joint-angle error over one turn of the output
    (eccentric encoder disc or reducer output):
    ``q_eff = q + s_i sin q_i + c_i cos q_i`` = ``A_i sin(q_i + phi_i)`` with
    ``A_i = hypot(s_i, c_i)``, ``phi_i = atan2(c_i, s_i)``. The sin/cos form
    is linear in its parameters (fits without a singularity at A = 0);
    :func:`eccentricity_amplitude_phase` converts.
``backlash``
    Lost motion in the reducer: the output lags the motor by a half-width
    ``b_i`` against the direction of the last motion of joint ``i``:
    ``q_eff = q - b_i sign_i``, ``sign_i`` in ``{-1, 0, +1}`` from the
    context (0: no motion yet, backlash centred).
``joint_compliance``
    Gravity twists each joint's reducer: ``q_eff = q - c_i g_i(dh_eff, q)``
    where ``g(q)`` is the gravity holding torque of
    :func:`station.models.robots.gravity_torques` (with the context's
    payload), so a positive ``c_i`` (rad per N m) lets the link sag. An
    external force ``F`` (N, base frame) on the TCP (the context's
    ``tcp_force_N``: the load of a static compliance test, ISO 9283 clause
    10) adds its holding torque ``-J_v^T F``, so the TCP gives way by
    ``C F`` with the compliance matrix :func:`tcp_compliance_mm_per_N`.
    Option ``basis``: further torque columns per joint, 1 kg at the elbow or
    at the tool point (:data:`COMPLIANCE_BASES`), for a mass model known
    only roughly (the diagnosis's candidate, an extended model file).

Each effect declares its parameters with units and ranges
(:attr:`param_specs`, :mod:`station.models.effect_params`).

Linearisation
-------------
The diagnosis (:mod:`station.analysis.diagnose.terms`) and the extended
model (:mod:`station.models.arm_extended`) use these effects to first order
about the nominal arm: every joint effect is linear in its parameters,
``dq = B(dh, q, ctx) P`` (:meth:`JointEffect.joint_basis`, the Jacobian with
respect to ``P``), the thermal drift a length scale linear in ``dT_max`` or
``alpha`` (:meth:`ThermalDrift.scale_jacobian`), the geometry the parameter
Jacobian of the kinematics. :meth:`EffectSet.joint_offsets` and
:meth:`EffectSet.length_scale` evaluate that first-order composition (all
joint effects at the same table and angles); :meth:`EffectSet.apply` the
composition below. They differ by second-order terms.

Composition order (:data:`EFFECT_ORDER`)
----------------------------------------
Table effects first, then joint effects from the motor outwards::

    geometric -> thermal_drift -> encoder_eccentricity -> backlash -> joint_compliance

``thermal_drift`` scales the lengths of the already-deviated table;
``joint_compliance`` evaluates gravity with the true table and the joint
angles after eccentricity and backlash. An :class:`EffectSet` always applies
its enabled effects in this order, whatever order they were given in.

Per-stop repeatability scatter (random, not a model parameter) is drawn by
:func:`realistic_stop_sigma_rad`; the simulated arm applies it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from station.errors import ConfigError, DataError
from station.models.effect_params import EffectSpec, ParamSpec

__all__ = [
    "EFFECT_ORDER",
    "STEEL_ALPHA_PER_K",
    "COMPLIANCE_BASES",
    "JointEffect",
    "motion_directions",
    "unit_mass_torques",
    "scale_lengths",
    "LENGTH_PARAMS",
    "EffectContext",
    "Geometric",
    "ThermalDrift",
    "EncoderEccentricity",
    "Backlash",
    "JointCompliance",
    "EffectSet",
    "make_effect",
    "eccentricity_amplitude_phase",
    "realistic_effects",
    "realistic_stop_sigma_rad",
    "tcp_compliance_mm_per_N",
]

N_JOINTS = 6
ARCMIN_RAD = math.radians(1.0 / 60.0)

#: linear expansion of steel and cast iron, 1/K (aluminium castings are ~2.3e-5 /K)
STEEL_ALPHA_PER_K = 1.2e-5
#: the thermal expansion coefficient, an option of :class:`ThermalDrift` (a fitted one in a model file)
THERMAL_ALPHA = ParamSpec.of_kind("alpha_per_K", "alpha_per_K")

#: the order in which an :class:`EffectSet` applies its effects
EFFECT_ORDER = ("geometric", "thermal_drift", "encoder_eccentricity", "backlash", "joint_compliance")


# --------------------------------------------------------------------------
# context
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class EffectContext:
    """Per-sample circumstances the effects depend on.

    Attributes
    ----------
    robot : RobotSpec or None
        Mass model for ``joint_compliance`` (required only by it).
    last_dir : array_like, shape (N, 6) or (6,), optional
        Sign of the last motion of each joint, in {-1, 0, +1}; ``None`` = 0.
    warmup_s : float or array_like, shape (N,), optional
        Time since the arm started working (warm-up model of
        ``thermal_drift``); ``None`` = 0 (cold).
    temperature_rise_K : float or array_like, shape (N,), optional
        Measured temperature rise; overrides the warm-up model when given.
    payload_kg : float or array_like, shape (N,)
        Mass at the TCP (``joint_compliance``).
    tcp_force_N : array_like, shape (N, 3) or (3,), optional
        External force on the TCP, base frame (``joint_compliance``); ``None`` = none.
    """

    robot: Any = None
    last_dir: Any = None
    warmup_s: Any = None
    temperature_rise_K: Any = None
    payload_kg: float = 0.0
    tcp_force_N: Any = None


def _q_array(q_rad) -> np.ndarray:
    q = np.asarray(q_rad, dtype=float)
    if q.ndim == 1:
        q = q[None]
    if q.ndim != 2 or q.shape[1] != N_JOINTS:
        raise DataError(f"`q_rad` must have shape (N, 6), got {np.shape(q_rad)}")
    return q


def _per_sample(x, n: int, name: str) -> np.ndarray:
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise DataError(f"context `{name}` must be a scalar or have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"context `{name}` contains non-finite values")
    return arr


def _params(params, n: int, name: str) -> np.ndarray:
    try:
        p = np.asarray(params, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise DataError(f"parameters of `{name}` must be numeric: {exc}") from exc
    if p.size != n:
        raise DataError(f"`{name}` takes {n} parameters, got {p.size}")
    if not np.all(np.isfinite(p)):
        raise DataError(f"parameters of `{name}` contain non-finite values")
    return p


# --------------------------------------------------------------------------
# helpers the effects and their linearisation share
# --------------------------------------------------------------------------
def motion_directions(q_rad, tol_rad: float = 1e-7) -> np.ndarray:
    """Sign of each joint's last motion (N, 6), the rows in motion order; 0 before a joint first moved.

    The context ``last_dir`` of :class:`Backlash` for poses visited one
    after another: a joint that moves less than ``tol_rad`` keeps the
    direction it had.
    """
    q = np.asarray(q_rad, dtype=float)
    d = np.zeros_like(q)
    cur = np.zeros(q.shape[1])
    for k in range(1, q.shape[0]):
        step = q[k] - q[k - 1]
        cur = np.where(np.abs(step) > tol_rad, np.sign(step), cur)
        d[k] = cur
    return d


def unit_mass_torques(dh, q_rad, frame_index: int) -> np.ndarray:
    """Gravity holding torques (N, 6) of 1 kg at the origin of frame ``frame_index`` (3: elbow, 7: TCP), N m.

    The torque of :func:`station.models.robots.gravity_torques` for a point
    mass: ``g e_z . (z_i x (c - o_i))``; the joints after the point do not carry it.
    """
    from station.models import kinematics as kin
    from station.models.robots import GRAVITY_M_S2

    F = kin.frames(dh, _q_array(q_rad))
    c = F[:, frame_index, :3, 3]
    z = F[:, :6, :3, 2]
    o = F[:, :6, :3, 3]
    lever = np.cross(z, c[:, None, :] - o)[:, :, 2]  # mm
    tau = GRAVITY_M_S2 * 1e-3 * lever
    tau[:, frame_index:] = 0.0
    return tau


# --------------------------------------------------------------------------
# the effects
# --------------------------------------------------------------------------
_DH_COLS = (("a", "mm", "length_mm"), ("alpha", "rad", "delta_angle_rad"), ("d", "mm", "length_mm"),
            ("theta", "rad", "delta_angle_rad"), ("beta", "rad", "delta_angle_rad"))
_DH_ROWS = ("1", "2", "3", "4", "5", "6", "TCP")


class _Declared:
    """What every effect says of itself: its parameters' names and its :class:`EffectSpec` (from ``param_specs``)."""

    acts_on = "table"

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.param_specs)

    @property
    def spec(self) -> EffectSpec:
        return EffectSpec(self.name, self.acts_on, self.param_specs)


@dataclass(frozen=True)
class Geometric(_Declared):
    """Deviations of the 35 kinematic parameters (mm, rad).

    Its linearisation is the parameter Jacobian of the kinematics (seed 002
    eq. (7)-(8), :func:`station.models.kinematics.fk_and_param_jacobian`).
    """

    name: str = field(default="geometric", init=False)

    @property
    def param_specs(self) -> tuple:
        return tuple(ParamSpec.of_kind(f"{c}{r}_{u}", kind, u) for r in _DH_ROWS for c, u, kind in _DH_COLS)

    def apply(self, params, dh, q_rad, ctx: EffectContext):
        p = _params(params, 35, self.name)
        return np.asarray(dh, dtype=float) + p.reshape(7, 5), q_rad


def _check_alpha(alpha_per_K) -> float:
    lo, hi = THERMAL_ALPHA.bounds
    if not (isinstance(alpha_per_K, (int, float)) and math.isfinite(alpha_per_K) and lo <= alpha_per_K <= hi):
        raise ConfigError(f"`alpha_per_K` must be finite and within {lo:g}..{hi:g} /K, got {alpha_per_K!r}")
    return float(alpha_per_K)


@dataclass(frozen=True)
class ThermalDrift(_Declared):
    """Link lengths ``a, d`` grow by ``alpha_per_K * dT``; params ``[dT_max_K, tau_s]``.

    :meth:`length_scale` is the relative growth ``alpha dT`` (N,);
    :meth:`scale_jacobian` its derivative with respect to the parameter a
    fit can take as linear: ``dT_max_K`` (warm-up model, ``tau`` fixed) or,
    with a measured temperature rise, ``alpha_per_K``.
    """

    alpha_per_K: float = STEEL_ALPHA_PER_K
    name: str = field(default="thermal_drift", init=False)

    def __post_init__(self) -> None:
        _check_alpha(self.alpha_per_K)

    @property
    def param_specs(self) -> tuple:
        return (ParamSpec.of_kind("dT_max_K", "dT_max_K"), ParamSpec.of_kind("tau_s", "tau_s"))

    def temperature_rise_K(self, params, ctx: EffectContext, n: int) -> np.ndarray:
        """``dT`` per sample (N,): measured if the context has it, else the warm-up model."""
        p = _params(params, 2, self.name)
        if ctx.temperature_rise_K is not None:
            return _per_sample(ctx.temperature_rise_K, n, "temperature_rise_K")
        warm = np.zeros(n) if ctx.warmup_s is None else _per_sample(ctx.warmup_s, n, "warmup_s")
        if p[1] <= 0:
            raise DataError(f"`thermal_drift` tau_s must be > 0, got {p[1]!r}")
        return p[0] * -np.expm1(-np.maximum(warm, 0.0) / p[1])

    def length_scale(self, params, ctx: EffectContext, n: int) -> np.ndarray:
        """Relative growth of the lengths, ``alpha_per_K dT`` (N,)."""
        return self.alpha_per_K * self.temperature_rise_K(params, ctx, n)

    def scale_jacobian(self, params, ctx: EffectContext, n: int) -> tuple[np.ndarray, tuple[str, ...]]:
        """``(d length_scale / d theta (N, 1), (name of theta,))``: ``theta`` is ``alpha_per_K`` when the context
        has a measured rise, else ``dT_max_K`` at the parameters' ``tau_s``. Exact: the scale is linear in both."""
        p = _params(params, 2, self.name)
        if ctx.temperature_rise_K is not None:
            return self.temperature_rise_K(p, ctx, n)[:, None], ("alpha_per_K",)
        return self.length_scale([1.0, p[1]], ctx, n)[:, None], ("dT_max_K",)

    def apply(self, params, dh, q_rad, ctx: EffectContext):
        q = _q_array(q_rad)
        return scale_lengths(dh, self.length_scale(params, ctx, q.shape[0])), q_rad


#: the columns of the kinematic table that are lengths (``a``, ``d``), which the thermal drift scales
LENGTH_COLUMNS = (0, 2)
#: their places in the flat 35-parameter vector (``dh.ravel()``)
LENGTH_PARAMS = np.array([5 * r + c for r in range(7) for c in LENGTH_COLUMNS])


def scale_lengths(dh, growth) -> np.ndarray:
    """The table with its lengths ``a, d`` grown by ``1 + growth`` (per sample, (N,)): (7, 5) when the growth is
    the same for every sample and ``dh`` is one table, else (N, 7, 5)."""
    dh = np.asarray(dh, dtype=float)
    scale = 1.0 + np.asarray(growth, dtype=float)  # (N,)
    cols = list(LENGTH_COLUMNS)
    if np.all(scale == scale[0]) and dh.ndim == 2:
        out = dh.copy()
        out[:, cols] *= scale[0]
        return out
    out = np.array(np.broadcast_to(dh, (scale.size, 7, 5)))
    out[:, :, cols] *= scale[:, None, None]
    return out


class JointEffect(_Declared):
    """An effect on the joint angles, linear in its parameters: ``dq_j = sum_m B_jm(dh, q, ctx) P_jm``.

    ``P`` is the parameter vector as (6, m), joint by joint; the basis ``B``
    (:meth:`joint_basis`, (N, 6, m)) is the effect's Jacobian with respect
    to its parameters, at any parameters: the diagnosis's candidate terms are
    its columns (:mod:`station.analysis.diagnose.terms`). Subclasses give
    ``per_joint`` (``(name template with {j}, ParamSpec kind, unit)`` per
    basis column) and ``joint_basis``.
    """

    per_joint: tuple = ()
    acts_on = "joint"

    @property
    def param_specs(self) -> tuple:
        return tuple(ParamSpec.of_kind(t.format(j=j), kind, unit) for j in range(1, 7) for t, kind, unit in self.per_joint)

    def joint_basis(self, dh, q_rad, ctx: EffectContext, params=None) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def offsets(self, params, dh, q_rad, ctx: EffectContext) -> np.ndarray:
        """``dq = sum_m B_jm P_jm`` (N, 6), rad, of these parameters at ``(dh, q_rad)``."""
        m = len(self.per_joint)
        P = _params(params, 6 * m, self.name).reshape(6, m)
        q = _q_array(q_rad)
        if not np.any(P):
            return np.zeros_like(q)
        return np.einsum("njm,jm->nj", self.joint_basis(dh, q, ctx, P), P)

    def apply(self, params, dh, q_rad, ctx: EffectContext):
        m = len(self.per_joint)
        P = _params(params, 6 * m, self.name).reshape(6, m)
        q = _q_array(q_rad)
        if not np.any(P):
            return dh, q
        B = self.joint_basis(dh, q, ctx, P)
        out = q
        for k in range(m):
            out = out + B[:, :, k] * P[:, k]
        return dh, out


@dataclass(frozen=True)
class EncoderEccentricity(JointEffect):
    """First-harmonic joint error ``s_i sin q_i + c_i cos q_i`` (rad)."""

    name: str = field(default="encoder_eccentricity", init=False)
    per_joint = (("s{j}_rad", "joint_offset_rad", "rad"), ("c{j}_rad", "joint_offset_rad", "rad"))

    def joint_basis(self, dh, q_rad, ctx: EffectContext, params=None) -> np.ndarray:
        q = _q_array(q_rad)
        return np.stack([np.sin(q), np.cos(q)], axis=2)


@dataclass(frozen=True)
class Backlash(JointEffect):
    """Half-width ``b_i`` (rad) against the direction of the last motion (``-b_i sign_i``)."""

    name: str = field(default="backlash", init=False)
    per_joint = (("b{j}_rad", "joint_offset_rad", "rad"),)

    def joint_basis(self, dh, q_rad, ctx: EffectContext, params=None) -> np.ndarray:
        q = _q_array(q_rad)
        if ctx.last_dir is None:
            return np.zeros(q.shape + (1,))
        return -np.sign(np.broadcast_to(np.asarray(ctx.last_dir, dtype=float), q.shape))[:, :, None]


#: the gravity-torque columns joint compliance can carry, in this order: the robot's mass model (with the
#: context's payload and TCP force), 1 kg at the elbow (origin of frame 3), 1 kg at the tool point
COMPLIANCE_BASES = {"mass_model": ("c{j}_rad_per_Nm", "rad/(N m)"), "elbow": ("k{j}_elbow_rad_per_kg", "rad/kg"),
                    "tcp": ("k{j}_tcp_rad_per_kg", "rad/kg")}


@dataclass(frozen=True)
class JointCompliance(JointEffect):
    """Gravity deflection ``-sum_b c_ib g_ib(q)`` over the torque columns of ``basis``.

    ``basis`` (a subset of :data:`COMPLIANCE_BASES`, in its order): the
    default, the robot's mass model alone, has the parameters
    ``c{i}_rad_per_Nm``; ``elbow`` and ``tcp`` add a column per joint of 1
    kg at that point (``k{i}_elbow_rad_per_kg``, ``k{i}_tcp_rad_per_kg``),
    which absorbs a mass distribution (or payload) known only roughly.
    """

    basis: tuple = ("mass_model",)
    name: str = field(default="joint_compliance", init=False)

    def __post_init__(self) -> None:
        b = tuple(self.basis) if isinstance(self.basis, (tuple, list)) else ()
        if not b or any(x not in COMPLIANCE_BASES for x in b) or list(b) != sorted(set(b), key=list(COMPLIANCE_BASES).index):
            raise ConfigError(f"`basis` of joint_compliance must be a non-empty subset of {', '.join(COMPLIANCE_BASES)} "
                              f"in that order, got {self.basis!r}")
        object.__setattr__(self, "basis", b)

    @property
    def per_joint(self) -> tuple:
        return tuple((COMPLIANCE_BASES[b][0], "compliance", COMPLIANCE_BASES[b][1]) for b in self.basis)

    def holding_torques(self, dh, q_rad, ctx: EffectContext, which: str) -> np.ndarray:
        """The torque column ``which`` of :data:`COMPLIANCE_BASES` (N, 6), N m."""
        q = _q_array(q_rad)
        dh_arr = np.asarray(dh, dtype=float)
        if which == "elbow":
            return unit_mass_torques(dh_arr, q, 3)
        if which == "tcp":
            return unit_mass_torques(dh_arr, q, 7)
        if ctx.robot is None:
            raise DataError("`joint_compliance` needs `robot` (mass model) in the effect context")
        from station.models.robots import gravity_torques

        if np.ndim(ctx.payload_kg) == 0:
            tau = np.reshape(gravity_torques(ctx.robot, dh_arr, q, payload_kg=float(ctx.payload_kg)), q.shape)
        else:  # a payload per sample: the arm's own torque plus that mass at the tool point
            load = _per_sample(ctx.payload_kg, q.shape[0], "payload_kg")
            tau = np.reshape(gravity_torques(ctx.robot, dh_arr, q, payload_kg=0.0), q.shape)
            tau = tau + load[:, None] * unit_mass_torques(dh_arr, q, 7)
        if ctx.tcp_force_N is not None:
            tau = tau - _force_torques_Nm(dh_arr, q, ctx.tcp_force_N)
        return tau

    def joint_basis(self, dh, q_rad, ctx: EffectContext, params=None) -> np.ndarray:
        q = _q_array(q_rad)
        P = None if params is None else np.reshape(params, (6, len(self.basis)))
        cols = [np.zeros(q.shape) if P is not None and not np.any(P[:, k]) else -self.holding_torques(dh, q, ctx, b)
                for k, b in enumerate(self.basis)]
        return np.stack(cols, axis=2)


def _force_torques_Nm(dh, q: np.ndarray, force_N) -> np.ndarray:
    """Joint torques (N m, (N, 6)) that a force ``force_N`` (N, base frame) on the TCP exerts: ``J_v^T F``."""
    from station.models import kinematics as kin

    F = np.broadcast_to(np.asarray(force_N, dtype=float), (q.shape[0], 3))
    if not np.all(np.isfinite(F)):
        raise DataError("`tcp_force_N` must be finite")
    Jv = np.reshape(kin.joint_jacobian(dh, q), (q.shape[0], 6, 6))[:, :3, :]  # mm/rad
    return 1e-3 * np.einsum("nki,nk->ni", Jv, F)


def tcp_compliance_mm_per_N(dh, q_rad, c_rad_per_Nm) -> np.ndarray:
    """Translational compliance matrix of the TCP from joint compliance, ``C = J_v diag(c) J_v^T`` (mm/N).

    The linearisation of :class:`JointCompliance` under an external force at
    the TCP: a force ``F`` (N, base frame) displaces the TCP by ``C F`` (mm).
    ``u^T C u`` is the static compliance along the unit direction ``u``
    (ISO 9283 clause 10: displacement per unit load, in the load's direction).

    Parameters
    ----------
    dh : array_like, shape (7, 5)
    q_rad : array_like, shape (6,)
    c_rad_per_Nm : array_like, shape (6,)

    Returns
    -------
    ndarray, shape (3, 3)
    """
    from station.models import kinematics as kin

    c = _params(c_rad_per_Nm, 6, "joint_compliance")
    Jv = np.reshape(kin.joint_jacobian(dh, np.reshape(np.asarray(q_rad, dtype=float), (1, 6))), (6, 6))[:3, :]
    return 1e-3 * (Jv * c) @ Jv.T


_EFFECT_TYPES = {
    "geometric": Geometric,
    "thermal_drift": ThermalDrift,
    "encoder_eccentricity": EncoderEccentricity,
    "backlash": Backlash,
    "joint_compliance": JointCompliance,
}


def make_effect(name: str, **options):
    """Instantiate the effect called ``name`` (options: e.g. ``alpha_per_K``)."""
    try:
        cls = _EFFECT_TYPES[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown effect {name!r}; known effects: {', '.join(EFFECT_ORDER)}") from None
    try:
        return cls(**options)
    except TypeError as exc:
        raise ConfigError(f"bad options for effect {name!r}: {exc}") from exc


def eccentricity_amplitude_phase(params) -> tuple[np.ndarray, np.ndarray]:
    """``(A_rad, phi_rad)`` per joint from ``encoder_eccentricity`` parameters."""
    p = _params(params, 12, "encoder_eccentricity").reshape(6, 2)
    return np.hypot(p[:, 0], p[:, 1]), np.arctan2(p[:, 1], p[:, 0])


# --------------------------------------------------------------------------
# composition
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class EffectSet:
    """An immutable, ordered set of effects with their parameters and switches.

    Build with :meth:`from_params` (or :func:`realistic_effects`); change with
    :meth:`with_params`, :meth:`switched`, :meth:`only` (each returns a new
    set). :meth:`flatten` / :meth:`unflatten` map the parameters of the
    enabled effects (or all, ``include_disabled=True``) to one named vector,
    in :data:`EFFECT_ORDER` and each effect's own parameter order.

    Attributes
    ----------
    effects : tuple
        Effect objects, in :data:`EFFECT_ORDER`.
    params : tuple of ndarray
        One parameter vector per effect.
    enabled : tuple of bool
    """

    effects: tuple
    params: tuple
    enabled: tuple

    def __post_init__(self) -> None:
        if not (len(self.effects) == len(self.params) == len(self.enabled)):
            raise ConfigError("`effects`, `params` and `enabled` must have the same length")
        names = [e.name for e in self.effects]
        if len(set(names)) != len(names):
            raise ConfigError(f"effects must be unique, got {names}")
        order = sorted(range(len(names)), key=lambda i: EFFECT_ORDER.index(names[i]))
        effects = tuple(self.effects[i] for i in order)
        params = []
        for i in order:
            eff = self.effects[i]
            try:
                p = _params(self.params[i], len(eff.param_names), eff.name).copy()
            except DataError as exc:
                raise ConfigError(str(exc)) from exc
            p.setflags(write=False)
            params.append(p)
        object.__setattr__(self, "effects", effects)
        object.__setattr__(self, "params", tuple(params))
        object.__setattr__(self, "enabled", tuple(bool(self.enabled[i]) for i in order))

    # construction -----------------------------------------------------
    @classmethod
    def from_params(cls, params: dict | None = None, enabled=None, options: dict | None = None) -> "EffectSet":
        """Set with every known effect; missing parameters are zero.

        Parameters
        ----------
        params : dict, optional
            ``{effect name: parameter vector}``.
        enabled : iterable of str or dict, optional
            Names switched on (default: those given in ``params``), or
            ``{name: bool}``.
        options : dict, optional
            ``{effect name: {option: value}}`` (e.g.
            ``{"thermal_drift": {"alpha_per_K": 2.3e-5}}``).
        """
        params = dict(params or {})
        options = dict(options or {})
        for key in list(params) + list(options):
            if key not in _EFFECT_TYPES:
                raise ConfigError(f"unknown effect {key!r}; known effects: {', '.join(EFFECT_ORDER)}")
        if enabled is None:
            on = set(params)
        elif isinstance(enabled, dict):
            on = {k for k, v in enabled.items() if v}
        else:
            on = set(enabled)
        for key in on:
            if key not in _EFFECT_TYPES:
                raise ConfigError(f"unknown effect {key!r}; known effects: {', '.join(EFFECT_ORDER)}")
        effects, vecs, flags = [], [], []
        for name in EFFECT_ORDER:
            eff = make_effect(name, **options.get(name, {}))
            effects.append(eff)
            vecs.append(params.get(name, np.zeros(len(eff.param_names))))
            flags.append(name in on)
        if "thermal_drift" not in params:
            # zero rise with a valid time constant, so switching it on is harmless
            vecs[EFFECT_ORDER.index("thermal_drift")] = np.array([0.0, 3600.0])
        return cls(tuple(effects), tuple(vecs), tuple(flags))

    @classmethod
    def none(cls) -> "EffectSet":
        """Every effect present, all switched off (the nominal arm)."""
        return cls.from_params({}, enabled=())

    # access -----------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    @property
    def enabled_names(self) -> tuple[str, ...]:
        return tuple(e.name for e, on in zip(self.effects, self.enabled) if on)

    def _index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(f"unknown effect {name!r}; this set has: {', '.join(self.names)}") from None

    def effect(self, name: str):
        return self.effects[self._index(name)]

    def get(self, name: str) -> np.ndarray:
        """Parameter vector of effect ``name`` (a copy)."""
        return self.params[self._index(name)].copy()

    def is_enabled(self, name: str) -> bool:
        return self.enabled[self._index(name)]

    def with_params(self, name: str, params) -> "EffectSet":
        i = self._index(name)
        vecs = list(self.params)
        vecs[i] = params
        return EffectSet(self.effects, tuple(vecs), self.enabled)

    def switched(self, name: str, on: bool = True) -> "EffectSet":
        i = self._index(name)
        flags = list(self.enabled)
        flags[i] = bool(on)
        return EffectSet(self.effects, self.params, tuple(flags))

    def only(self, *names: str) -> "EffectSet":
        """The same parameters with exactly ``names`` switched on."""
        for n in names:
            self._index(n)
        return EffectSet(self.effects, self.params, tuple(e.name in names for e in self.effects))

    # fitting ------------------------------------------------------------
    def _selected(self, include_disabled: bool) -> list[int]:
        return [i for i, on in enumerate(self.enabled) if on or include_disabled]

    def param_names(self, include_disabled: bool = False) -> tuple[str, ...]:
        """``"effect.param"`` names in the order of :meth:`flatten`."""
        return tuple(
            f"{self.effects[i].name}.{p}" for i in self._selected(include_disabled) for p in self.effects[i].param_names
        )

    def flatten(self, include_disabled: bool = False) -> tuple[np.ndarray, tuple[str, ...]]:
        """All parameters of the (enabled) effects as one vector, with names."""
        sel = self._selected(include_disabled)
        vec = np.concatenate([self.params[i] for i in sel]) if sel else np.zeros(0)
        return vec, self.param_names(include_disabled)

    def unflatten(self, vector, include_disabled: bool = False) -> "EffectSet":
        """Inverse of :meth:`flatten`: a new set with these parameter values."""
        sel = self._selected(include_disabled)
        sizes = [len(self.effects[i].param_names) for i in sel]
        try:
            v = np.asarray(vector, dtype=float).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise DataError(f"`vector` must be numeric: {exc}") from exc
        if v.size != sum(sizes):
            raise DataError(f"`vector` must have {sum(sizes)} values ({', '.join(self.names[i] for i in sel)}), got {v.size}")
        vecs = list(self.params)
        offset = 0
        for i, n in zip(sel, sizes):
            vecs[i] = v[offset : offset + n]
            offset += n
        return EffectSet(self.effects, tuple(vecs), self.enabled)

    # evaluation -----------------------------------------------------------
    def apply(self, dh, q_rad, ctx: EffectContext | None = None):
        """Apply the enabled effects in :data:`EFFECT_ORDER`.

        Parameters
        ----------
        dh : array_like, shape (7, 5) or (N, 7, 5)
            Nominal table.
        q_rad : array_like, shape (N, 6)
            Joint angles the controller believes (encoder angles).
        ctx : EffectContext, optional

        Returns
        -------
        dh_eff : ndarray, shape (7, 5) or (N, 7, 5)
        q_eff : ndarray, shape (N, 6)
            Feed both to ``kinematics.fk`` for the true tool pose.
        """
        ctx = ctx or EffectContext()
        dh_out = np.asarray(dh, dtype=float)
        q_out = _q_array(q_rad)
        for eff, p, on in zip(self.effects, self.params, self.enabled):
            if on:
                dh_out, q_out = eff.apply(p, dh_out, q_out, ctx)
        return dh_out, q_out

    def joint_offsets(self, dh, q_rad, ctx: EffectContext | None = None) -> np.ndarray:
        """First-order joint error ``dq`` (N, 6), rad: every enabled joint effect at the same ``(dh, q_rad)``, summed.

        The linear model the diagnosis fits (:mod:`station.analysis.diagnose.terms`)
        and an extended model evaluates (:mod:`station.models.arm_extended`);
        :meth:`apply` composes the effects instead, which differs by second-order terms.
        """
        ctx = ctx or EffectContext()
        q = _q_array(q_rad)
        dq = np.zeros_like(q)
        for eff, p, on in zip(self.effects, self.params, self.enabled):
            if on and isinstance(eff, JointEffect):
                dq = dq + eff.offsets(p, dh, q, ctx)
        return dq

    def length_scale(self, n: int, ctx: EffectContext | None = None) -> np.ndarray | None:
        """Relative growth of the lengths ``a, d`` (N,) of the enabled thermal drift, None without one."""
        ctx = ctx or EffectContext()
        for eff, p, on in zip(self.effects, self.params, self.enabled):
            if on and isinstance(eff, ThermalDrift):
                return eff.length_scale(p, ctx, n)
        return None

    # records --------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-able description: ``{name: {"enabled", "params": {pname: value}}}``."""
        out = {}
        for eff, p, on in zip(self.effects, self.params, self.enabled):
            entry = {"enabled": on, "params": dict(zip(eff.param_names, p.tolist()))}
            if isinstance(eff, ThermalDrift):
                entry["alpha_per_K"] = eff.alpha_per_K
            if isinstance(eff, JointCompliance) and eff.basis != ("mass_model",):
                entry["basis"] = list(eff.basis)
            out[eff.name] = entry
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "EffectSet":
        """Inverse of :meth:`to_dict` (missing parameters are zero)."""
        if not isinstance(data, dict):
            raise ConfigError(f"effects description must be a dict, got {type(data).__name__}")
        params, enabled, options = {}, [], {}
        for name, entry in data.items():
            if name not in _EFFECT_TYPES:
                raise ConfigError(f"unknown effect {name!r}; known effects: {', '.join(EFFECT_ORDER)}")
            opts = {}
            if "alpha_per_K" in entry:
                opts["alpha_per_K"] = float(entry["alpha_per_K"])
            if "basis" in entry:
                opts["basis"] = tuple(entry["basis"]) if isinstance(entry["basis"], list) else entry["basis"]
            eff = make_effect(name, **opts)
            values = entry.get("params", {})
            unknown = set(values) - set(eff.param_names)
            if unknown:
                raise ConfigError(f"effect {name!r} has no parameter(s) {sorted(unknown)}")
            params[name] = [float(values.get(p, 0.0)) for p in eff.param_names]
            if entry.get("enabled", True):
                enabled.append(name)
            if opts:
                options[name] = opts
        return cls.from_params(params, enabled=enabled, options=options)


# --------------------------------------------------------------------------
# realistic magnitudes
# --------------------------------------------------------------------------
def _reach_mm(robot) -> float:
    dh = np.asarray(robot.dh_nominal)
    return float(np.sum(np.abs(dh[:, 0])) + np.sum(np.abs(dh[1:, 2])))


def realistic_effects(robot, rng: np.random.Generator) -> EffectSet:
    """Draw the error effects of a plant-floor arm after overhaul, uncalibrated.

    Target: pose accuracy AP of a few mm and vAP of tenths of a mm over the
    ISO 9283 cube, as seed 000 Table 3 reports for an overhauled NACHI 8608
    (AP 3.2-4.7 mm, vAP 0.4-1.2 mm). Magnitudes and their sources:

    * ``geometric``: lengths ``a, d`` N(0, 0.1 mm + 1e-4 * reach); twists
      ``alpha`` N(0, 0.02 deg); zero offsets ``theta`` N(0, 0.05 deg)
      (re-mastering after motor or reducer exchange); Hayati ``beta``
      N(0, 0.01 deg) on rows whose next axis is nominally parallel (where it
      replaces ``d``), zero elsewhere; the tool row gets lengths only. For
      scale, seed 002 Table 3 shows a never-calibrated cobot deviating by up
      to 2.8 mm and 0.5 deg.
    * ``joint_compliance``: each joint deflects by U(0.5, 2) arcmin at the
      largest gravity torque it sees (64 random poses, rated payload), the
      order of the torsional deflection of precision cycloidal reducers near
      rated torque; a joint without gravity load (vertical axis) gets 0.
    * ``backlash``: half-width U(0.1, 0.4) arcmin (lost motion <= 1 arcmin
      after overhaul).
    * ``thermal_drift``: dT_max U(2, 6) K, tau U(1800, 5400) s, steel
      (1.2e-5 /K).
    * ``encoder_eccentricity``: amplitude U(0.05, 0.3) arcmin, uniform phase.

    Parameters
    ----------
    robot : RobotSpec
    rng : numpy.random.Generator

    Returns
    -------
    EffectSet
        Every effect switched on.
    """
    from station.models.robots import gravity_torques

    dh = np.asarray(robot.dh_nominal)
    reach = _reach_mm(robot)
    geo = np.zeros((7, 5))
    sig_len = 0.1 + 1e-4 * reach
    geo[:, 0] = rng.normal(0.0, sig_len, 7)
    geo[:, 2] = rng.normal(0.0, sig_len, 7)
    geo[:6, 1] = rng.normal(0.0, math.radians(0.02), 6)
    geo[:6, 3] = rng.normal(0.0, math.radians(0.05), 6)
    parallel = np.abs(np.sin(dh[:6, 1])) < 1e-6
    geo[:6, 4] = np.where(parallel, rng.normal(0.0, math.radians(0.01), 6), 0.0)
    geo[6, [1, 3, 4]] = 0.0

    lim = np.asarray(robot.joint_limits_rad)
    lo = np.maximum(lim[:, 0], -np.pi)
    hi = np.minimum(lim[:, 1], np.pi)
    q_rand = lo + (hi - lo) * rng.random((64, 6))
    tau = np.abs(gravity_torques(robot, dh, q_rand, payload_kg=float(robot.rated_payload_kg)))
    tau_ref = tau.max(axis=0)
    defl = rng.uniform(0.5, 2.0, 6) * ARCMIN_RAD
    loaded = tau_ref > 1e-3 * max(float(tau_ref.max()), 1e-12)
    comp = np.where(loaded, defl / np.where(loaded, tau_ref, 1.0), 0.0)

    back = rng.uniform(0.1, 0.4, 6) * ARCMIN_RAD
    thermal = np.array([rng.uniform(2.0, 6.0), rng.uniform(1800.0, 5400.0)])
    amp = rng.uniform(0.05, 0.3, 6) * ARCMIN_RAD
    phase = rng.uniform(0.0, 2.0 * np.pi, 6)
    ecc = np.stack([amp * np.cos(phase), amp * np.sin(phase)], axis=1).reshape(-1)
    return EffectSet.from_params(
        {
            "geometric": geo.reshape(-1),
            "thermal_drift": thermal,
            "encoder_eccentricity": ecc,
            "backlash": back,
            "joint_compliance": comp,
        }
    )


def realistic_stop_sigma_rad(robot, rng: np.random.Generator, sigma_mm: float | None = None) -> np.ndarray:
    """Per-joint 1-sigma of the random stopping error (repeatability scatter).

    The arm adds an independent Gaussian joint offset at every stop. Its
    size is set so that the TCP scatter at the home pose has ``sigma_mm``
    per coordinate (default drawn uniformly from the model's
    ``robot.stop_scatter_mm``), which gives ISO 9283
    ``RP = l_bar + 3 S_l ~ 3.6 sigma``: for the seed's large arm
    U(0.012, 0.04) mm, RP about 0.05-0.15 mm, the range of seed 000 Table 3
    (0.07-0.20 mm); for a UR5e U(0.005, 0.011) mm, the RP a real one measured
    (0.012-0.024 mm, issue 42).

    Parameters
    ----------
    robot : RobotSpec
    rng : numpy.random.Generator
    sigma_mm : float, optional
        Target TCP scatter per coordinate (mm).

    Returns
    -------
    sigma_rad : ndarray, shape (6,)
        The same value for every joint.
    """
    from station.models.kinematics import joint_jacobian

    if sigma_mm is None:
        sigma_mm = float(rng.uniform(*getattr(robot, "stop_scatter_mm", (0.012, 0.04))))
    if not (math.isfinite(sigma_mm) and sigma_mm >= 0):
        raise ConfigError(f"`sigma_mm` must be finite and >= 0, got {sigma_mm!r}")
    J = joint_jacobian(robot.dh_nominal, robot.home_q_rad)[:3]
    gain = math.sqrt(float(np.trace(J @ J.T)) / 3.0)
    return np.full(6, sigma_mm / gain)
