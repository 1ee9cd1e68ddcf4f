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
from fakes.cells import demo_config
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


def test_scatter_is_zero_without_noise_and_grows_with_it(plan, rng):
    from procedures.iso9283_truth import RunGeometry, prediction_scatter

    geo = RunGeometry.of(plan)
    none = prediction_scatter(plan, None, np.zeros(6), cycles=3, draws=20, geometry=geo)
    assert max(none.AP_rms_mm.values()) < 1e-6 and none.AD_sd_mm["P2-P4"] < 1e-6
    sigma = np.full(6, math.radians(rng.uniform(2e-4, 1e-3)))  # ~0.01-0.05 mm at the TCP
    seed = int(rng.integers(2**31))
    one = prediction_scatter(plan, None, sigma, cycles=3, draws=40, rng=np.random.default_rng(seed), geometry=geo)
    two = prediction_scatter(plan, None, 2 * sigma, cycles=3, draws=40, rng=np.random.default_rng(seed), geometry=geo)
    # rms length of one stop's TCP offset at each pose
    J = kin.joint_jacobian(plan.robot.dh_nominal, pose_joints_rad(plan))[:, :3] * sigma
    stop_rms = np.sqrt(np.einsum("pij,pij->p", J, J))
    for k, n in enumerate(plan.poses_mm):
        # the same normal draws: small errors propagate linearly through the fits
        assert two.AP_rms_mm[n] == pytest.approx(2 * one.AP_rms_mm[n], rel=0.02)
        # the short arcs' circle fits amplify the point scatter: the frame error at the poses is far
        # above one stop's offset, let alone the mean of three
        assert one.AP_rms_mm[n] > 3 * stop_rms[k], (n, one.AP_rms_mm[n], stop_rms[k])
    with pytest.raises(ConfigError, match="stop_sigma_rad"):
        prediction_scatter(plan, None, np.zeros(5), cycles=3)
    with pytest.raises(ConfigError, match="cycles >= 1"):
        prediction_scatter(plan, None, sigma, cycles=0)


def test_the_registration_absorbs_the_trackers_offset_and_angles_not_its_scale(plan, rng):
    """The tracker's MPE as a systematic error of each draw (tracker_accuracy): an offset of its frame moves the
    registration with it (AP unchanged), its angles turn it with it, and what is left is its scale error, of
    the order of b / 2 ppm times the distances."""
    from procedures.iso9283_truth import RunGeometry, prediction_scatter

    geo = RunGeometry.of(plan)
    origin = np.array([rng.uniform(-3000, 3000), rng.uniform(-3000, 3000), rng.uniform(500, 1500)])
    zero = np.zeros(6)
    kw = dict(cycles=3, draws=30, geometry=geo)
    offset = prediction_scatter(plan, None, zero, tracker_accuracy=(origin, 50.0, 0.0), rng=np.random.default_rng(1),
                                **kw)
    assert max(offset.AP_rms_mm.values()) < 1e-6
    b = rng.uniform(5.0, 20.0)
    scale = prediction_scatter(plan, None, zero, tracker_accuracy=(origin, 0.0, b), rng=np.random.default_rng(2),
                               **kw)
    poses = np.array(list(plan.poses_mm.values()))
    reach = np.linalg.norm(poses - origin, axis=1).max()
    ap = np.array(list(scale.AP_rms_mm.values()))
    assert np.all(ap > 0) and np.all(ap < 3 * b / 2 * 1e-6 * reach), (ap, b, reach)
