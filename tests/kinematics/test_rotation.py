"""Rotation vectors of rotation matrices (station.models.rotation) against scipy's."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from station.models.rotation import rotvec_of, rotvec_to_matrix


def test_rotation_vectors_of_the_stream_are_scipys(rng):
    """The rotation vectors of the fake's stream (TCP pose, angular speed) and the driver's moves against scipy's, over random rotations and
    angles near 0, near the series' switch at 1e-3 rad and near pi, where the quaternion's choice matters."""
    R = Rotation.random(2000, random_state=int(rng.integers(2**31)))
    np.testing.assert_allclose(rotvec_of(R.as_matrix()), R.as_rotvec(), atol=1e-13)
    axis = rng.normal(size=(600, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.concatenate([10.0 ** rng.uniform(-12, -2, 200), 1e-3 * (1 + rng.uniform(-1e-3, 1e-3, 200)),
                            np.pi - 10.0 ** rng.uniform(-12, -2, 200)])
    M = Rotation.from_rotvec(axis * angle[:, None]).as_matrix()
    ours = rotvec_of(M)
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), angle, rtol=0, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_rotvec(ours).as_matrix(), M, atol=1e-13)
    # a few rows at a time (the stream's batches) go another way: the same vectors
    edges = np.unique(np.concatenate([[0], np.cumsum(rng.integers(1, 9, 600)), [600]]).clip(0, 600))
    few = np.concatenate([rotvec_of(M[a:b]) for a, b in zip(edges[:-1], edges[1:])])
    np.testing.assert_allclose(few, ours, rtol=0, atol=1e-13)
    assert rotvec_of(np.zeros((0, 3, 3))).shape == (0, 3)


def test_matrices_of_rotation_vectors_one_at_a_time_are_the_array_paths_and_scipys(rng):
    """One vector goes through plain floats (an identification's step): the same matrices as the array path
    and scipy's, from angles near 0 (and below 1e-12 rad, the identity) to near pi; NaN stays NaN."""
    axis = rng.normal(size=(300, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.concatenate([10.0 ** rng.uniform(-11, -2, 100), rng.uniform(0.0, np.pi, 100),
                            np.pi - 10.0 ** rng.uniform(-12, -2, 100)])
    v = axis * angle[:, None]
    one = np.array([rotvec_to_matrix(x) for x in v])
    np.testing.assert_allclose(one, rotvec_to_matrix(v), rtol=0, atol=2e-15)
    np.testing.assert_allclose(one, Rotation.from_rotvec(v).as_matrix(), rtol=0, atol=2e-15)
    assert np.array_equal(rotvec_to_matrix(axis[0] * 1e-13), np.eye(3))
    assert np.isnan(rotvec_to_matrix(np.array([np.nan, 0.0, 0.0]))).all()
