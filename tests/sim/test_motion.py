"""Motion profiles, joint/linear moves and the servo response (station.models.motion)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from station.errors import ConfigError, DataError
from station.models import kinematics as kin
from station.models import motion

REL = 1e-9


def _fine(profile, n=20001):
    t = np.linspace(0.0, profile.duration_s, n)
    return (t, *profile.evaluate(t))


@pytest.mark.parametrize("kind", ["trapezoid", "scurve"])
def test_profiles_respect_limits_and_end_exactly(kind, rng):
    for _ in range(25):
        L = 10 ** rng.uniform(-4, 3)
        v, a = 10 ** rng.uniform(-1, 1, 2)
        j = a / rng.uniform(0.02, 0.5)
        p = motion.make_profile(kind, L, v, a, j)
        t, s, vel, acc = _fine(p)
        assert s[-1] == L  # exactly the target, not integrated to it
        assert vel[-1] == 0 and vel[0] == 0
        assert np.all(np.diff(s) >= -1e-12 * L)
        assert vel.max() <= v * (1 + REL)
        assert np.abs(acc).max() <= a * (1 + REL)
        assert p.peak_velocity <= v * (1 + REL) and p.peak_acceleration <= a * (1 + REL)
        # the integrated segments meet the target (continuity of the pieces)
        assert abs(p.evaluate(p.duration_s * (1 - 1e-12))[0] - L) <= 1e-9 * max(L, 1.0)
        if kind == "scurve":
            jerk = np.diff(acc) / np.diff(t)
            assert np.abs(jerk).max() <= j * (1 + 1e-6)
        # a long move reaches the speed limit
        if L > 10 * (v * v / a + v * a / j):
            assert vel.max() == pytest.approx(v, rel=1e-9)


def test_trapezoid_closed_forms():
    # cruise case: T = L/v + v/a
    p = motion.trapezoid_profile(10.0, 2.0, 4.0)
    assert p.duration_s == pytest.approx(10.0 / 2.0 + 2.0 / 4.0)
    # triangular: peak sqrt(L a), T = 2 sqrt(L/a)
    p = motion.trapezoid_profile(0.25, 2.0, 4.0)
    assert p.peak_velocity == pytest.approx(math.sqrt(0.25 * 4.0))
    assert p.duration_s == pytest.approx(2 * math.sqrt(0.25 / 4.0))


def test_scurve_closed_forms():
    # both limits reached: T = L/v + v/a + a/j (Biagiotti & Melchiorri 3.4)
    L, v, a, j = 10.0, 2.0, 4.0, 40.0
    assert motion.scurve_profile(L, v, a, j).duration_s == pytest.approx(L / v + v / a + a / j)
    # neither reached: Tj = (L / 2j)^(1/3), T = 4 Tj
    L = 1e-3
    tj = (L / (2 * j)) ** (1 / 3)
    p = motion.scurve_profile(L, v, a, j)
    assert p.duration_s == pytest.approx(4 * tj)
    assert p.peak_acceleration == pytest.approx(j * tj)


def test_profile_refuses_bad_limits():
    with pytest.raises(DataError, match="v_max"):
        motion.trapezoid_profile(1.0, 0.0, 1.0)
    with pytest.raises(DataError, match="a_max"):
        motion.scurve_profile(1.0, 1.0, float("nan"), 1.0)
    with pytest.raises(DataError, match="distance"):
        motion.trapezoid_profile(-1.0, 1.0, 1.0)
    with pytest.raises(DataError, match="profile"):
        motion.make_profile("cubic", 1.0, 1.0, 1.0, 1.0)


@pytest.mark.parametrize("kind", ["trapezoid", "scurve"])
def test_joint_move_synchronised_within_limits(kind, robot, rng):
    lim = robot.joint_limits_rad
    for _ in range(10):
        q0 = rng.uniform(lim[:, 0], lim[:, 1]) * 0.5
        q1 = rng.uniform(lim[:, 0], lim[:, 1]) * 0.5
        fv, fa = rng.uniform(0.1, 1.0, 2)
        plan = motion.plan_joint_move(
            q0, q1, robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2,
            speed_frac=fv, accel_frac=fa, profile=kind,
        )
        tr = plan.trajectory
        t = np.linspace(0, tr.duration_s, 8001)
        qd = tr.evaluate(t, 1)
        qdd = tr.evaluate(t, 2)
        ratio_v = np.abs(qd).max(axis=0) / (fv * robot.joint_speed_limits_rad_s)
        ratio_a = np.abs(qdd).max(axis=0) / (fa * robot.joint_accel_limits_rad_s2)
        assert ratio_v.max() <= 1 + 1e-9 and ratio_a.max() <= 1 + 1e-9
        # one axis is the limiting one (speed or acceleration)
        assert max(ratio_v.max(), ratio_a.max()) == pytest.approx(1.0, rel=1e-3)
        # every axis ends exactly at its target at the same time
        np.testing.assert_array_equal(tr.evaluate(tr.duration_s), q1)
        np.testing.assert_allclose(tr.evaluate(tr.duration_s * (1 - 1e-12)), q1, atol=1e-9)
        # synchronised: normalised progress identical on every moving axis
        prog = (tr.evaluate(t) - q0) / (q1 - q0)
        np.testing.assert_allclose(prog, prog[:, :1].repeat(6, axis=1), atol=1e-9)


def test_joint_move_zero_and_bad_fraction(robot):
    q = robot.home_q_rad
    plan = motion.plan_joint_move(q, q, robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2)
    assert plan.duration_s == 0
    with pytest.raises(DataError, match="speed_frac"):
        motion.plan_joint_move(q, q, robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2, speed_frac=1.5)


def test_linear_move_is_straight_and_ends_at_target(robot, iso_q):
    dh = robot.dh_nominal
    T0 = kin.fk(dh, iso_q[0])
    T1 = T0.copy()
    T1[:3, 3] = [-500.0, 2200.0, 1900.0]
    speed = 800.0
    plan = motion.plan_linear_move(
        dh, iso_q[0], T1, speed_mm_s=speed, accel_mm_s2=3000.0,
        joint_limits_rad=robot.joint_limits_rad,
        joint_speed_limits_rad_s=robot.joint_speed_limits_rad_s,
        joint_accel_limits_rad_s2=robot.joint_accel_limits_rad_s2,
    )
    tr = plan.trajectory
    # dense times include the midpoints between interpolation knots
    t = np.linspace(0, tr.duration_s, 20 * tr.n_segments + 1)
    T = kin.fk(dh, tr.evaluate(t))
    p0, p1 = T0[:3, 3], T1[:3, 3]
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    d = T[:, :3, 3] - p0
    off = d - (d @ u)[:, None] * u
    assert np.linalg.norm(off, axis=1).max() < 1e-3  # mm: on the line between knots too
    # orientation fixed
    dR = np.einsum("nji,jk->nik", T[:, :3, :3], T0[:3, :3])
    assert np.abs(dR - np.eye(3)).max() < 1e-6
    # ends at the target
    assert np.linalg.norm(kin.fk(dh, tr.evaluate(tr.duration_s))[:3, 3] - p1) < 1e-4
    # path speed within the requested speed (small interpolation excess allowed)
    v = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) / np.diff(t)
    assert v.max() <= speed * 1.001
    assert plan.time_scale >= 1.0
    qd = np.abs(tr.evaluate(t, 1)).max(axis=0)
    assert np.all(qd <= robot.joint_speed_limits_rad_s * 1.001)


def test_linear_move_time_scaled_to_joint_limits(robot, iso_q):
    # a very fast request must be slowed until no joint exceeds its limits
    dh = robot.dh_nominal
    target = np.array([-500.0, 2200.0, 1900.0])
    slow_limits = robot.joint_speed_limits_rad_s * 0.2
    plan = motion.plan_linear_move(
        dh, iso_q[0], target, speed_mm_s=2000.0, accel_mm_s2=20000.0,
        joint_limits_rad=robot.joint_limits_rad,
        joint_speed_limits_rad_s=slow_limits,
        joint_accel_limits_rad_s2=robot.joint_accel_limits_rad_s2,
    )
    assert plan.time_scale > 1.0
    tr = plan.trajectory
    t = np.linspace(0, tr.duration_s, 4001)
    assert np.all(np.abs(tr.evaluate(t, 1)).max(axis=0) <= slow_limits * 1.01)


def test_linear_move_unreachable_refused(robot, iso_q):
    with pytest.raises(DataError, match="not reachable|reachable space"):
        motion.plan_linear_move(
            robot.dh_nominal, iso_q[0], np.array([0.0, 9000.0, 1400.0]), speed_mm_s=500.0, accel_mm_s2=1000.0,
            joint_limits_rad=robot.joint_limits_rad,
            joint_speed_limits_rad_s=robot.joint_speed_limits_rad_s,
            joint_accel_limits_rad_s2=robot.joint_accel_limits_rad_s2,
        )


def test_stop_trajectory_within_decel_limits(robot, rng):
    q = robot.home_q_rad
    qd = rng.uniform(-1, 1, 6) * robot.joint_speed_limits_rad_s
    tr = motion.stop_trajectory(q, qd, robot.joint_accel_limits_rad_s2)
    t = np.linspace(0, tr.duration_s, 1001)
    assert np.abs(tr.evaluate(t, 2)).max(axis=0).max() > 0
    assert np.all(np.abs(tr.evaluate(t, 2)) <= robot.joint_accel_limits_rad_s2 * (1 + 1e-9))
    np.testing.assert_allclose(tr.evaluate(t[-1:] * (1 - 1e-12), 1), 0, atol=1e-9)
    np.testing.assert_allclose(tr.evaluate(tr.duration_s), q + 0.5 * qd * tr.duration_s)


def test_hold_is_a_dwell():
    q = np.arange(6.0)
    h = motion.hold(q, 0.5)
    assert h.duration_s == 0.5
    np.testing.assert_array_equal(h.evaluate(np.linspace(-1, 2, 7)), np.tile(q, (7, 1)))


# -------------------------------------------------------------------- servo
def _long_accel_move(a, v=50.0):
    """Axis 0 accelerates at ``a`` for a long time (a step of r'')."""
    lim_v = np.full(6, v)
    lim_a = np.full(6, a)
    q1 = np.zeros(6)
    q1[0] = 1000.0
    return motion.plan_joint_move(np.zeros(6), q1, lim_v, lim_a, profile="trapezoid")


def test_servo_step_overshoot_matches_second_order_theory(rng):
    for _ in range(6):
        zeta = rng.uniform(0.2, 0.8)
        omega = rng.uniform(20.0, 80.0)
        a = rng.uniform(0.5, 5.0)
        servo = motion.ServoParams.uniform(omega, zeta)
        plan = _long_accel_move(a)
        tr = plan.trajectory
        E, Ed = motion.propagate_servo(tr, np.zeros(6), np.zeros(6), servo)
        wd = omega * math.sqrt(1 - zeta**2)
        t_peak = math.pi / wd
        t = np.linspace(0, 3 * t_peak, 30001)
        q, _ = motion.evaluate_servo(tr, E, Ed, t, servo)
        e = q[:, 0] - tr.evaluate(t)[:, 0]
        e_ss = -a / omega**2
        frac = math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
        k = int(np.argmin(e))
        assert e[k] == pytest.approx(e_ss * (1 + frac), rel=1e-6)
        assert t[k] == pytest.approx(t_peak, abs=2 * (t[1] - t[0]))
        assert servo.overshoot_fraction()[0] == pytest.approx(frac)


def test_servo_stop_overshoot_and_settling(rng):
    """After a trapezoid stop the joint overshoots its target and settles in the envelope."""
    zeta, omega = rng.uniform(0.3, 0.7), rng.uniform(30.0, 60.0)
    # the braking (1 rad/s at a) lasts long enough for the lag to settle to 1e-4 of itself: the
    # transient of the braking's start decays as exp(-zeta omega t) / sqrt(1 - zeta^2); at 2 rad/s^2
    # (0.5 s) a slow, lightly damped servo (zeta omega < 19 /s) would still ring when the stop comes
    a = min(2.0, zeta * omega / math.log(1e4 / math.sqrt(1 - zeta**2)))
    servo = motion.ServoParams.uniform(omega, zeta)
    q1 = np.zeros(6)
    q1[0] = 5.0
    plan = motion.plan_joint_move(np.zeros(6), q1, np.full(6, 1.0), np.full(6, a), profile="trapezoid")
    tr = plan.trajectory
    E, Ed = motion.propagate_servo(tr, np.zeros(6), np.zeros(6), servo)
    T = tr.duration_s
    t = T + np.linspace(0, 1.0, 100001)
    q, _ = motion.evaluate_servo(tr, E, Ed, t, servo)
    e = q[:, 0] - q1[0]
    # the decel phase (1/a s) is long: the error had settled at +a/omega^2 (lag while braking)
    e0 = a / omega**2
    assert e[0] == pytest.approx(e0, rel=1e-3)
    frac = math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
    assert -e.min() == pytest.approx(frac * e0, rel=1e-3)  # overshoot past the target
    band = 0.01 * e0
    outside = np.nonzero(np.abs(e) > band)[0]
    t_settle = t[outside[-1]] - T
    bound = math.log(e0 / (band * math.sqrt(1 - zeta**2))) / (zeta * omega)
    assert t_settle <= bound
    assert t_settle >= 0.5 * bound  # and not trivially early


@pytest.mark.parametrize("zeta", [0.35, 1.0, 2.5])
def test_servo_exact_against_ode_integration(zeta):
    omega = 40.0
    servo = motion.ServoParams.uniform(omega, zeta)
    q1 = np.linspace(0.2, 1.2, 6)
    plan = motion.plan_joint_move(np.zeros(6), q1, np.full(6, 2.0), np.full(6, 8.0), jerk_time_s=0.05)
    tr = plan.trajectory
    E, Ed = motion.propagate_servo(tr, np.zeros(6), np.zeros(6), servo)
    t_eval = np.linspace(0, tr.duration_s + 0.5, 401)
    q, qd = motion.evaluate_servo(tr, E, Ed, t_eval, servo)

    knots, c = tr.t_knots, tr.coeffs[:, :, 5]

    def rhs(t, y):
        k = min(max(int(np.searchsorted(knots, t, side="right")) - 1, 0), len(c))
        if k >= len(c):
            r, rd = q1[5], 0.0
        else:
            tau = t - knots[k]
            r = c[k, 0] + tau * (c[k, 1] + tau * (c[k, 2] + tau * c[k, 3]))
            rd = c[k, 1] + tau * (2 * c[k, 2] + 3 * tau * c[k, 3])
        return [y[1], omega**2 * (r - y[0]) + 2 * zeta * omega * (rd - y[1])]

    sol = solve_ivp(rhs, (0, t_eval[-1]), [0.0, 0.0], t_eval=t_eval, rtol=1e-10, atol=1e-12, max_step=5e-3)
    np.testing.assert_allclose(q[:, 5], sol.y[0], atol=1e-8)
    np.testing.assert_allclose(qd[:, 5], sol.y[1], atol=1e-6)


def test_servo_params_refused():
    with pytest.raises(ConfigError, match="omega_rad_s"):
        motion.ServoParams(np.full(6, -1.0), np.full(6, 0.7))
    with pytest.raises(ConfigError, match="zeta"):
        motion.ServoParams(np.full(6, 10.0), np.full(5, 0.7))
