"""A plain full DH + Hayati least-squares fit, by scipy's MINPACK Levenberg-Marquardt, as the yardstick.

Every one of the 35 kinematic parameters and the 6 of the base transform is
free (no identifiability analysis: MINPACK's damping copes with the
redundant directions), finite-difference Jacobian, started from the nominal
table and a rigid fit. The calibration must predict held-out poses about as
well as this does (issue 22's acceptance: within 1.05x).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from station.analysis.arm.identification import rigid_fit
from station.models import kinematics as kin


def plain_fit(dh0, q, meas):
    """``(dh, base_T)`` of the full least-squares fit of the absolute positions."""
    B0 = rigid_fit(kin.tool_position(dh0, q), meas)
    x0 = np.concatenate([np.zeros(35), Rotation.from_matrix(B0[:3, :3]).as_rotvec(), B0[:3, 3]])

    def unpack(x):
        B = np.eye(4)
        B[:3, :3] = Rotation.from_rotvec(x[35:38]).as_matrix()
        B[:3, 3] = x[38:41]
        return dh0 + x[:35].reshape(7, 5), B

    def res(x):
        dh, B = unpack(x)
        return (kin.tool_position(dh, q) @ B[:3, :3].T + B[:3, 3] - meas).ravel()

    sol = least_squares(res, x0, method="lm", x_scale="jac", max_nfev=4000)
    return unpack(sol.x)


def position_error(dh, B, q, meas) -> np.ndarray:
    return np.linalg.norm(kin.tool_position(dh, q) @ B[:3, :3].T + B[:3, 3] - meas, axis=1)
