"""An external force on the simulated arm's TCP: the arm gives way through its joint compliance, as the
compliance matrix of :func:`station.models.effects.tcp_compliance_mm_per_N` says, and springs back."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from fakes.sim.world import make_world
from station.errors import DataError


def test_a_force_on_the_tool_deflects_the_arm_by_its_compliance_and_it_springs_back(test_seed, rng):
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock())
    arm = world.arm
    world.clock.advance(1.0)
    p0 = arm.tool_position_mm()
    C = arm.compliance_mm_per_N()
    assert np.allclose(C, C.T) and np.all(np.linalg.eigvalsh(C) >= -1e-12)
    rated = world.robot.rated_payload_kg * 9.80665
    F = rng.normal(size=3)
    F *= rng.uniform(0.2, 1.0) * rated / np.linalg.norm(F)
    arm.apply_tcp_force(F)
    world.clock.advance(0.5)
    d = arm.tool_position_mm() - p0
    predicted = C @ F
    # linear in the load up to second order in the joint deflection (arcmin: 1e-3 of it)
    assert np.linalg.norm(d - predicted) < 0.02 * np.linalg.norm(predicted) + 1e-4
    assert np.linalg.norm(predicted) > 1e-3  # the load moved the tool measurably
    t_loaded = world.clock.now()
    arm.apply_tcp_force([0.0, 0.0, 0.0])
    world.clock.advance(0.5)
    # thermal warm-up moves the tool a little in the second it took; the load's share is gone
    assert np.linalg.norm(arm.tool_position_mm() - p0) < 0.01 * np.linalg.norm(predicted) + 1e-3
    assert np.allclose(arm.tcp_force_N(t_loaded - 0.1), F)  # the history is kept: a past sample is the loaded one
    with pytest.raises(DataError, match="before the last change"):
        arm.apply_tcp_force(F, t_s=t_loaded - 1.0)
    with pytest.raises(DataError, match="3 finite values"):
        arm.apply_tcp_force([1.0, np.nan, 0.0])


def test_an_arm_without_joint_compliance_does_not_give_way(test_seed):
    world = make_world("industrial-3100", seed=test_seed, clock=ManualClock(), effects=None)
    p0 = world.arm.tool_position_mm()
    world.arm.apply_tcp_force([500.0, -300.0, 800.0])
    world.clock.advance(0.1)
    assert np.allclose(world.arm.tool_position_mm(), p0, atol=1e-9)
    assert np.all(world.arm.compliance_mm_per_N() == 0.0)
