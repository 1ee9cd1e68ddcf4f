"""The simulated arm warms while its joints move and cools at rest (fakes.sim.heat, eq. (H1)), with the thermal
drift the world is told (``warmup``: a drift test's known truth); a cell started again carries the warmth on."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from fakes.sim.heat import H_REF
from fakes.sim.world import make_world
from station.errors import ConfigError
from station.models.arm_extended import STEEL_ALPHA_PER_K
from station.models.effects import EffectSet

THERMAL_ONLY = EffectSet.from_params({}, enabled=("thermal_drift",))


def _world(test_seed, rng, **kw):
    dT, tau = float(rng.uniform(1.0, 8.0)), float(rng.uniform(300.0, 3600.0))
    world = make_world(seed=test_seed, clock=ManualClock(kw.pop("start_s", 0.0)), effects=THERMAL_ONLY, servo=None,
                       warmup=(dT, tau), **kw)
    return world, dT, tau


def _ode_rise(moves, dT, tau, speed_limits, t_query, dt=0.01) -> np.ndarray:
    """Eq. (H1) integrated step by step from the moves' joint travel over their times (independent of the
    arm's knots): input mean_j |dq_j| / (v_max_j T) during each move, 0 between."""
    t_end = max(float(np.max(t_query)), moves[-1][1])
    grid = np.arange(0.0, t_end + dt, dt)
    h = np.zeros_like(grid)
    for t0, t1, travel in moves:
        h[(grid >= t0) & (grid < t1)] = np.mean(travel / speed_limits) / (t1 - t0)
    T = np.zeros_like(grid)
    a = np.exp(-dt / tau)
    for k in range(1, grid.size):  # exact for an input held over each step
        T[k] = dT * h[k - 1] / H_REF + (T[k - 1] - dT * h[k - 1] / H_REF) * a
    return np.interp(t_query, grid, T)


def test_the_arm_at_rest_stays_cold(rng, test_seed):
    world, _, tau = _world(test_seed, rng)
    p0 = world.arm.tool_position_mm(0.0)
    for t in rng.uniform(0.0, 5.0 * tau, 4):
        world.clock.advance(float(t) - world.clock.now() if t > world.clock.now() else 0.0)
        assert np.array_equal(world.arm.tool_position_mm(float(t)), p0)
    assert not np.any(world.arm.temperature_rise_K(rng.uniform(0.0, 5.0 * tau, 10)))


def test_moves_warm_the_arm_and_rest_cools_it_by_the_first_order_balance(rng, test_seed):
    world, dT, tau = _world(test_seed, rng)
    arm, robot = world.arm, world.robot
    home = np.asarray(robot.home_q_rad, dtype=float)
    # back and forth between home and a drawn pose, at drawn speeds, with drawn rests between some moves
    lim = np.asarray(robot.joint_limits_rad)
    away = np.clip(home + rng.uniform(-0.6, 0.6, 6), lim[:, 0] + 0.05, lim[:, 1] - 0.05)
    moves, q = [], home
    for k in range(2 * int(rng.integers(10, 20))):  # ends at home
        target = away if k % 2 == 0 else home
        m = arm.move_joint(target, speed_frac=float(rng.uniform(0.3, 1.0)))
        moves.append((m.t_start, m.t_end, np.abs(target - q)))
        q = target
        if rng.random() < 0.3:
            arm.dwell(float(rng.uniform(1.0, 0.2 * tau)))
    t_moved = moves[-1][1]
    t_q = np.concatenate([rng.uniform(0.0, t_moved, 20), t_moved + rng.uniform(0.0, 3.0 * tau, 10)])
    want = _ode_rise(moves, dT, tau, np.asarray(robot.joint_speed_limits_rad_s), t_q)
    got = arm.temperature_rise_K(t_q)
    assert np.allclose(got, want, rtol=1e-3, atol=1e-4 * dT), np.c_[t_q, got, want]
    assert float(arm.temperature_rise_K(t_moved)[0]) > 0.0  # the motion warmed it
    # at rest after the moves it cools: exp(-t / tau) from where the motion left it
    t_rest = t_moved + rng.uniform(0.0, 3.0 * tau, 5)
    assert np.allclose(arm.temperature_rise_K(t_rest),
                       arm.temperature_rise_K(t_moved)[0] * np.exp(-(t_rest - t_moved) / tau), rtol=1e-9)
    # the links grow by alpha dT: the resting tool point at home scales about the base so
    p_cold = arm.tool_position_mm(0.0)
    for t in t_rest[:2]:
        grown = STEEL_ALPHA_PER_K * float(arm.temperature_rise_K(t)[0])
        assert np.allclose(arm.tool_position_mm(float(t)), (1.0 + grown) * p_cold, rtol=0, atol=1e-9)


def test_a_protective_stop_cuts_the_moves_it_stops_from_the_heat(rng, test_seed):
    world, dT, tau = _world(test_seed, rng)
    arm = world.arm
    lim = np.asarray(world.robot.joint_limits_rad)
    far = np.clip(np.asarray(world.robot.home_q_rad) + 0.8, lim[:, 0] + 0.05, lim[:, 1] - 0.05)
    whole = make_world(seed=test_seed, clock=ManualClock(), effects=THERMAL_ONLY, servo=None, warmup=(dT, tau))
    m = arm.move_joint(far, speed_frac=0.3)
    whole.arm.move_joint(far, speed_frac=0.3)
    t_stop = m.t_start + float(rng.uniform(0.2, 0.6)) * (m.t_end - m.t_start)
    world.clock.advance(t_stop)
    arm.protective_stop()
    later = m.t_end + tau
    assert 0.0 < arm.temperature_rise_K(later)[0] < whole.arm.temperature_rise_K(later)[0]


def test_a_cell_started_again_carries_the_arms_warmth_on(rng, test_seed):
    world, dT, tau = _world(test_seed, rng)
    world.arm.move_joint(np.asarray(world.robot.home_q_rad) + 0.5)
    world.arm.dwell(1.0)
    world.clock.advance(world.arm.queue_end_s)
    carried = world.carried()
    t_left, rise = carried["arm_rise"]
    assert t_left == world.clock.now() and rise == world.arm.temperature_rise_K(t_left)[0] > 0
    start = t_left + float(rng.uniform(1.0, tau))
    again = make_world(seed=test_seed, time_scale=1e6, start_s=start, effects=THERMAL_ONLY, servo=None,
                       warmup=(dT, tau), **carried)
    t = start + rng.uniform(0.0, tau, 3)
    assert np.allclose(again.arm.temperature_rise_K(t), rise * np.exp(-(t - t_left) / tau), rtol=1e-12)
    assert make_world(seed=1, clock=ManualClock(), effects=None).carried() == {}


def test_the_realistic_arm_keeps_its_drawn_effects_but_the_warm_up_given(test_seed):
    drawn = make_world(seed=test_seed, clock=ManualClock()).arm.effects
    given = make_world(seed=test_seed, clock=ManualClock(), warmup=(4.0, 1800.0)).arm.effects
    assert np.array_equal(given.get("thermal_drift"), [4.0, 1800.0])
    for name in ("geometric", "backlash", "joint_compliance", "encoder_eccentricity"):
        assert np.array_equal(given.get(name), drawn.get(name))


@pytest.mark.parametrize("options, word", [
    ({"warmup": (4.0, 0.0)}, "tau_s"), ({"warmup": (-1.0, 100.0)}, "dT_max_K"), ({"warmup": ("hot",)}, "warmup"),
    ({"warmup": (4.0, float("nan"))}, "tau_s"), ({"warmup": (4.0, 100.0), "effects": None}, "effects"),
    ({"arm_rise": (10.0, -1.0)}, "arm_rise dT_K"), ({"arm_rise": (float("inf"), 1.0)}, "arm_rise t_s"),
    ({"arm_rise": "warm"}, "arm_rise"),
])
def test_a_bad_warm_up_is_refused_naming_it(options, word):
    with pytest.raises(ConfigError, match=word):
        make_world(seed=1, clock=ManualClock(), **{"effects": "realistic", **options})
