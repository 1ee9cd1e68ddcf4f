"""A plain full DH + Hayati least-squares fit, by scipy's MINPACK Levenberg-Marquardt, as the yardstick.

Every one of the 35 kinematic parameters and the 6 of the base transform is
free (no identifiability analysis: MINPACK's damping copes with the
redundant directions), started from the nominal table and a rigid fit. The
Jacobian's kinematic columns are seed 002 eq. (7)-(8) in closed form
(:func:`station.models.kinematics.fk_and_param_jacobian`, checked against
finite differences in tests/kinematics), the base rotation's by central
differences of the rotation alone (MINPACK's own finite differences of all
41 columns made this fit most of the calibration tests' time). The calibration must predict held-out poses about as
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

    def jac(x):
        dh, B = unpack(x)
        T, Jp = kin.fk_and_param_jacobian(dh, q)
        p = T[:, :3, 3]
        cols = [np.einsum("ij,njk->nik", B[:3, :3], Jp)]
        h = 1e-7
        rot = []
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            Rp = Rotation.from_rotvec(x[35:38] + e).as_matrix()
            Rm = Rotation.from_rotvec(x[35:38] - e).as_matrix()
            rot.append(p @ ((Rp - Rm) / (2 * h)).T)
        cols += [np.stack(rot, axis=2), np.broadcast_to(np.eye(3), (q.shape[0], 3, 3))]
        return np.concatenate(cols, axis=2).reshape(-1, 41)

    sol = least_squares(res, x0, jac=jac, method="lm", x_scale="jac", xtol=1e-14, max_nfev=4000)
    return unpack(sol.x)


def position_error(dh, B, q, meas) -> np.ndarray:
    return np.linalg.norm(kin.tool_position(dh, q) @ B[:3, :3].T + B[:3, 3] - meas, axis=1)
