"""The simulated arm's localised joint flaw (the "one pose out" robot)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from fakes.sim.joint_defect import JointDefect
from fakes.sim.world import make_world
from station.errors import ConfigError


def test_the_flaw_moves_its_joint_at_its_angle_and_nowhere_else(rng):
    j = int(rng.integers(1, 7))
    centre, width, amp = rng.uniform(-90, 90), rng.uniform(0.02, 2.0), rng.uniform(0.05, 0.5)
    d = JointDefect(j, centre, width, amp)
    q = rng.uniform(-2.0, 2.0, (50, 6))
    q[0, j - 1] = math.radians(centre)
    q[1, j - 1] = math.radians(centre + 6.0 * width)
    q_true = d.apply(q, q)
    assert q_true[0, j - 1] - q[0, j - 1] == pytest.approx(math.radians(amp), rel=1e-12)
    assert abs(q_true[1, j - 1] - q[1, j - 1]) < 1e-7 * math.radians(amp)  # exp(-18) of it six widths away
    others = [k for k in range(6) if k != j - 1]
    assert np.array_equal(q_true[:, others], q[:, others])


def test_the_world_s_arm_carries_the_flaw(rng):
    """A flaw at the arm's standing angle of joint J: the true joints are off by its amplitude there."""
    J = int(rng.integers(1, 4))
    amp = float(rng.uniform(0.05, 0.5))
    plain = make_world(seed=3, clock=ManualClock(), effects=None, servo=None, stop_sigma_mm=None)
    _, q0 = plain.arm.true_model(0.0)
    d = {"joint": J, "centre_deg": math.degrees(q0[0, J - 1]), "width_deg": 0.1, "amplitude_deg": amp}
    flawed = make_world(seed=3, clock=ManualClock(), effects=None, servo=None, stop_sigma_mm=None, joint_defect=d)
    _, q1 = flawed.arm.true_model(0.0)
    assert q1[0, J - 1] - q0[0, J - 1] == pytest.approx(math.radians(amp), rel=1e-9)
    assert np.array_equal(np.delete(q1, J - 1, axis=1), np.delete(q0, J - 1, axis=1))
    p0, p1 = plain.arm.tool_position_mm(0.0), flawed.arm.tool_position_mm(0.0)
    assert np.linalg.norm(p1 - p0) > 0.5 * math.radians(amp) * 100.0  # a lever of more than 100 mm


@pytest.mark.parametrize("bad, why", [({"joint": 7, "centre_deg": 0, "width_deg": 1, "amplitude_deg": 1}, "1..6"),
                                      ({"joint": 2, "centre_deg": 0, "width_deg": 0, "amplitude_deg": 1}, "> 0"),
                                      ({"joint": 2, "centre_deg": 0, "width_deg": 1}, "amplitude_deg"),
                                      ({"joint": 2, "centre_deg": 0, "width_deg": 1, "amplitude_deg": 1, "x": 1},
                                       "unknown key")])
def test_a_bad_flaw_is_refused_by_name(bad, why):
    with pytest.raises(ConfigError, match=why):
        make_world(seed=1, clock=ManualClock(), joint_defect=bad)
