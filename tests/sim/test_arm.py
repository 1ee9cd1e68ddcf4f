"""The simulated arm: queue timing, truth = nominal + effects + servo, stops, memory."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from scipy import stats

from fakes.sim.arm import SimArm
from fakes.sim.clock import ManualClock, SimClock
from station.errors import DataError, DeviceFault, DeviceTimeout
from station.models import kinematics as kin
from station.models.effects import EffectContext, EffectSet, realistic_effects
from station.models.motion import ServoParams


def test_queue_timing_and_states(robot, clock, iso_q):
    arm = SimArm(robot, clock)
    assert arm.state == "idle"
    np.testing.assert_array_equal(arm.commanded_q_rad(), robot.home_q_rad)
    clock.advance(1.0)
    m1 = arm.move_joint(iso_q[0])
    assert m1.t_start == 1.0 and m1.t_end > m1.t_start
    d = arm.dwell(0.5)
    m2 = arm.move_joint(iso_q[1], speed_frac=0.5)
    assert d.t_start == m1.t_end and d.t_end == m1.t_end + 0.5
    assert m2.t_start == d.t_end
    assert arm.state == "moving"
    clock.advance(0.5 * (m1.t_end - m1.t_start))
    assert arm.state == "moving"
    assert arm.wait_idle() is True
    assert clock.now() == pytest.approx(m2.t_end)
    assert arm.state == "idle"
    np.testing.assert_array_equal(arm.commanded_q_rad(m2.t_end), iso_q[1])
    np.testing.assert_array_equal(arm.commanded_q_rad(m1.t_end + 0.25), iso_q[0])
    # a move queued after idle time starts now, not at the old end
    clock.advance(3.0)
    m3 = arm.move_joint(iso_q[2])
    assert m3.t_start == clock.now()
    # half speed takes longer than full speed over the same distance
    arm2 = SimArm(robot, ManualClock())
    f1 = arm2.move_joint(iso_q[1])
    assert (m2.t_end - m2.t_start) > (f1.t_end - f1.t_start)


def test_nominal_arm_follows_command_exactly(robot, clock, iso_q):
    arm = SimArm(robot, clock)
    arm.move_joint(iso_q[0])
    arm.move_linear(np.array([-500.0, 2200.0, 1900.0]), speed_mm_s=1000.0, accel_mm_s2=5000.0)
    arm.wait_idle()
    t = np.linspace(0, clock.now(), 3001)
    np.testing.assert_array_equal(arm.actual_q_rad(t), arm.commanded_q_rad(t))
    np.testing.assert_allclose(arm.tool_position_mm(t), kin.tool_position(robot.dh_nominal, arm.commanded_q_rad(t)),
                               atol=1e-9)
    np.testing.assert_allclose(arm.tool_position_mm(), [-500.0, 2200.0, 1900.0], atol=1e-4)
    T = arm.tool_pose(t[:5])
    assert T.shape == (5, 4, 4)
    assert arm.tool_pose(0.0).shape == (4, 4) and arm.tool_position_mm(0.0).shape == (3,)


def test_truth_is_nominal_plus_effects_plus_servo(robot, clock, iso_q, rng):
    effects = realistic_effects(robot, rng)
    servo = ServoParams(2 * np.pi * rng.uniform(6, 12, 6), rng.uniform(0.5, 0.9, 6))
    arm = SimArm(robot, clock, effects=effects, servo=servo, payload_kg=80.0)
    arm.move_joint(iso_q[0])
    arm.move_joint(iso_q[3])
    arm.wait_idle()
    t = np.sort(rng.uniform(0, clock.now() + 1.0, 500))
    q_act = arm.actual_q_rad(t)
    q_cmd = arm.commanded_q_rad(t)
    # during motion the servo lags; at rest after settling it meets the command
    assert np.abs(q_act - q_cmd).max() > 1e-4
    np.testing.assert_allclose(arm.actual_q_rad(clock.now() + 2.0), iso_q[3], atol=1e-12)
    # the true position is FK of the effects applied to the actual joints, with
    # the direction of the last commanded motion of each joint as context
    d2 = np.sign(iso_q[3] - iso_q[0])
    last = np.where(d2 != 0, d2, np.sign(iso_q[0] - robot.home_q_rad))
    t_rest = np.array([clock.now() + 2.0])
    ctx = EffectContext(robot=robot, last_dir=last[None], warmup_s=t_rest, payload_kg=80.0)
    dh, q = effects.apply(robot.dh_nominal, arm.actual_q_rad(t_rest), ctx)
    np.testing.assert_allclose(arm.tool_position_mm(t_rest), kin.tool_position(dh, q), atol=1e-9)
    assert np.linalg.norm(arm.tool_position_mm(t_rest) - kin.tool_position(robot.dh_nominal, iso_q[3])) > 0.1


def test_servo_overshoot_at_a_stop_in_joint_space(robot, clock):
    """A trapezoid stop of one joint overshoots by the second-order fraction."""
    zeta, omega = 0.4, 40.0
    arm = SimArm(robot, clock, servo=ServoParams.uniform(omega, zeta), profile="trapezoid")
    q1 = robot.home_q_rad.copy()
    q1[0] += 1.5
    m = arm.move_joint(q1, speed_frac=0.5, accel_frac=0.5)
    a = 0.5 * robot.joint_accel_limits_rad_s2[0]
    t = m.t_end + np.linspace(0, 1.0, 20001)
    e = arm.actual_q_rad(t)[:, 0] - q1[0]
    frac = math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
    assert e[0] == pytest.approx(a / omega**2, rel=1e-3)
    assert -e.min() == pytest.approx(frac * a / omega**2, rel=1e-3)


def test_backlash_seen_from_two_directions(robot, clock, iso_q, rng):
    b = rng.uniform(5e-5, 1e-4, 6)
    effects = EffectSet.from_params({"backlash": b})
    arm = SimArm(robot, clock, effects=effects)
    target = iso_q[0]
    below, above = target - 0.05, target + 0.05
    arm.move_joint(below)
    m1 = arm.move_joint(target)
    arm.dwell(0.5)
    arm.move_joint(above)
    m2 = arm.move_joint(target)
    arm.dwell(0.5)
    arm.wait_idle()
    p_up = arm.tool_position_mm(m1.t_end + 0.1)  # approached with every joint increasing
    p_down = arm.tool_position_mm(m2.t_end + 0.1)
    J = kin.joint_jacobian(robot.dh_nominal, target)[:3]
    np.testing.assert_allclose(p_down - p_up, J @ (2 * b), atol=1e-3)
    np.testing.assert_allclose(p_up, kin.tool_position(robot.dh_nominal, target - b), atol=1e-9)


def test_stop_scatter_statistics(robot, clock, iso_q):
    """Each stop adds N(0, sigma) per joint: chi-square test on the offsets."""
    sigma = np.full(6, 2e-5)
    arm = SimArm(robot, clock, stop_sigma_rad=sigma, rng=np.random.default_rng(7))
    ends = []
    for k in range(150):
        arm.move_joint(iso_q[1] if k % 2 else iso_q[2])
        ends.append(arm.move_joint(iso_q[0]).t_end)
    arm.wait_idle()
    off = arm.actual_q_rad(np.array(ends)) - iso_q[0]
    n = off.size
    chi2 = float(np.sum((off / sigma) ** 2))
    assert stats.chi2.ppf(1e-4, n) < chi2 < stats.chi2.ppf(1 - 1e-4, n)
    # the controller believes it reached the target exactly
    np.testing.assert_array_equal(arm.commanded_q_rad(np.array(ends)), np.tile(iso_q[0], (len(ends), 1)))


def test_protective_stop_and_reset(robot, clock, iso_q):
    arm = SimArm(robot, clock)
    m = arm.move_joint(iso_q[1])
    queued = arm.move_joint(iso_q[2])
    clock.advance(0.5 * (m.t_start + m.t_end))
    t_s = clock.now()
    v_before = np.gradient(arm.commanded_q_rad(t_s + np.array([-1e-4, 0.0])), axis=0)[-1] / 1e-4
    assert np.abs(v_before).max() > 0.01
    stop = arm.protective_stop()
    assert arm.state == "protective_stop"
    assert m.cancelled and queued.cancelled
    with pytest.raises(DeviceFault, match="protective stop"):
        arm.move_joint(iso_q[0])
    assert stop.kind == "stop" and stop.t_start == t_s
    # decelerates within the acceleration limits, then rests short of the target
    t = np.linspace(t_s, stop.t_end, 2001)
    acc = np.gradient(np.gradient(arm.commanded_q_rad(t), t, axis=0), t, axis=0)[5:-5]
    assert np.all(np.abs(acc) <= robot.joint_accel_limits_rad_s2 * 1.01)
    q_rest = arm.commanded_q_rad(stop.t_end + 1.0)
    np.testing.assert_allclose(arm.commanded_q_rad(stop.t_end + 5.0), q_rest)
    assert np.abs(q_rest - iso_q[1]).max() > 1e-3
    assert arm.wait_idle() is True
    arm.reset()
    assert arm.state == "idle"
    m3 = arm.move_joint(iso_q[0])
    assert m3.t_start >= stop.t_end
    np.testing.assert_array_equal(arm.commanded_q_rad(m3.t_end), iso_q[0])


def test_refusals(robot, clock):
    arm = SimArm(robot, clock)
    q = robot.home_q_rad.copy()
    q[1] = robot.joint_limits_rad[1, 1] + 0.1
    with pytest.raises(DeviceFault, match="joint 2"):
        arm.move_joint(q)
    with pytest.raises(DataError, match="q_rad"):
        arm.move_joint([0.0, np.nan, 0, 0, 0, 0])
    with pytest.raises(DataError, match="speed_mm_s"):
        arm.move_linear(np.zeros(3), speed_mm_s=1e6)
    with pytest.raises(DeviceFault, match="refused"):
        arm.move_linear(np.array([0.0, 9000.0, 1000.0]), speed_mm_s=500.0)
    with pytest.raises(DataError, match="seconds"):
        arm.dwell(-1)


def test_thread_safe_queue(robot, iso_q):
    arm = SimArm(robot, ManualClock())
    moves = []
    lock = threading.Lock()

    def worker(k):
        for i in range(10):
            m = arm.move_joint(iso_q[(k + i) % 5])
            with lock:
                moves.append(m)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=30)
    spans = sorted((m.t_start, m.t_end) for m in moves)
    assert len(spans) == 40
    for (a0, a1), (b0, _) in zip(spans, spans[1:]):
        assert a1 <= b0 + 1e-12  # no overlap: each starts at the end of the previous


def test_wait_idle_on_a_running_clock(robot, iso_q):
    arm = SimArm(robot, SimClock(time_scale=1.0))
    arm.move_joint(iso_q[1])
    with pytest.raises(DeviceTimeout):
        arm.wait_idle(timeout_s=0.05)
    stop = threading.Event()
    stop.set()
    assert arm.wait_idle(stop_event=stop) is False
    fast = SimArm(robot, SimClock(time_scale=200.0))
    fast.move_joint(iso_q[1])
    assert fast.wait_idle(timeout_s=10.0) is True
    assert fast.state == "idle"


def test_history_is_bounded(robot, clock, iso_q):
    arm = SimArm(robot, clock, history_s=20.0)
    for k in range(600):
        arm.move_joint(iso_q[k % 5])
        arm.wait_idle()
    assert arm._seg.n < 2 * 1024 + 100  # dropped old segments, not growing with the run
    assert arm._seg.t0.size < 8 * 1024
    with pytest.raises(DataError, match="retained history"):
        arm.tool_position_mm(1.0)
    arm.tool_position_mm(clock.now() - 10.0)  # recent past is still there
