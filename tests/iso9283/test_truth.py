"""The noise-free prediction of an ISO 9283 run from an arm's known errors (procedures.iso9283_truth).

Each case has an answer that follows from geometry alone: a nominal arm
attains every pose; an error of the tool row moves every attained point
without touching the axes the registration finds; a zero offset of joint 1
turns the whole arm about the axis the registration measures, so the frame
takes it up and AP stays zero although the points moved by millimetres.
The sizes are drawn at random each run.
"""

import math

import numpy as np
import pytest

from procedures.iso9283 import plan_from_config
from procedures.iso9283_truth import pose_joints_rad, predict_static
from station.commands.demo import demo_config
from station.config import config_from_dict
from station.errors import ConfigError
from station.models import kinematics as kin
from station.models.effects import EffectSet


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    cfg = demo_config(tmp_path_factory.mktemp("truth"), cycles=5, vap_cycles=2, rate_hz=100.0)
    return plan_from_config(config_from_dict(cfg, "demo"))


def _geometric(plan, row, col, value):
    geo = np.zeros((7, 5))
    geo[row, col] = value
    return EffectSet.from_params({"geometric": geo.ravel()})


def test_nominal_arm_attains_every_pose(plan):
    pred = predict_static(plan, None)
    assert set(pred.AP_mm) == set(plan.poses_mm)
    # the safety gate solves the IK to 1e-3 mm or better
    assert max(pred.AP_mm.values()) < 2e-3
    assert abs(pred.AD_mm["P2-P4"]) < 2e-3


def test_tool_row_error_is_all_of_AP(plan, rng):
    # tool row lengths a and d (seed 002 eq. (3) last row): the joint axes stay where they are
    da, dd = rng.uniform(0.5, 3.0, 2) * rng.choice([-1.0, 1.0], 2)
    geo = np.zeros((7, 5))
    geo[6, 0], geo[6, 2] = da, dd
    eff = EffectSet.from_params({"geometric": geo.ravel()})
    pred = predict_static(plan, eff)
    q = pose_joints_rad(plan)
    true = kin.fk(plan.robot.dh_nominal + geo, q)[:, :3, 3]
    cmd = np.array(list(plan.poses_mm.values()))
    raw = np.linalg.norm(true - cmd, axis=1)
    assert np.allclose([pred.AP_mm[n] for n in plan.poses_mm], raw, atol=2e-3)
    # a tool-length error is seen at every pose: AP = |(da, dd)| in the tool frame
    assert np.allclose(raw, math.hypot(da, dd), atol=2e-3)


def test_joint1_zero_offset_is_taken_up_by_the_axis_registration(plan, rng):
    eps = math.radians(rng.uniform(0.05, 0.5)) * rng.choice([-1.0, 1.0])
    eff = _geometric(plan, 0, 3, eps)  # theta offset of joint 1
    pred = predict_static(plan, eff)
    q = pose_joints_rad(plan)
    true = kin.fk(plan.robot.dh_nominal + eff.get("geometric").reshape(7, 5), q)[:, :3, 3]
    cmd = np.array(list(plan.poses_mm.values()))
    raw = np.linalg.norm(true - cmd, axis=1)
    # the points moved by the turn about the base z axis: radius * eps
    assert np.allclose(raw, np.linalg.norm(cmd[:, :2], axis=1) * abs(eps), rtol=1e-3)
    assert max(pred.AP_mm.values()) < 2e-3
    assert abs(pred.AD_mm["P2-P4"]) < 2e-3


def test_prediction_needs_the_axis_registration(plan):
    from dataclasses import replace

    with pytest.raises(ConfigError, match="axis registration"):
        predict_static(replace(plan, registration="best-fit"), None)
