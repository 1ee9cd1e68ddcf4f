"""The identification's forward pass (station.models.frame_pass) against the kinematics it restates.

Same frames, tool points and parameter Jacobian (seed 002 eq. (3), (5), (7)-(8)) as
:mod:`station.models.kinematics`, turned by a base rotation when one is given; the Jacobian of the
kinematics is itself checked against finite differences in test_jacobians.py. Tolerance: rounding,
``1e-12`` of the largest entry (the two passes multiply the same factors in another order).
"""

from __future__ import annotations

import numpy as np
import pytest

from station.errors import DataError
from station.models import frame_pass as fpass
from station.models import kinematics as kin
from station.models.rotation import rotvec_to_matrix

from .conftest import perturbed_dh, random_q


def _close(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(float(np.abs(b).max()), 1.0))


def test_frames_tool_points_and_jacobian_are_the_kinematics_turned_by_the_base_rotation(rng, robot):
    dh = perturbed_dh(rng, robot.dh_nominal)           # every parameter off its nominal, betas included
    q = random_q(rng, robot, int(rng.integers(1, 400)))
    R = rotvec_to_matrix(rng.normal(0.0, 1.5, 3))
    fp = fpass.frame_pass(dh, q, R)
    F = kin.frames(dh, q)                              # (N, 8, 4, 4)
    # axes[k, j] is column j (x, y, z axis, origin) of frame k, turned by R, poses last
    _close(fp.axes, np.einsum("ic,nkcj->kjin", R, F[:, :, :3, :]))
    _close(fpass.tool_points(fp), kin.tool_position(dh, q) @ R.T)
    _close(fpass.param_jacobian(fp), np.matmul(R, kin.param_jacobian(dh, q)))
    # without a rotation: the kinematics themselves; turned afterwards (in place): as turned from the start
    fp0 = fpass.frame_pass(dh, q)
    _close(fpass.param_jacobian(fp0), kin.param_jacobian(dh, q))
    axes0 = fp0.axes
    assert fpass.turn(fp0, R).axes is axes0
    _close(fp0.axes, fp.axes)
    _close(fp0.turned, fp.turned)
    _close(fpass.param_jacobian(fp0), fpass.param_jacobian(fp))


def test_the_jacobian_is_written_into_a_view_of_a_wider_matrix(rng, robot):
    dh = perturbed_dh(rng, robot.dh_nominal)
    q = random_q(rng, robot, int(rng.integers(1, 100)))
    fp = fpass.frame_pass(dh, q)
    wide = np.full((q.shape[0], 3, kin.N_PARAMS + 6), 7.0)
    got = fpass.param_jacobian(fp, out=wide[:, :, :kin.N_PARAMS])
    assert np.shares_memory(got, wide)
    _close(wide[:, :, :kin.N_PARAMS], kin.param_jacobian(dh, q))
    assert np.all(wide[:, :, kin.N_PARAMS:] == 7.0)       # the columns beyond are left alone


def test_bad_shapes_are_refused_by_name(rng, robot):
    q = random_q(rng, robot, 5)
    with pytest.raises(DataError, match="dh"):
        fpass.frame_pass(np.stack([robot.dh_nominal] * 5), q)     # one table per pose: not this pass's job
    with pytest.raises(DataError, match="q_rad"):
        fpass.frame_pass(robot.dh_nominal, q[:, :5])
    fp = fpass.frame_pass(robot.dh_nominal, q)
    with pytest.raises(DataError, match="out"):
        fpass.param_jacobian(fp, out=np.empty((4, 3, kin.N_PARAMS)))
