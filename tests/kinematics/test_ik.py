"""Numerical IK: round trips on random reachable targets, joint limits, the
seed 000 test cube on the large arm, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from station.errors import ConfigError, DataError
from station.models.kinematics import fk, ik, joint_jacobian, tool_position
from station.models.robots import get_robot

from .conftest import well_conditioned_q

# seed 000 Table 1 (cube corners C1..C8) and Table 2 (P1..P5), mm, base frame
CUBE_CORNERS = np.array(
    [
        [600, 2300, 2000], [600, 1100, 2000], [-600, 1100, 2000], [-600, 2300, 2000],
        [600, 2300, 800], [600, 1100, 800], [-600, 1100, 800], [-600, 2300, 800],
    ],
    dtype=float,
)
SEED_POSES = np.array(
    [[0, 1700, 1400], [-500, 2200, 1900], [500, 2200, 1900], [500, 1200, 900], [-500, 1200, 900]],
    dtype=float,
)
# Reflector orientation: tool z axis along +y (towards a tracker standing in
# front of the cube), tool x axis pointing down.
R_REFLECTOR = np.column_stack([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _inside(q, lim):
    return np.all((q >= lim[:, 0] - 1e-12) & (q <= lim[:, 1] + 1e-12))


@pytest.mark.parametrize("name", ["rb5-850", "ur5e", "industrial-3100"])
def test_pose_round_trip(rng, name):
    robot = get_robot(name)
    lim = robot.joint_limits_rad
    q_true = well_conditioned_q(rng, robot, 30)
    T = fk(robot.dh_nominal, q_true)
    # start near the truth (the controller case: seed = current pose)
    q0 = np.clip(q_true + rng.normal(0, 0.2, q_true.shape), lim[:, 0], lim[:, 1])
    res = ik(robot.dh_nominal, T, q0=q0, joint_limits_rad=lim, tol_mm=1e-4, tol_deg=1e-5)
    assert res.success.all(), (res.residual_mm, res.residual_deg)
    assert res.residual_deg is not None
    assert _inside(res.q_rad, lim)
    T_sol = fk(robot.dh_nominal, res.q_rad)
    assert np.abs(T_sol[:, :3, 3] - T[:, :3, 3]).max() < 1e-4
    cosang = (np.einsum("nij,nij->n", T_sol[:, :3, :3], T[:, :3, :3]) - 1) / 2
    assert np.rad2deg(np.arccos(np.clip(cosang, -1, 1))).max() < 1e-4
    np.testing.assert_allclose(res.residual_mm, np.linalg.norm(T_sol[:, :3, 3] - T[:, :3, 3], axis=1), atol=1e-12)


def test_round_trip_from_home_uses_restarts(rng):
    robot = get_robot("ur10e")
    q_true = well_conditioned_q(rng, robot, 40)
    T = fk(robot.dh_nominal, q_true)
    res = ik(robot.dh_nominal, T, q0=robot.home_q_rad, joint_limits_rad=robot.joint_limits_rad, seed=int(rng.integers(1 << 31)))
    assert res.success.all()
    assert (res.attempts >= 1).all() and (res.iterations >= 1).all()
    np.testing.assert_allclose(fk(robot.dh_nominal, res.q_rad), T, atol=1e-3)


def test_position_targets(rng):
    robot = get_robot("rb5-850-as-built")
    q_true = well_conditioned_q(rng, robot, 25)
    p = tool_position(robot.dh_nominal, q_true)
    res = ik(robot.dh_nominal, p, q0=robot.home_q_rad, joint_limits_rad=robot.joint_limits_rad)
    assert res.success.all()
    assert res.residual_deg is None
    assert np.linalg.norm(tool_position(robot.dh_nominal, res.q_rad) - p, axis=1).max() < 1e-4


def _conditioned_uniform(rng, robot, lo, hi, min_sv=0.02):
    """Joint angles uniform in [lo, hi] whose scaled joint Jacobian (see ``well_conditioned_q``) has its
    smallest singular value above ``min_sv``."""
    reach = np.abs(robot.dh_nominal[:, [0, 2]]).sum()
    while True:
        q = rng.uniform(lo, hi, (8, 6))
        J = joint_jacobian(robot.dh_nominal, q)
        J[:, :3] /= reach
        ok = np.linalg.svd(J, compute_uv=False).min(axis=1) > min_sv
        if ok.any():
            return q[np.argmax(ok)]


def test_joint_limits_are_respected(rng):
    # Narrow limits around a random pose: the only solutions inside are near
    # it; every returned q (success or not) stays inside.
    #
    # Near the shoulder singularity (wrist centre close to the joint-1 axis) a
    # turn of joint 1 is nearly undone by the other joints, so a target "out
    # of reach" of joint 1 has a near solution inside the limits: the poses
    # are drawn away from singular arm poses, as ``well_conditioned_q`` does.
    robot = get_robot("ur5e")
    q_mid = _conditioned_uniform(rng, robot, -1.5, 1.5)
    lim = np.column_stack([q_mid - 0.3, q_mid + 0.3])
    q_true = q_mid + rng.uniform(-0.25, 0.25, (20, 6))
    T = fk(robot.dh_nominal, q_true)
    q0 = q_mid + 0.5  # outside: clipped into the limits
    res = ik(robot.dh_nominal, T, q0=q0, joint_limits_rad=lim)
    assert _inside(res.q_rad, lim)
    assert res.success.all()
    # a target that needs joint 1 outside its limit cannot be reached
    q_out = q_mid.copy()
    q_out[0] += 0.6
    res2 = ik(robot.dh_nominal, fk(robot.dh_nominal, q_out[None]), joint_limits_rad=lim, n_restarts=3)
    assert not res2.success[0]
    assert _inside(res2.q_rad, lim)
    assert res2.residual_mm[0] > 1.0 or res2.residual_deg[0] > 0.1


def test_unreachable_target_is_a_status_not_an_exception():
    robot = get_robot("ur5e")
    far = np.array([[5000.0, 0.0, 0.0], [300.0, 200.0, 400.0]])
    res = ik(robot.dh_nominal, far, q0=robot.home_q_rad, joint_limits_rad=robot.joint_limits_rad, n_restarts=2)
    assert res.success.tolist() == [False, True]
    reach = 425.0 + 392.2 + 133.3 + 99.7 + 99.6 + 162.5
    assert res.residual_mm[0] > 5000.0 - reach


def test_industrial_arm_reaches_the_seed000_cube_and_poses():
    robot = get_robot("industrial-3100")
    pts = np.concatenate([CUBE_CORNERS, SEED_POSES])
    T = np.tile(np.eye(4), (len(pts), 1, 1))
    T[:, :3, :3] = R_REFLECTOR
    T[:, :3, 3] = pts
    res = ik(robot.dh_nominal, T, q0=robot.home_q_rad, joint_limits_rad=robot.joint_limits_rad)
    assert res.success.all(), np.column_stack([res.residual_mm, res.residual_deg])
    assert _inside(res.q_rad, robot.joint_limits_rad)
    np.testing.assert_allclose(fk(robot.dh_nominal, res.q_rad)[:, :3, 3], pts, atol=1e-3)
    # away from the wrist singularity (|sin q5| > 0.1) so the poses are well posed
    assert np.all(np.abs(np.sin(res.q_rad[:, 4])) > 0.1)


@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(target=np.zeros((3, 4))), DataError, "target"),
        (dict(target=np.full((2, 3), np.nan)), DataError, "target"),
        (dict(target=np.diag([1.0, 1.0, -1.0, 1.0])), DataError, "target"),
        (dict(target=2 * np.eye(4)), DataError, "target"),
        (dict(target=np.zeros(3), joint_limits_rad=np.zeros((5, 2))), DataError, "joint_limits_rad"),
        (dict(target=np.zeros(3), joint_limits_rad=np.tile([1.0, -1.0], (6, 1))), DataError, "joint 1"),
        (dict(target=np.zeros(3), q0=np.zeros(5)), DataError, "q0"),
        (dict(target=np.zeros((2, 3)), q0=np.zeros((3, 6))), DataError, "q0"),
        (dict(target=np.zeros(3), tol_mm=-1.0), ConfigError, "tol_mm"),
        (dict(target=np.zeros(3), max_iter=0), ConfigError, "max_iter"),
        (dict(target=np.zeros(3), n_restarts=1.5), ConfigError, "n_restarts"),
    ],
)
def test_bad_input_refused(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        ik(get_robot("ur5e").dh_nominal, **kwargs)


def test_ik_needs_one_table():
    with pytest.raises(DataError, match="dh"):
        ik(np.zeros((2, 7, 5)), np.zeros(3))
