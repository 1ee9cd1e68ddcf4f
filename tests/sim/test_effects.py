"""Error effects: each moves the tool by what its parameter predicts (station.models.effects)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from station.errors import ConfigError, DataError
from station.models import kinematics as kin
from station.models.effects import (
    EFFECT_ORDER,
    EffectContext,
    EffectSet,
    eccentricity_amplitude_phase,
    realistic_effects,
    realistic_stop_sigma_rad,
)
from station.models.robots import gravity_torques


def _poses(robot, rng, n=40):
    lim = robot.joint_limits_rad
    lo = np.maximum(lim[:, 0], -2.5)
    hi = np.minimum(lim[:, 1], 2.5)
    return lo + (hi - lo) * rng.random((n, 6))


def _tool(dh, q):
    return kin.tool_position(dh, q)


def test_geometric_matches_parameter_jacobian(robot, rng):
    q = _poses(robot, rng)
    delta = np.concatenate([rng.normal(0, 1e-3, (7, 1)), rng.normal(0, 1e-6, (7, 1)), rng.normal(0, 1e-3, (7, 1)),
                            rng.normal(0, 1e-6, (7, 2))], axis=1).reshape(-1)
    es = EffectSet.from_params({"geometric": delta})
    dh_eff, q_eff = es.apply(robot.dh_nominal, q)
    np.testing.assert_array_equal(dh_eff, robot.dh_nominal + delta.reshape(7, 5))
    dp = _tool(dh_eff, q_eff) - _tool(robot.dh_nominal, q)
    pred = np.einsum("nij,j->ni", kin.param_jacobian(robot.dh_nominal, q), delta)
    # second-order remainder: |delta_angle|^2 * reach ~ 1e-12 * 3e3
    np.testing.assert_allclose(dp, pred, atol=1e-7)
    assert np.abs(dp).max() > 1e-4


def test_thermal_drift_scales_positions_exactly(robot, rng):
    """All lengths scale by (1 + alpha dT): the TCP position scales about the base origin."""
    q = _poses(robot, rng)
    dT_max, tau = rng.uniform(2, 8), rng.uniform(600, 4000)
    t = rng.uniform(0, 3 * tau, q.shape[0])
    es = EffectSet.from_params({"thermal_drift": [dT_max, tau]})
    alpha = es.effect("thermal_drift").alpha_per_K
    dh_eff, q_eff = es.apply(robot.dh_nominal, q, EffectContext(warmup_s=t))
    dT = dT_max * (1 - np.exp(-t / tau))
    expect = (1 + alpha * dT)[:, None] * _tool(robot.dh_nominal, q)
    np.testing.assert_allclose(_tool(dh_eff, q_eff), expect, rtol=0, atol=1e-9)
    # a measured temperature rise overrides the warm-up model
    dh2, _ = es.apply(robot.dh_nominal, q, EffectContext(warmup_s=t, temperature_rise_K=3.0))
    np.testing.assert_allclose(_tool(dh2, q), (1 + alpha * 3.0) * _tool(robot.dh_nominal, q), atol=1e-9)


def test_encoder_eccentricity_first_harmonic(robot, rng):
    q = _poses(robot, rng)
    p = rng.normal(0, 1e-4, 12)
    es = EffectSet.from_params({"encoder_eccentricity": p})
    _, q_eff = es.apply(robot.dh_nominal, q)
    A, phi = eccentricity_amplitude_phase(p)
    np.testing.assert_allclose(q_eff - q, A * np.sin(q + phi), atol=1e-15)
    dp = _tool(robot.dh_nominal, q_eff) - _tool(robot.dh_nominal, q)
    pred = np.einsum("nij,nj->ni", kin.joint_jacobian(robot.dh_nominal, q)[:, :3], q_eff - q)
    # second-order remainder <= |dq|_1^2 / 2 * reach (reach < 4000 mm)
    bound = 0.5 * 4000.0 * np.abs(q_eff - q).sum(axis=1) ** 2
    assert np.all(np.linalg.norm(dp - pred, axis=1) <= bound)
    assert np.all(bound < 0.01 * np.linalg.norm(pred, axis=1).max())


def test_backlash_against_last_motion(robot, rng):
    q = _poses(robot, rng)
    b = rng.uniform(1e-5, 1e-4, 6)
    sgn = rng.choice([-1.0, 0.0, 1.0], size=q.shape)
    es = EffectSet.from_params({"backlash": b})
    _, q_eff = es.apply(robot.dh_nominal, q, EffectContext(last_dir=sgn))
    np.testing.assert_allclose(q_eff - q, -b * sgn, atol=1e-16)
    # the same pose approached from both sides differs by J . 2b (first order)
    _, qp = es.apply(robot.dh_nominal, q, EffectContext(last_dir=np.ones(6)))
    _, qm = es.apply(robot.dh_nominal, q, EffectContext(last_dir=-np.ones(6)))
    dp = _tool(robot.dh_nominal, qm) - _tool(robot.dh_nominal, qp)
    pred = np.einsum("nij,j->ni", kin.joint_jacobian(robot.dh_nominal, q)[:, :3], 2 * b)
    bound = 0.5 * 4000.0 * (2 * b.sum()) ** 2
    assert np.linalg.norm(dp - pred, axis=1).max() <= bound
    # no direction known yet: backlash centred
    _, q0 = es.apply(robot.dh_nominal, q, EffectContext())
    np.testing.assert_array_equal(q0, q)


def test_joint_compliance_deflects_by_gravity_torque(robot, rng):
    q = _poses(robot, rng)
    c = rng.uniform(1e-8, 1e-7, 6)
    payload = rng.uniform(0, robot.rated_payload_kg)
    es = EffectSet.from_params({"joint_compliance": c})
    _, q_eff = es.apply(robot.dh_nominal, q, EffectContext(robot=robot, payload_kg=payload))
    tau = gravity_torques(robot, robot.dh_nominal, q, payload_kg=payload)
    np.testing.assert_allclose(q_eff - q, -c * tau, atol=1e-15)
    assert np.abs(q_eff - q).max() > 1e-6
    with pytest.raises(DataError, match="robot"):
        es.apply(robot.dh_nominal, q, EffectContext())


def test_switched_off_or_zero_is_nominal(robot, rng):
    q = _poses(robot, rng)
    full = realistic_effects(robot, rng)
    ctx = EffectContext(robot=robot, last_dir=np.ones(6), warmup_s=1e4, payload_kg=50.0)
    p_nom = _tool(robot.dh_nominal, q)
    off = full.only()
    dh, qq = off.apply(robot.dh_nominal, q, ctx)
    np.testing.assert_array_equal(_tool(dh, qq), p_nom)
    zero = full.unflatten(np.zeros(full.flatten()[0].size)).with_params("thermal_drift", [0.0, 100.0])
    dh, qq = zero.apply(robot.dh_nominal, q, ctx)
    np.testing.assert_allclose(_tool(dh, qq), p_nom, atol=1e-9)
    # each effect alone changes the position, and switching it off removes exactly that
    for name in EFFECT_ORDER:
        dh1, q1 = full.only(name).apply(robot.dh_nominal, q, ctx)
        assert np.abs(_tool(dh1, q1) - p_nom).max() > 1e-3, name


def test_flatten_unflatten_round_trip(robot, rng):
    es = realistic_effects(robot, rng)
    vec, names = es.flatten()
    assert len(names) == vec.size == 35 + 2 + 12 + 6 + 6
    assert len(set(names)) == len(names)
    assert names[0] == "geometric.a1_mm" and "thermal_drift.tau_s" in names
    new = rng.normal(size=vec.size)
    es2 = es.unflatten(new)
    np.testing.assert_array_equal(es2.flatten()[0], new)
    assert es2.flatten()[1] == names
    # only the enabled effects are in the vector
    sub = es.only("backlash", "joint_compliance")
    v2, n2 = sub.flatten()
    assert n2 == tuple(f"backlash.b{i}_rad" for i in range(1, 7)) + tuple(
        f"joint_compliance.c{i}_rad_per_Nm" for i in range(1, 7))
    np.testing.assert_array_equal(sub.unflatten(v2 * 2).get("backlash"), 2 * es.get("backlash"))
    assert sub.flatten(include_disabled=True)[0].size == vec.size
    with pytest.raises(DataError, match="12 values"):
        sub.unflatten(np.zeros(5))
    # dict round trip
    es3 = EffectSet.from_dict(es.to_dict())
    np.testing.assert_array_equal(es3.flatten()[0], vec)
    assert es3.enabled_names == es.enabled_names


def test_order_is_canonical(robot, rng):
    q = _poses(robot, rng, 10)
    es = realistic_effects(robot, rng)
    shuffled = EffectSet(es.effects[::-1], es.params[::-1], es.enabled[::-1])
    assert shuffled.names == EFFECT_ORDER
    ctx = EffectContext(robot=robot, last_dir=-np.ones(6), warmup_s=500.0)
    a = es.apply(robot.dh_nominal, q, ctx)
    b = shuffled.apply(robot.dh_nominal, q, ctx)
    np.testing.assert_array_equal(_tool(*a), _tool(*b))


def test_bad_effect_configuration():
    with pytest.raises(ConfigError, match="unknown effect 'gravity'"):
        EffectSet.from_params({"gravity": [1.0]})
    with pytest.raises(ConfigError, match="backlash.*6 parameters"):
        EffectSet.from_params({"backlash": [1.0, 2.0]})
    with pytest.raises(ConfigError, match="alpha_per_K"):
        EffectSet.from_params({}, options={"thermal_drift": {"alpha_per_K": -1.0}})


def test_realistic_magnitudes(robot, iso_q):
    """Uncalibrated AP of a few mm (seed 000 Table 3: 3.2-4.7 mm) over many draws."""
    P = kin.tool_position(robot.dh_nominal, iso_q)
    aps = []
    for seed in range(20):
        es = realistic_effects(robot, np.random.default_rng(seed))
        ctx = EffectContext(robot=robot, last_dir=np.ones(6), warmup_s=1800.0)
        aps.append(np.linalg.norm(_tool(*es.apply(robot.dh_nominal, iso_q, ctx)) - P, axis=1))
    med = float(np.median(aps))
    assert 1.0 < med < 6.0
    sig = realistic_stop_sigma_rad(robot, np.random.default_rng(0), sigma_mm=0.03)
    J = kin.joint_jacobian(robot.dh_nominal, robot.home_q_rad)[:3]
    assert math.sqrt(np.trace(J @ np.diag(sig**2) @ J.T) / 3) == pytest.approx(0.03)
