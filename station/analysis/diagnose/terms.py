"""Candidate model extensions of the arm diagnosis: one :class:`Term` per (effect, joint).

Every named effect of :mod:`station.models.effects` enters the diagnosis as
its linearisation about the nominal arm, computed by the effect's own
functions (the effects are arcminutes and micrometres per kelvin, so the
first-order Taylor term is exact to far below the instrument's noise): a
term's features are the Jacobian of the effect with respect to its
parameters, one joint's columns of it.

``geometric``
    The DH + Hayati deviations (seed 002 eq. (3), (7)-(8)) that
    :func:`station.analysis.arm_identification.identify` finds identifiable
    on the training poses; the table ``dh + delta``.
``encoder_eccentricity`` (joint j)
    ``dq_j = s_j sin q_j + c_j cos q_j`` (rad): the columns of
    :meth:`EncoderEccentricity.joint_basis <station.models.effects.EncoderEccentricity.joint_basis>`.
``backlash`` (joint j)
    ``dq_j = -b_j d_j`` with ``d_j`` the direction of the last motion of
    joint ``j`` taken from the row order (:func:`station.models.effects.motion_directions`).
``joint_compliance`` (joint j)
    ``dq_j = -c_j g_j(q) - k_j g^TCP_j(q)``: ``g_j`` the gravity holding
    torque of the robot's mass model (with the file's ``load`` as payload
    when given), ``g^TCP_j`` that of 1 kg at the tool point
    (:class:`station.models.effects.JointCompliance` with the basis
    ``mass_model, tcp``). The second column is the small basis that absorbs
    a mass distribution (or payload) the station knows only roughly. Without
    a mass model (a model file) the basis is 1 kg at the elbow (origin of
    frame 3) and 1 kg at the tool point (``elbow, tcp``).
``thermal_drift``
    Link lengths ``a, d`` scaled by ``1 + alpha dT``
    (:meth:`station.models.effects.ThermalDrift.scale_jacobian`): with a
    ``temperature`` column ``dT = T - T_first`` and the parameter is
    ``alpha_per_K``; with only ``t`` the warm-up ``dT = dT_max (1 - exp(-t / tau))``
    at the station's steel ``alpha``, ``dT_max`` linear, ``tau`` on a grid.

No other candidate is added: a payload-dependent error is covered by the
compliance basis (its TCP column) and a constant joint offset is part of
``geometric`` (theta).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.models.effects import (
    STEEL_ALPHA_PER_K,
    Backlash,
    EffectContext,
    EncoderEccentricity,
    JointCompliance,
    ThermalDrift,
)

__all__ = ["Term", "joint_terms", "thermal_terms", "compliance_effect", "TAU_GRID_S"]

#: warm-up time constants tried when only ``t`` is known (s)
TAU_GRID_S = (300.0, 600.0, 1200.0, 1800.0, 2700.0, 3600.0, 5400.0, 7200.0, 10800.0)
#: a joint that moved less than this (deg) over the whole file is "constant"
MIN_JOINT_RANGE_DEG = 1.0
#: encoder eccentricity needs a joint swept at least this far (deg): over a shorter arc its sine and cosine
#: are an offset and a slope (geometry's theta, a scale) plus a curvature the noise can fake, and the
#: once-per-turn error fitted there extrapolates off the arc (a FANUC-like J3 swept 39 deg in the training
#: poses named eccentricity[3]: held-out error 0.244 mm against geometry's 0.171)
MIN_ECCENTRICITY_RANGE_DEG = 90.0
#: joint compliance needs its torque to vary over at least this share of the range it takes over the joint
#: space: below that its deflection is told from geometry over a sliver of torques and extrapolates off it
#: (a FANUC-like J2 swept 36 deg named compliance[2]: held-out error 0.385 mm against geometry's 0.159)
MIN_COMPLIANCE_TORQUE_SHARE = 0.5


@dataclass(frozen=True)
class Term:
    """One candidate: its effect, joint (1-based or None), parameter names and per-row features.

    ``kind`` is ``"geometric"`` (``index``: free columns of the 35), ``"joint"``
    (``features`` (N, k): ``dq_joint = features @ theta``) or ``"scale"``
    (``features`` (N, 1): lengths scaled by ``1 + features @ theta``).
    ``extra`` holds what the parameters need to be read (``tau_s``, the basis).
    ``fitted_dof`` counts parameters chosen outside the linear fit (``tau``).
    """

    effect: str
    joint: int | None
    kind: str
    param_names: tuple
    features: np.ndarray | None = None
    index: np.ndarray | None = None
    extra: dict = field(default_factory=dict)
    fitted_dof: int = 0

    @property
    def key(self) -> str:
        return self.effect if self.joint is None else f"{self.effect}[{self.joint}]"

    @property
    def k(self) -> int:
        return len(self.param_names)


def _spread_poses(robot, n: int = 400) -> np.ndarray:
    """Poses spread over the joint space (the robot's limits, else a turn), seeded."""
    lo, hi = np.full(6, -np.pi), np.full(6, np.pi)
    if robot is not None:
        lim = np.asarray(robot.joint_limits_rad, dtype=float)
        lo, hi = np.maximum(lim[:, 0], lo), np.minimum(lim[:, 1], hi)
    return np.random.default_rng(0).uniform(lo, hi, (n, 6))


def compliance_effect(robot) -> JointCompliance:
    """The compliance the diagnosis tests: the robot's mass model and 1 kg at the TCP, or without a mass model
    1 kg at the elbow and 1 kg at the TCP."""
    return JointCompliance(basis=("mass_model", "tcp") if robot is not None else ("elbow", "tcp"))


def _holding_torques(comp: JointCompliance, dh_nominal, q, ctx) -> np.ndarray:
    """The sum of the compliance basis's holding torques (N, 6), N m: the arm's masses (without a mass model:
    1 kg at the elbow) and 1 kg at the TCP."""
    return comp.holding_torques(dh_nominal, q, ctx, comp.basis[0]) + comp.holding_torques(dh_nominal, q, ctx, "tcp")


def joint_terms(dh_nominal, q_rad, last_dir, *, robot=None, load_kg=None) -> tuple[list[Term], dict]:
    """Candidate joint terms and ``{key: reason}`` for those that cannot be tested on these rows.

    Each term's features are one joint's columns of its effect's Jacobian
    (:meth:`station.models.effects.JointEffect.joint_basis`) at the nominal
    table and these angles.
    """
    q = np.asarray(q_rad, dtype=float)
    terms: list[Term] = []
    untestable: dict = {}
    rng_deg = np.degrees(q.max(axis=0) - q.min(axis=0))
    ctx = EffectContext(robot=robot, last_dir=last_dir,
                        payload_kg=0.0 if load_kg is None else np.asarray(load_kg, dtype=float))
    ecc, back, comp = EncoderEccentricity(), Backlash(), compliance_effect(robot)
    B_ecc = ecc.joint_basis(dh_nominal, q, ctx)
    B_back = back.joint_basis(dh_nominal, q, ctx)
    B_comp = comp.joint_basis(dh_nominal, q, ctx)
    if robot is not None:
        basis_note = "robot mass model" + (" with the file's load" if load_kg is not None else "") + " + 1 kg at the TCP"
    else:
        basis_note = "1 kg at the elbow + 1 kg at the TCP (no mass model)"
    # the share of its range over the whole joint space (poses spread within the limits) each joint's
    # holding torque spans in these poses
    no_load = EffectContext(robot=robot)
    full = _holding_torques(comp, dh_nominal, _spread_poses(robot), no_load)
    share = np.ptp(_holding_torques(comp, dh_nominal, q, no_load), axis=0) / np.maximum(np.ptp(full, axis=0), 1e-12)
    for j in range(6):
        J = j + 1
        const = rng_deg[j] < MIN_JOINT_RANGE_DEG
        why_const = f"q{J} is constant (range {rng_deg[j]:.3g} deg < {MIN_JOINT_RANGE_DEG:g} deg)"
        # encoder eccentricity
        if const:
            untestable[f"encoder_eccentricity[{J}]"] = why_const
        elif rng_deg[j] < MIN_ECCENTRICITY_RANGE_DEG:
            untestable[f"encoder_eccentricity[{J}]"] = (
                f"q{J} spans {rng_deg[j]:.3g} deg, less than the {MIN_ECCENTRICITY_RANGE_DEG:g} deg a once-per-turn "
                "error needs to be told from an offset and a slope")
        else:
            terms.append(Term("encoder_eccentricity", J, "joint", _joint_names(ecc, J), B_ecc[:, j, :]))
        # backlash
        d = np.asarray(last_dir, dtype=float)[:, j]
        if const:
            untestable[f"backlash[{J}]"] = why_const
        elif not (np.any(d > 0) and np.any(d < 0)):
            untestable[f"backlash[{J}]"] = (f"joint {J} is reached from one direction only, so lost motion "
                                             "cannot be told from a zero offset")
        else:
            terms.append(Term("backlash", J, "joint", _joint_names(back, J), B_back[:, j, :]))
        # compliance
        cols, names = [], []
        for col, name in zip(B_comp[:, j, :].T, _joint_names(comp, J)):
            if np.sqrt(np.mean(col ** 2)) <= 1e-6:
                continue
            if cols:  # a basis column that repeats the shape of one kept adds nothing but a parameter
                K = np.column_stack(cols)
                coef, *_ = np.linalg.lstsq(K, col, rcond=None)
                if np.linalg.norm(col - K @ coef) < 1e-3 * np.linalg.norm(col):
                    continue
            cols.append(col)
            names.append(name)
        if const:
            untestable[f"joint_compliance[{J}]"] = why_const
        elif cols and share[j] < MIN_COMPLIANCE_TORQUE_SHARE:
            untestable[f"joint_compliance[{J}]"] = (
                f"joint {J}'s gravity torque spans {100 * share[j]:.0f} % of its range over the joint space, less than "
                f"the {100 * MIN_COMPLIANCE_TORQUE_SHARE:.0f} % a deflection needs to be told from geometry")
        elif not cols:
            untestable[f"joint_compliance[{J}]"] = f"gravity puts no torque on joint {J} in these poses (a vertical axis, or the masses lie on it)"
        else:
            terms.append(Term("joint_compliance", J, "joint", tuple(names), np.column_stack(cols),
                              extra={"basis": basis_note}))
    return terms, untestable


def _joint_names(effect, joint: int) -> tuple[str, ...]:
    """The parameter names of ``effect`` for one joint (1-based)."""
    m = len(effect.per_joint)
    return effect.param_names[(joint - 1) * m: joint * m]


def thermal_terms(t_s=None, temperature_c=None) -> tuple[list[Term], str | None]:
    """Variants of the ``thermal_drift`` candidate (one per ``tau`` when only ``t`` is known), or the reason why none."""
    thermal = ThermalDrift()
    if temperature_c is not None:
        T = np.asarray(temperature_c, dtype=float)
        dT = T - T.min()  # order-free: the coolest row is the reference
        if np.ptp(T) < 0.05:
            return [], f"temperature is constant (range {np.ptp(T):.3g} K)"
        feat, names = thermal.scale_jacobian([0.0, 1.0], EffectContext(temperature_rise_K=dT), T.size)
        return [Term("thermal_drift", None, "scale", names, feat, extra={"dT_source": "temperature column"})], None
    if t_s is None:
        return [], "no time or temperature column"
    t = np.asarray(t_s, dtype=float)
    t = t - t.min()
    span = float(np.ptp(t))
    if span < 0.1 * TAU_GRID_S[0]:
        return [], f"the file spans {span:.3g} s, too short for a warm-up (shortest time constant {TAU_GRID_S[0]:g} s)"
    out = []
    for tau in TAU_GRID_S:
        feat, names = thermal.scale_jacobian([0.0, tau], EffectContext(warmup_s=t), t.size)
        out.append(Term("thermal_drift", None, "scale", names, feat,
                        extra={"tau_s": tau, "alpha_per_K": STEEL_ALPHA_PER_K, "dT_source": "warm-up model from t"},
                        fitted_dof=1))
    return out, None
