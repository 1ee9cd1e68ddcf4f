"""Fixtures for the kinematics tests.

Random draws come from the ``rng`` fixture of tests/seeding.py: they differ on
every run (the point is to catch what one lucky seed would hide); a failing
test prints the seed and the command that replays it.
"""

from __future__ import annotations


import numpy as np
import pytest

from station.models.robots import ROBOT_NAMES, get_robot


@pytest.fixture(params=ROBOT_NAMES)
def robot(request):
    return get_robot(request.param)


def random_q(rng, robot, n, margin_rad=0.0):
    """Joint angles drawn uniformly inside the robot's limits (shrunk by margin)."""
    lo = robot.joint_limits_rad[:, 0] + margin_rad
    hi = robot.joint_limits_rad[:, 1] - margin_rad
    return lo + (hi - lo) * rng.random((n, 6))


def perturbed_dh(rng, dh, n=None, len_sigma_mm=1.0, ang_sigma_rad=2e-3):
    """A DH table with random deviations in all 35 parameters (betas included)."""
    shape = (7, 5) if n is None else (n, 7, 5)
    scale = np.array([len_sigma_mm, ang_sigma_rad, len_sigma_mm, ang_sigma_rad, ang_sigma_rad])
    return dh + rng.standard_normal(shape) * scale


def well_conditioned_q(rng, robot, n, margin_rad=0.05, min_sv=0.02):
    """Random joint angles inside the limits, away from singular arm poses.

    Keeps draws whose joint Jacobian (linear rows divided by the arm's reach,
    angular rows as they are) has its smallest singular value above
    ``min_sv``: a stretched elbow or aligned wrist axes make targets within
    a hair of the workspace boundary, which a local solver reaches only
    slowly and which no test pose of the station uses.
    """
    from station.models.kinematics import joint_jacobian

    reach = np.abs(robot.dh_nominal[:, [0, 2]]).sum()
    out = np.empty((0, 6))
    while len(out) < n:
        q = random_q(rng, robot, 4 * n, margin_rad)
        J = joint_jacobian(robot.dh_nominal, q)
        J[:, :3] /= reach
        sv = np.linalg.svd(J, compute_uv=False).min(axis=1)
        out = np.concatenate([out, q[sv > min_sv]])
    return out[:n]
