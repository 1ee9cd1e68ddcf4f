"""The simulated arm warms from its cold start as the world is told (``warmup``: a drift test's known truth)."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from fakes.sim.world import make_world
from station.errors import ConfigError
from station.models.arm_extended import STEEL_ALPHA_PER_K
from station.models.effects import EffectSet


def test_the_arm_at_rest_grows_by_the_first_order_warm_up_it_was_given(rng, test_seed):
    dT, tau = float(rng.uniform(1.0, 8.0)), float(rng.uniform(600.0, 7200.0))
    thermal_only = EffectSet.from_params({}, enabled=("thermal_drift",))
    clock = ManualClock()
    world = make_world(seed=test_seed, clock=clock, effects=thermal_only, servo=None, warmup=(dT, tau))
    assert np.array_equal(world.arm.effects.get("thermal_drift"), [dT, tau])
    p0 = world.arm.tool_position_mm(0.0)
    for t in rng.uniform(0.0, 5.0 * tau, 4):
        # every link length a, d scales by 1 + alpha dT(t): the resting tool point scales about the base so
        grown = STEEL_ALPHA_PER_K * dT * (1.0 - np.exp(-t / tau))
        assert np.allclose(world.arm.tool_position_mm(float(t)), (1.0 + grown) * p0, rtol=0, atol=1e-9)


def test_the_realistic_arm_keeps_its_drawn_effects_but_the_warm_up_given(test_seed):
    drawn = make_world(seed=test_seed, clock=ManualClock()).arm.effects
    given = make_world(seed=test_seed, clock=ManualClock(), warmup=(4.0, 1800.0)).arm.effects
    assert np.array_equal(given.get("thermal_drift"), [4.0, 1800.0])
    for name in ("geometric", "backlash", "joint_compliance", "encoder_eccentricity"):
        assert np.array_equal(given.get(name), drawn.get(name))


@pytest.mark.parametrize("warmup, effects, word", [
    ((4.0, 0.0), "realistic", "tau_s"), ((-1.0, 100.0), "realistic", "dT_max_K"), (("hot",), "realistic", "warmup"),
    ((4.0, float("nan")), "realistic", "tau_s"), ((4.0, 100.0), None, "effects"),
])
def test_a_bad_warm_up_is_refused_naming_it(warmup, effects, word):
    with pytest.raises(ConfigError, match=word):
        make_world(seed=1, clock=ManualClock(), effects=effects, warmup=warmup)
