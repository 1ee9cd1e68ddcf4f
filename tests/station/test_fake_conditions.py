"""Fake cells drawn in or out of the robot's limits (station.acceptance.fake_robot_seed)."""

import numpy as np
import pytest

from fakes.sim.clock import ManualClock
from fakes.sim.world import make_world
from procedures.iso9283 import plan_from_config
from procedures.iso9283_truth import predict_static
from station.acceptance import SPEC_MARGIN_MM, Station, fake_robot_seed
from station.errors import ConfigError, InsufficientDataError


def _prediction(station: Station):
    plan = plan_from_config(station.config, "r1")
    world = make_world(robot=plan.robot.name, seed=station.seed, clock=ManualClock(), payload_kg=plan.payload_kg)
    try:
        return plan, predict_static(plan, world.arm.effects)
    finally:
        world.close()


def test_in_and_out_of_spec_cells_keep_their_margin(tmp_path, world_seed):
    good = Station.fake(tmp_path / "a", seed=world_seed, condition="in-spec")
    bad = Station.fake(tmp_path / "b", seed=world_seed, condition="out-of-spec")
    assert good.seed >= world_seed and bad.seed >= world_seed and good.seed != bad.seed
    plan, pred = _prediction(good)
    assert pred.worst_AP_mm() <= plan.limits["AP_mm"] - SPEC_MARGIN_MM
    assert abs(pred.AD_mm["P2-P4"]) <= plan.limits["AD_mm"] - SPEC_MARGIN_MM
    plan, pred = _prediction(bad)
    assert pred.worst_AP_mm() >= plan.limits["AP_mm"] + SPEC_MARGIN_MM
    # the first such cell: every seed before it is not out of spec
    assert fake_robot_seed(bad.config, world_seed, "out-of-spec") == bad.seed
    # as drawn: the seed asked for
    assert Station.fake(tmp_path / "c", seed=world_seed).seed == world_seed


def test_conditions_refused_clearly(tmp_path, world_seed):
    with pytest.raises(ConfigError, match="condition must be one of"):
        Station.fake(tmp_path, seed=world_seed, condition="nice")
    with pytest.raises(ConfigError, match="ap_limit_mm is needed"):
        Station.fake(tmp_path, seed=world_seed, condition="out-of-spec", limits={"rp_limit_mm": 0.5})
    st = Station.fake(tmp_path, seed=world_seed, limits={"ap_limit_mm": 0.5})
    with pytest.raises(InsufficientDataError, match="no fake cell in-spec among seeds"):
        fake_robot_seed(st.config, world_seed, "in-spec", max_tries=20)
