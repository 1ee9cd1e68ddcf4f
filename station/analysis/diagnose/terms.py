"""Candidate model extensions of the arm diagnosis: one :class:`Term` per (effect, joint).

Every named effect of :mod:`station.models.effects` enters the diagnosis in
its linear form (the effects are arcminutes and micrometres per kelvin, so
the first-order Taylor term is exact to far below the instrument's noise):

``geometric``
    The DH + Hayati deviations (seed 002 eq. (3), (7)-(8)) that
    :func:`station.analysis.arm_identification.identify` finds identifiable
    on the training poses; the table ``dh + delta``.
``encoder_eccentricity`` (joint j)
    ``dq_j = s_j sin q_j + c_j cos q_j`` (rad).
``backlash`` (joint j)
    ``dq_j = -b_j d_j`` with ``d_j`` the direction of the last motion of
    joint ``j`` taken from the row order (:func:`last_motion_direction`).
``joint_compliance`` (joint j)
    ``dq_j = -c_j g_j(q) - k_j g^TCP_j(q)``: ``g_j`` the gravity holding
    torque of the robot's mass model (with the file's ``load`` as payload
    when given), ``g^TCP_j`` that of 1 kg at the tool point. The second
    column is the small basis that absorbs a mass distribution (or payload)
    the station knows only roughly. Without a mass model (a model file) the
    basis is 1 kg at the elbow (origin of frame 3) and 1 kg at the tool point.
``thermal_drift``
    Link lengths ``a, d`` scaled by ``1 + alpha dT``: with a ``temperature``
    column ``dT = T - T_first`` and the parameter is ``alpha_per_K``; with
    only ``t`` the warm-up ``dT = dT_max (1 - exp(-t / tau))`` at the
    station's steel ``alpha`` (1.2e-5 /K), ``dT_max`` linear, ``tau`` on a grid.

No other candidate is added: a payload-dependent error is covered by the
compliance basis (its TCP column) and a constant joint offset is part of
``geometric`` (theta).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.models import kinematics as kin
from station.models.robots import GRAVITY_M_S2, gravity_torques

__all__ = ["Term", "last_motion_direction", "joint_terms", "thermal_terms", "STEEL_ALPHA_PER_K", "TAU_GRID_S"]

STEEL_ALPHA_PER_K = 1.2e-5
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


def last_motion_direction(q_rad: np.ndarray, tol_rad: float = 1e-7) -> np.ndarray:
    """Sign of the last motion of each joint (N, 6) from the row order; 0 before a joint first moved."""
    q = np.asarray(q_rad, dtype=float)
    d = np.zeros_like(q)
    step = np.diff(q, axis=0)
    cur = np.zeros(q.shape[1])
    for k in range(1, q.shape[0]):
        moved = np.abs(step[k - 1]) > tol_rad
        cur = np.where(moved, np.sign(step[k - 1]), cur)
        d[k] = cur
    return d


def _unit_mass_torques(dh, q_rad, frame_index: int) -> np.ndarray:
    """Gravity holding torques (N, 6) of 1 kg at the origin of frame ``frame_index`` (N m)."""
    F = kin.frames(dh, q_rad)
    c = F[:, frame_index, :3, 3]
    z = F[:, :6, :3, 2]
    o = F[:, :6, :3, 3]
    lever = np.cross(z, c[:, None, :] - o)[:, :, 2]  # mm
    tau = GRAVITY_M_S2 * 1e-3 * lever
    tau[:, frame_index:] = 0.0  # joints after the point do not carry it
    return tau


def _spread_poses(robot, n: int = 400) -> np.ndarray:
    """Poses spread over the joint space (the robot's limits, else a turn), seeded."""
    lo, hi = np.full(6, -np.pi), np.full(6, np.pi)
    if robot is not None:
        lim = np.asarray(robot.joint_limits_rad, dtype=float)
        lo, hi = np.maximum(lim[:, 0], lo), np.minimum(lim[:, 1], hi)
    return np.random.default_rng(0).uniform(lo, hi, (n, 6))


def _holding_torques(robot, dh_nominal, q) -> np.ndarray:
    """Gravity holding torques (N, 6) of the arm's masses (without a mass model: 1 kg at the elbow) and 1 kg at
    the TCP, N m."""
    arm = gravity_torques(robot, dh_nominal, q, payload_kg=0.0) if robot is not None else \
        _unit_mass_torques(dh_nominal, q, 3)
    return arm + _unit_mass_torques(dh_nominal, q, 7)


def joint_terms(dh_nominal, q_rad, last_dir, *, robot=None, load_kg=None) -> tuple[list[Term], dict]:
    """Candidate joint terms and ``{key: reason}`` for those that cannot be tested on these rows."""
    q = np.asarray(q_rad, dtype=float)
    terms: list[Term] = []
    untestable: dict = {}
    rng_deg = np.degrees(q.max(axis=0) - q.min(axis=0))
    tcp = _unit_mass_torques(dh_nominal, q, 7)
    if robot is not None:
        base = gravity_torques(robot, dh_nominal, q, payload_kg=0.0)
        if load_kg is not None:
            base = base + np.asarray(load_kg, dtype=float)[:, None] * tcp
        basis = [(base, "c{j}_rad_per_Nm"), (tcp, "k{j}_tcp_rad_per_kg")]
        basis_note = "robot mass model" + (" with the file's load" if load_kg is not None else "") + " + 1 kg at the TCP"
    else:
        elbow = _unit_mass_torques(dh_nominal, q, 3)
        basis = [(elbow, "k{j}_elbow_rad_per_kg"), (tcp, "k{j}_tcp_rad_per_kg")]
        basis_note = "1 kg at the elbow + 1 kg at the TCP (no mass model)"
    # the share of its range over the whole joint space (poses spread within the limits) each joint's
    # holding torque spans in these poses
    full = _holding_torques(robot, dh_nominal, _spread_poses(robot))
    share = np.ptp(_holding_torques(robot, dh_nominal, q), axis=0) / np.maximum(np.ptp(full, axis=0), 1e-12)
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
            terms.append(Term("encoder_eccentricity", J, "joint", (f"s{J}_rad", f"c{J}_rad"),
                              np.column_stack([np.sin(q[:, j]), np.cos(q[:, j])])))
        # backlash
        d = np.asarray(last_dir, dtype=float)[:, j]
        if const:
            untestable[f"backlash[{J}]"] = why_const
        elif not (np.any(d > 0) and np.any(d < 0)):
            untestable[f"backlash[{J}]"] = (f"joint {J} is reached from one direction only, so lost motion "
                                             "cannot be told from a zero offset")
        else:
            terms.append(Term("backlash", J, "joint", (f"b{J}_rad",), -d[:, None]))
        # compliance
        cols, names = [], []
        for g, name in basis:
            col = g[:, j]
            if np.sqrt(np.mean(col ** 2)) <= 1e-6:
                continue
            if cols:  # a basis column that repeats the shape of one kept adds nothing but a parameter
                K = np.column_stack(cols)
                coef, *_ = np.linalg.lstsq(K, -col, rcond=None)
                if np.linalg.norm(-col - K @ coef) < 1e-3 * np.linalg.norm(col):
                    continue
            cols.append(-col)
            names.append(name.format(j=J))
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


def thermal_terms(t_s=None, temperature_c=None) -> tuple[list[Term], str | None]:
    """Variants of the ``thermal_drift`` candidate (one per ``tau`` when only ``t`` is known), or the reason why none."""
    if temperature_c is not None:
        T = np.asarray(temperature_c, dtype=float)
        dT = T - T.min()  # order-free: the coolest row is the reference
        if np.ptp(T) < 0.05:
            return [], f"temperature is constant (range {np.ptp(T):.3g} K)"
        return [Term("thermal_drift", None, "scale", ("alpha_per_K",), dT[:, None],
                     extra={"dT_source": "temperature column"})], None
    if t_s is None:
        return [], "no time or temperature column"
    t = np.asarray(t_s, dtype=float)
    t = t - t.min()
    span = float(np.ptp(t))
    if span < 0.1 * TAU_GRID_S[0]:
        return [], f"the file spans {span:.3g} s, too short for a warm-up (shortest time constant {TAU_GRID_S[0]:g} s)"
    out = []
    for tau in TAU_GRID_S:
        feat = STEEL_ALPHA_PER_K * -np.expm1(-np.maximum(t, 0.0) / tau)
        out.append(Term("thermal_drift", None, "scale", ("dT_max_K",), feat[:, None],
                        extra={"tau_s": tau, "alpha_per_K": STEEL_ALPHA_PER_K, "dT_source": "warm-up model from t"},
                        fitted_dof=1))
    return out, None


