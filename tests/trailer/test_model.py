"""The trailer model: eq. (23) steady state, eq. (25) bound, the joint-angle
dynamics (D) derived from the two nonholonomic axles, commands, sensors, SimTrailer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from fakes.sim.clock import ManualClock
from fakes.sim.trailer import SimTrailer, record_commands
from station.errors import ConfigError, DataError
from station.models.trailer import (
    PSI_LIMIT_RAD, CurvatureBoundError, JointAngleLimitError, SensorModel, check_curvature_command,
    command_curvature, curvature_bound, integrate_psi, psi_rate, steady_state_kappa, steady_state_psi,
    steady_state_residual,
)

L1, L2 = 1.25, 2.48


def test_steady_state_solves_eq23_on_the_stable_branch():
    kappa = np.linspace(-0.46, 0.46, 93)
    psi = steady_state_psi(kappa, L1, L2)
    assert np.max(np.abs(steady_state_residual(kappa, psi, L1, L2))) < 1e-14
    # the root nearest zero (bracketed numerically) is the closed form's
    # the root bracketed where cos(psi - atan(kappa L1)) > 0 (the stable half) is the closed form's
    ref = [brentq(lambda p, k=k: math.sin(p) - k * (L2 + L1 * math.cos(p)),
                  math.atan(k * L1) - math.pi / 2 + 1e-9, math.atan(k * L1) + math.pi / 2 - 1e-9, xtol=1e-15)
           for k in kappa]
    np.testing.assert_allclose(psi, ref, atol=1e-12)
    # stable: d(rate)/dpsi < 0 there
    h = 1e-6
    slope = (psi_rate(psi + h, kappa, 1.0, L1, L2) - psi_rate(psi - h, kappa, 1.0, L1, L2)) / (2 * h)
    assert np.all(slope < 0)
    np.testing.assert_allclose(steady_state_kappa(psi, L1, L2), kappa, atol=1e-14)


def test_curvature_bound_is_eq25_and_the_largest_steady_curvature():
    bound = curvature_bound(L1, L2)
    assert bound == pytest.approx(1 / math.sqrt(L2 ** 2 - L1 ** 2), rel=1e-15)
    psi = np.linspace(0, math.pi, 200001)
    assert np.max(steady_state_kappa(psi, L1, L2)) == pytest.approx(bound, rel=1e-9)
    steady_state_psi(np.array([0.999999 * bound]), L1, L2)
    with pytest.raises(CurvatureBoundError, match=r"eq\. \(25\)"):
        steady_state_psi(np.array([0.1, bound]), L1, L2)


def test_relaxation_matches_the_closed_form_of_the_dynamics():
    """kappa = 0: dpsi/dt = -(v/L2) sin(psi), so tan(psi/2) = tan(psi0/2) exp(-v t / L2)."""
    t = np.linspace(0.0, 10.0, 201)
    v, psi0 = 0.8, 0.6
    exact = 2 * np.arctan(math.tan(psi0 / 2) * np.exp(-v * t / L2))
    psi = integrate_psi(t, np.zeros_like(t), v, psi0, L1, L2)
    np.testing.assert_allclose(psi, exact, atol=1e-8)
    clock = ManualClock()
    sim = SimTrailer(clock, L1, L2, v_m_s=v, noise=None, psi0_rad=psi0)
    np.testing.assert_allclose(sim.record(t)["psi_true"], exact, atol=1e-9)


def test_constant_curvature_settles_to_eq23():
    t = np.linspace(0.0, 40.0, 401)
    psi = integrate_psi(t, np.full_like(t, 0.15), 1.0, 0.0, L1, L2)
    assert psi[-1] == pytest.approx(float(steady_state_psi(np.array([0.15]), L1, L2)[0]), abs=1e-6)
    # a joint angle that lags: after one time constant L2/v it is ~63 % of the way
    i = int(np.argmin(np.abs(t - L2)))
    assert 0.55 < psi[i] / psi[-1] < 0.72


def test_sim_trailer_keeps_both_axles_nonholonomic():
    """The rear axle C2 = C1 - L1 e1 - L2 e2 never slides sideways (derivation of (D))."""
    clock = ManualClock()
    sim = SimTrailer(clock, L1, L2, v_m_s=1.3, noise=None, max_step_s=0.005)
    sim.set_profile("H", 0.2, duration_s=60.0, t0_s=0.0)
    t = np.arange(0.0, 40.0, 0.01)
    states = [sim.state(float(ti)) for ti in t]
    x = np.array([s.x_m for s in states])
    y = np.array([s.y_m for s in states])
    th1 = np.array([s.theta1_rad for s in states])
    psi = np.array([s.psi_rad for s in states])
    th2 = th1 - psi
    c2x = x - L1 * np.cos(th1) - L2 * np.cos(th2)
    c2y = y - L1 * np.sin(th1) - L2 * np.sin(th2)
    vx = (c2x[2:] - c2x[:-2]) / 0.02
    vy = (c2y[2:] - c2y[:-2]) / 0.02
    lateral = -np.sin(th2[1:-1]) * vx + np.cos(th2[1:-1]) * vy
    assert np.max(np.abs(lateral)) < 1e-4 * 1.3
    assert np.max(np.abs(psi)) > 0.5  # it really turned
    # front axle moves along link 1 at the commanded speed
    fx = (x[2:] - x[:-2]) / 0.02
    fy = (y[2:] - y[:-2]) / 0.02
    np.testing.assert_allclose(np.hypot(fx, fy), 1.3, rtol=1e-4)


def test_sensitivities_match_finite_differences():
    t = np.arange(0.0, 30.0, 0.1)
    kappa = command_curvature("H", 0.2, t)
    theta = np.array([1.1, 2.6, 0.05])
    psi, sens = integrate_psi(t, kappa, 0.9, theta[2], theta[0], theta[1], sensitivities=True)
    for j in range(3):
        h = 1e-6
        up, dn = theta.copy(), theta.copy()
        up[j] += h
        dn[j] -= h
        fd = (integrate_psi(t, kappa, 0.9, up[2], up[0], up[1])
              - integrate_psi(t, kappa, 0.9, dn[2], dn[0], dn[1])) / (2 * h)
        np.testing.assert_allclose(sens[:, j], fd, atol=1e-7)


def test_commands_of_paragraph_0127():
    t = np.array([0.0, 5 * math.pi, 10 * math.pi, 20 * math.pi])
    np.testing.assert_allclose(command_curvature("H", 0.2, t), [0, 0.2, 0, 0], atol=1e-15)
    np.testing.assert_allclose(command_curvature("C", 0.1, t), 0.1 * np.tanh(0.1 * t))
    np.testing.assert_allclose(command_curvature("L", 0.2, t), [-0.2, -0.1, 0.0, 0.2], atol=1e-15)
    with pytest.raises(ConfigError, match="kind"):
        command_curvature("S", 0.2, t)
    with pytest.raises(ConfigError, match="amplitude"):
        command_curvature("H", float("nan"), t)


def test_command_check_refuses_bound_and_joint_limit():
    assert check_curvature_command(command_curvature("H", 0.2, np.linspace(0, 63, 300)), L1, L2) \
        == pytest.approx(0.7470, abs=1e-3)  # 42.8 deg: inside 45
    with pytest.raises(JointAngleLimitError, match="45"):
        check_curvature_command(np.array([0.22]), L1, L2)  # steady psi 47.6 deg
    with pytest.raises(CurvatureBoundError):
        check_curvature_command(np.array([0.5]), L1, L2)
    with pytest.raises(ConfigError, match="L2_m"):
        curvature_bound(2.0, 1.5)


def test_sensor_model_noise_offset_gain():
    rng = np.random.default_rng(3)
    n = 20000
    model = SensorModel(kappa_sigma=0.02, psi_sigma=0.01, kappa_offset=0.005, psi_offset=-0.02,
                        kappa_gain=1.1, psi_gain=0.95)
    km, pm = model.measure(np.full(n, 0.1), np.full(n, 0.4), rng)
    assert abs(km.mean() - (1.1 * 0.1 + 0.005)) < 5 * 0.02 / math.sqrt(n)
    assert abs(pm.mean() - (0.95 * 0.4 - 0.02)) < 5 * 0.01 / math.sqrt(n)
    assert abs(km.std() / 0.02 - 1) < 5 / math.sqrt(2 * n)
    assert abs(pm.std() / 0.01 - 1) < 5 / math.sqrt(2 * n)
    with pytest.raises(ConfigError, match="kappa_sigma"):
        SensorModel(kappa_sigma=-1.0)


def test_sim_trailer_commands_rate_limit_and_refusals():
    clock = ManualClock()
    sim = SimTrailer(clock, noise=None, max_curvature_rate=0.2)
    sim.command_curvature(0.2, 0.0)
    assert sim.state(0.5).kappa_1_m == pytest.approx(0.1)   # ramps at 0.2 1/(m s)
    assert sim.state(2.0).kappa_1_m == pytest.approx(0.2)
    with pytest.raises(CurvatureBoundError):
        sim.command_curvature(0.6)
    with pytest.raises(JointAngleLimitError):
        sim.command_curvature(0.25)
    assert sim.state(5.0).kappa_1_m == pytest.approx(0.2)   # refused commands change nothing
    with pytest.raises(ConfigError, match="v_m_s"):
        sim.command_speed(-0.5)
    clock.advance(10.0)
    assert sim.state().t_s == 10.0
    assert sim.state(3.0).t_s == 10.0  # time never runs backwards
    with pytest.raises(DataError, match="already integrated"):
        sim.record(np.array([4.0, 5.0]))


def test_sim_trailer_steering_ramps_exactly_at_its_rate(rng):
    """A set point the steering reaches within an integration step: the ramp ends after |dk|/rate, not at the
    step's end (the odometry's interval average of the path curvature shows the ramp's lag, which biases the
    dynamic estimator's L2 by v x the lag when the command is its instrument)."""
    rate = float(rng.uniform(0.1, 0.5))
    for r in (rate, math.inf):
        clock = ManualClock()
        sim = SimTrailer(clock, noise=None, max_curvature_rate=r)
        dk = float(rng.uniform(0.0005, 0.004)) * float(rng.choice([-1.0, 1.0]))
        sim.read_sensors(1.0)
        sim.command_curvature(dk, 1.0)
        avg = sim.read_sensors(1.1).kappa_1_m
        ramp_s = abs(dk) / r  # shorter than the max step of 0.02 s: inside one RK4 step
        assert avg == pytest.approx(dk * (1.0 - 0.5 * ramp_s / 0.1), rel=1e-6, abs=1e-12)
        assert sim.state(1.1).kappa_1_m == pytest.approx(dk, abs=1e-15)


def test_sim_trailer_record_repeats_share_one_truth():
    clock = ManualClock()
    sim = SimTrailer(clock, noise=0.01, rng=np.random.default_rng(0))
    sim.set_profile("C", 0.2, duration_s=30.0)
    rec = sim.record(np.arange(0, 30, 0.1), repeats=50)
    assert rec["kappa"].shape == (50, 300) and rec["kappa_true"].shape == (300,)
    resid = rec["psi"] - rec["psi_true"]
    assert abs(resid.std() / 0.01 - 1) < 5 / math.sqrt(2 * resid.size)
    np.testing.assert_allclose(rec["kappa_inst"], command_curvature("C", 0.2, np.arange(0, 30, 0.1)),
                               atol=1e-12)
    # the odometry reports the average over the interval since the previous reading
    tau = np.arange(0, 30, 0.1)
    avg = (np.log(np.cosh(0.1 * tau[1:])) - np.log(np.cosh(0.1 * tau[:-1]))) / (0.1 * 0.1) * 0.2
    np.testing.assert_allclose(rec["kappa_true"][1:], avg, atol=1e-9)


def test_record_commands_is_continuous_and_labelled():
    rec = record_commands([("H", 0.1), ("L", 0.1)], noise=None, settle_s=15.0, duration_s=10.0)
    t = rec["t"]
    np.testing.assert_allclose(np.diff(t), 0.1, atol=1e-9)
    assert list(np.unique(rec["segment"])) == [0, 1]
    assert np.sum(rec["phase"] == 1) == 2 * 101 and np.sum(rec["phase"] == 0) == 2 * 150
    # L segment settled at its start value -M before its profile
    start_L = np.flatnonzero((rec["segment"] == 1) & (rec["phase"] == 1))[0]
    assert rec["kappa_true"][start_L] == pytest.approx(-0.1)
    assert abs(rec["psi_true"][start_L] - steady_state_psi(np.array([-0.1]))[0]) < 0.01
    assert np.max(np.abs(rec["psi_true"])) < PSI_LIMIT_RAD
