import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from station.analysis.registration import fit_rigid
from station.errors import DataError, InsufficientDataError


def test_recovers_random_transform_within_noise(rng):
    R = Rotation.random(random_state=rng).as_matrix()
    t = rng.uniform(-3000, 3000, 3)
    n, sigma = 8, 0.01
    base = rng.uniform([-600, 1100, 800], [600, 2300, 2000], size=(n, 3))
    meas = base @ R.T + t + rng.normal(0, sigma, (n, 3))
    reg = fit_rigid(base, meas)
    # rms residual of a 6-parameter fit of 3n coordinates: sigma*sqrt((3n-6)/n) expected
    expect = sigma * np.sqrt((3 * n - 6) / n)
    assert 0.3 * expect < reg.rms_mm < 2.5 * expect
    probe = rng.uniform(-1000, 1000, (5, 3))
    # transferred error at ~1 m from the centroid: a few sigma at most
    assert np.max(np.linalg.norm(reg.to_tracker(probe) - (probe @ R.T + t), axis=1)) < 10 * sigma * 3
    np.testing.assert_allclose(reg.to_base(reg.to_tracker(probe)), probe, atol=1e-9)
    assert np.isclose(np.linalg.det(reg.R), 1.0)


def test_refuses_bad_input():
    with pytest.raises(InsufficientDataError, match="at least 3"):
        fit_rigid(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(5.0), [1, 2, 3])
    with pytest.raises(InsufficientDataError, match="collinear"):
        fit_rigid(line, line)
    with pytest.raises(DataError, match="same shape"):
        fit_rigid(np.zeros((4, 3)), np.zeros((5, 3)))
    bad = np.ones((4, 3))
    bad[1, 2] = np.nan
    with pytest.raises(DataError, match="p_tracker_mm contains NaN"):
        fit_rigid(np.eye(4)[:, :3], bad)


def test_axis_registration_recovers_the_base_frame_and_keeps_link_errors_out_of_it(rng):
    """Joint-1 and joint-2 circles give the base frame; errors of links 3..6 stay out of it."""
    from station.analysis.registration import fit_circle, register_by_axes
    from station.models import kinematics as K
    from station.models.robots import get_robot

    robot = get_robot("industrial-3100")
    dh = robot.dh_nominal
    true = dh.copy()
    true[2:, 0] += rng.normal(0, 1.0, 5)  # mm errors of the distal links (a)
    true[2:, 2] += rng.normal(0, 1.0, 5)  # (d)
    true[2:, 1] += np.radians(rng.normal(0, 0.05, 5))
    R = Rotation.random(random_state=rng).as_matrix()
    t = rng.uniform(-3000, 3000, 3)
    sigma = 0.015
    q0 = robot.home_q_rad.copy()
    q1 = np.tile(q0, (7, 1))
    q1[:, 0] += np.radians(np.linspace(-25, 25, 7))
    q2 = np.tile(q0, (7, 1))
    q2[:, 1] += np.radians(np.linspace(-15, 15, 7))
    meas = lambda q: K.tool_position(true, q) @ R.T + t + rng.normal(0, sigma, (len(q), 3))
    reg = register_by_axes(dh, q1, meas(q1), q2, meas(q2))
    ang = np.degrees(np.arccos(np.clip((np.trace(reg.R.T @ R) - 1) / 2, -1, 1)))
    # the plane of an arc is known to about sigma / (sagitta sqrt(n)); the joint-2 arc is the flatter one
    r2 = fit_circle(K.tool_position(true, q2)).radius_mm
    sagitta = r2 * (1 - np.cos(np.radians(15)))
    tilt = sigma / (sagitta * np.sqrt(7))  # rad, one standard error of the arc's plane
    assert ang < np.degrees(10 * tilt)  # axes 1 and 2 are nominal here
    # the origin follows from the axes (centre error ~ r * tilt), not from the distal links
    assert np.linalg.norm(reg.t_mm - t) < 10 * r2 * tilt
    assert reg.rms_mm < 5 * sigma
    # a best fit over the same points would put part of the link errors into the frame instead
    c = fit_circle(meas(q1))
    assert abs(np.linalg.norm(c.normal @ R[:, 2]) - 1) < 1e-4  # joint-1 axis is the base z axis
    with pytest.raises(InsufficientDataError, match="at least 4"):
        fit_circle(np.zeros((3, 3)))
