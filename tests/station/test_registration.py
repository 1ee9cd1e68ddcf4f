import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from station.analysis.registration import fit_rigid
from station.errors import DataError, InsufficientDataError


def test_recovers_random_transform_within_noise():
    rng = np.random.default_rng()
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
