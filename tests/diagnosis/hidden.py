"""Hidden effects for the diagnosis tests and bench: a random joint, a magnitude near detectability."""

from __future__ import annotations

import numpy as np

from fakes.sim.diagnosis_data import simulate_arm_data
from station.models import kinematics as kin
from station.models.effects import EffectSet, realistic_effects

JOINT_EFFECTS = ("encoder_eccentricity", "backlash", "joint_compliance")


def hidden_params(robot, effect: str, joint: int | None, rng) -> np.ndarray:
    """A unit-shape parameter vector for ``effect`` on ``joint`` (1-based; None for thermal)."""
    if effect == "thermal_drift":
        return np.array([1.0, rng.uniform(1200.0, 3600.0)])
    p = np.zeros(12 if effect == "encoder_eccentricity" else 6)
    j = joint - 1
    small = 1e-4  # rad: small enough that the displacement scales linearly
    if effect == "encoder_eccentricity":
        ph = rng.uniform(0, 2 * np.pi)
        p[2 * j:2 * j + 2] = small * np.array([np.cos(ph), np.sin(ph)])
    elif effect == "backlash":
        p[j] = small
    else:
        p[j] = small / _max_torque(robot)[j]
    return p


def _max_torque(robot) -> np.ndarray:
    from station.models.robots import gravity_torques

    q = np.random.default_rng(0).uniform(-2, 2, (64, 6))
    return np.maximum(np.abs(gravity_torques(robot, robot.dh_nominal, q)).max(axis=0), 1e-9)


def compliance_joints(robot) -> list[int]:
    """Joints that gravity loads (joint 1 and 6 of the library arms carry none)."""
    from station.models.robots import gravity_torques

    q = np.random.default_rng(0).uniform(-2, 2, (64, 6))
    tau = np.abs(gravity_torques(robot, robot.dh_nominal, q)).max(axis=0)
    return [j + 1 for j in range(6) if tau[j] > 1e-3 * tau.max()]


def _geometric_basis(robot, probe) -> np.ndarray:
    """Columns (3n, k) of what a geometric fit can absorb at the probe's poses, in the instrument frame:
    the 35 kinematic parameters (seed 002 eq. (7)-(8)) and a small move of the instrument frame."""
    R = probe.base_T[:3, :3]
    J = kin.param_jacobian(robot.dh_nominal, probe.q_rad)  # (n, 3, 35), robot base frame
    J = np.einsum("ij,njk->nik", R, J)
    p = probe.true_points(robot)
    shift = np.broadcast_to(np.eye(3), (p.shape[0], 3, 3))
    turn = np.stack([np.cross(np.eye(3)[k], p) for k in range(3)], axis=2)  # (n, 3, 3): e_k x p
    return np.concatenate([J, shift, turn], axis=2).reshape(-1, 35 + 6)


def _unabsorbed_rms(basis: np.ndarray, d: np.ndarray) -> float:
    """RMS (3-D, per point) of the displacement ``d`` (n, 3) that no geometric error can mimic."""
    flat = d.reshape(-1)
    scale = np.linalg.norm(basis, axis=0)
    scale[scale == 0] = 1.0
    coef, *_ = np.linalg.lstsq(basis / scale, flat, rcond=1e-10)
    rest = (flat - (basis / scale) @ coef).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(rest ** 2, axis=1))))


def make_case(robot, hidden: list, rng, *, n: int = 160, strength=(0.6, 1.0)):
    """Data with realistic geometric errors plus ``hidden`` [(effect, joint)], each scaled so that the
    part of its tool-point displacement that no geometric error can mimic (the part a diagnosis can
    see once the geometric step has fitted the arm) has an RMS of ``U(strength)`` times the RMS of the
    measurement and stopping noise."""
    base = realistic_effects(robot, rng)
    params = {"geometric": base.get("geometric")}
    for effect, joint in hidden:
        unit = hidden_params(robot, effect, joint, rng)
        prev = params.get(effect)
        params[effect] = unit if prev is None else (prev + unit if effect != "thermal_drift" else unit)
    seed = int(rng.integers(2 ** 32))
    probe = simulate_arm_data(robot, EffectSet.from_params({"geometric": params["geometric"]}),
                              np.random.default_rng(seed), n=n)
    noise_rms = float(np.sqrt(np.mean(np.sum((probe.xyz_mm - probe.true_points(robot)) ** 2, axis=1))))
    geo_only = probe.true_points(robot)
    basis = _geometric_basis(robot, probe)
    for effect, joint in hidden:
        one = {"geometric": params["geometric"], effect: hidden_params(robot, effect, joint, rng) * 0}
        # displacement of this effect alone at unit size, then the scale that gives the drawn strength
        unit = _unit_vector(effect, joint, params[effect])
        one[effect] = unit
        d = probe.true_points(robot, EffectSet.from_params(one)) - geo_only
        rms = _unabsorbed_rms(basis, d)
        target = rng.uniform(*strength) * noise_rms
        params[effect] = _rescale(effect, joint, params[effect], target / rms)
    data = simulate_arm_data(robot, EffectSet.from_params(params), np.random.default_rng(seed), n=n)
    return data


def _unit_vector(effect, joint, vec):
    v = np.zeros_like(vec)
    if effect == "thermal_drift":
        return np.array([1.0, vec[1]])
    j = joint - 1
    sl = slice(2 * j, 2 * j + 2) if effect == "encoder_eccentricity" else slice(j, j + 1)
    v[sl] = vec[sl]
    return v


def _rescale(effect, joint, vec, factor):
    v = vec.copy()
    if effect == "thermal_drift":
        v[0] *= factor
        return v
    j = joint - 1
    sl = slice(2 * j, 2 * j + 2) if effect == "encoder_eccentricity" else slice(j, j + 1)
    v[sl] *= factor
    return v


def found(res, effect: str, joint) -> bool:
    """Named by a step, or named as explaining the same residual as a selected step."""
    for s in res.steps:
        if s.term.effect == effect and s.term.joint == joint:
            return True
        if any(a["effect"] == effect and a["joint"] == joint for a in s.ambiguous_with):
            return True
    return False
