"""The registered frame's rotation in the uncertainty of orientation AP (a, b, c).

A tracker-to-base registration fitted on noisy points is turned by a small rotation; every orientation measured
through it is turned alike, so orientation AP is off by up to that angle, the same at every stop. The budget
states the rotation's covariance (a point-pair fit's normal equations, or the procedure's jackknife of its axis
registration), and orientation AP's U carries it; RP does not (a fixed rotation changes no scatter).

The tests draw registrations with noise on their points, check the stated covariance against the spread of
the fitted rotations, and that orientation AP measured through each drawn frame lies within U of the truth at
the stated rate (and would not without the frame's term); a frame fitted on fewer or closer points gives AP a
larger U.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from station.analysis.iso9283.characteristics import OrientationAR
from station.analysis.iso9283.orientation import abc_in_base, abc_of_matrices
from station.analysis.iso9283.uncertainty import orientation_uncertainty
from station.analysis.registration import fit_rigid, register_by_axes
from station.analysis.uncertainty import Budget, rigid_fit_rotation_cov_rad2
from station.errors import ConfigError, DataError
from station.models.rotation import rotvec_of, rotvec_to_matrix

#: one-sided tail of each check on drawn data
TAIL = 1e-5


def _matrix(abc) -> np.ndarray:
    """R = Rz(c) Ry(b) Rx(a) of angles (N, 3), rad -> (N, 3, 3)."""
    a, b, c = np.asarray(abc, dtype=float).reshape(-1, 3).T
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.stack([np.stack([cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa], -1),
                     np.stack([sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa], -1),
                     np.stack([-sb, cb * sa, cb * ca], -1)], -2)


def _quat(R) -> np.ndarray:
    """Unit quaternions (N, 4), scalar first, of rotation matrices (N, 3, 3) (through their rotation vectors)."""
    rv = np.array([rotvec_of(r).ravel() for r in R])
    ang = np.linalg.norm(rv, axis=1)
    axis = rv / np.where(ang > 0, ang, 1.0)[:, None]
    return np.column_stack([np.cos(ang / 2), axis * np.sin(ang / 2)[:, None]])


def _wrap(x):
    return (np.asarray(x) + math.pi) % (2 * math.pi) - math.pi


def test_a_frame_rotation_moves_the_angles_as_the_budget_says(rng):
    """Draws of a rotation with the stated covariance applied to a drawn orientation: the spread of each angle
    is the budget's sd (J^-1 of the rotation), within what 20000 draws leave."""
    A = rng.normal(size=(3, 3))
    cov = A @ A.T * float(rng.uniform(1e-4, 1e-2))  # deg^2
    abc = np.array([rng.uniform(-math.pi, math.pi), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi)])
    b = Budget(registration_rotation_cov_deg2=tuple(map(tuple, cov)))
    M = 20_000
    d = rng.standard_normal((M, 3)) @ np.linalg.cholesky(np.radians(np.radians(cov))).T
    R = rotvec_to_matrix(d) @ _matrix(abc)[0]
    spread = np.degrees(_wrap(abc_of_matrices(R) - abc)).std(axis=0)
    # an sd of M normal draws is off by sd / sqrt(2 M); the second-order terms of 0.1 deg rotations are far less
    z = stats.norm.isf(TAIL / 6)
    assert np.allclose(spread, b.registration_angle_sd_deg(abc), rtol=z / math.sqrt(2 * M) + 2e-3, atol=0)
    assert np.all(Budget().registration_angle_sd_deg(abc) == 0.0)
    # tool down (a = 180 deg, b = c = 0): a, b, c are turned by the rotations about x, y, z themselves
    assert np.allclose(b.registration_angle_sd_deg([math.pi, 0.0, 0.0]), np.sqrt(np.diag(cov)), rtol=1e-9)


def test_a_bad_rotation_covariance_is_refused_naming_it():
    for bad in (((1.0, 0.0), (0.0, 1.0)), ((1.0, 0.5, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
                ((-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
                ((math.nan, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))):
        with pytest.raises(ConfigError, match="registration_rotation_cov_deg2"):
            Budget(registration_rotation_cov_deg2=bad)
    with pytest.raises(DataError, match="collinear"):
        rigid_fit_rotation_cov_rad2(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]), 0.01)


class _Cell:
    """A drawn measurement of one pose's orientation through a fitted frame: the true frame, the tool's true
    rest orientation, the stops' scatter and the 6-DoF angle noise (rad)."""

    def __init__(self, rng, n_stops: int):
        self.R0 = rotvec_to_matrix(rng.normal(0.0, 1.5, 3))
        self.t0 = rng.normal(0.0, 3000.0, 3)
        self.cmd = np.array([math.pi, 0.0, 0.0])  # the procedure's tool down
        self.true = self.cmd + rng.normal(0.0, math.radians(0.05), 3)  # the arm's orientation error
        self.n = n_stops
        self.scatter = math.radians(float(rng.uniform(0.5e-3, 1e-3)))  # the stops' own, per angle
        self.noise_deg = float(rng.uniform(0.5e-3, 1e-3))  # a 6-DoF target's reading noise

    def measure(self, rng, base_points, sigma_mm):
        """Register on ``base_points`` read with ``sigma_mm`` noise per axis; the stops read through it."""
        meas = base_points @ self.R0.T + self.t0 + sigma_mm * rng.standard_normal(base_points.shape)
        reg = fit_rigid(base_points, meas)
        stops = self.true + self.scatter * rng.standard_normal((self.n, 3))
        R_tracker = self.R0 @ _matrix(stops)
        read = R_tracker @ rotvec_to_matrix(math.radians(self.noise_deg) * rng.standard_normal((self.n, 3)))
        return reg, abc_in_base(_quat(read), reg.R)

    def figures(self, abc, budget: Budget):
        """Orientation AP/RP of the measured angles (the pose analysis' formulas) and their uncertainties."""
        dev = _wrap(abc - self.cmd)
        S = dev.std(axis=0, ddof=1)
        o = OrientationAR(dev.mean(axis=0), 3.0 * S, _wrap(self.cmd + dev.mean(axis=0)), S, self.n,
                          np.arange(self.n))
        return o, orientation_uncertainty(o, budget, "P1")


def _box(rng, n: int, half_mm: float) -> np.ndarray:
    """n registration points in a box of half-width ``half_mm`` about a drawn centre (the inset cube's)."""
    return rng.normal(0.0, 500.0, 3) + rng.uniform(-half_mm, half_mm, (n, 3))


def _coverage(rng, cell: _Cell, n_points: int, half_mm: float, sigma_mm: float, trials: int):
    """Over ``trials`` drawn registrations (one drawn angle each: independent trials): the fitted frame's
    rotation error, its stated sd, |AP - truth| and U with and without the frame's term, and RP's U."""
    rows = []
    for _ in range(trials):
        base = _box(rng, n_points, half_mm)
        reg, abc = cell.measure(rng, base, sigma_mm)
        budget = Budget(trials=2000, seed=int(rng.integers(2**31)), angle_sd_deg=cell.noise_deg
                        ).with_registration(reg, base)
        o, fu = cell.figures(abc, budget)
        _, bare = cell.figures(abc, replace(budget, registration_rotation_cov_deg2=None))
        j = int(rng.integers(3))
        ax = "abc"[j]
        err = abs(fu[f"AP{ax}_deg"].value - math.degrees(cell.true[j] - cell.cmd[j]))
        rows.append((rotvec_of(cell.R0.T @ reg.R).ravel(), np.sqrt(np.diag(budget.registration_rotation_cov_deg2)),
                     err, fu[f"AP{ax}_deg"].U, bare[f"AP{ax}_deg"].U, fu[f"RP{ax}_deg"].U, bare[f"RP{ax}_deg"].U,
                     fu[f"AP{ax}_deg"].components))
    return rows


@pytest.mark.parametrize("geometry", ["wide", "closer", "fewer"])
def test_orientation_ap_through_a_fitted_frame_is_within_u_at_the_stated_rate(rng, geometry):
    """Drawn point-pair registrations (the inset cube's 8 points, a cube half their size, or 4 points): the
    fitted rotation's spread is what the fit's covariance states; orientation AP measured through each frame
    lies within U of the arm's truth at least 95 % of the time, and without the frame's term it would not."""
    cell = _Cell(rng, n_stops=6)
    n_points, half = {"wide": (8, 500.0), "closer": (8, 250.0), "fewer": (4, 500.0)}[geometry]
    # the registration's noise: its frame turns the angles several times more than the stops' mean is unsure of
    sigma_mm = float(rng.uniform(0.02, 0.04))
    K = 400
    rows = _coverage(rng, cell, n_points, half, sigma_mm, K)
    # each fitted rotation's error about a drawn axis in units of its stated sd: a t with the 3n - 6 degrees
    # of freedom of the residuals' variance (the drawn points' geometry differs from fit to fit)
    axis = rng.integers(3, size=K)
    t = np.array([np.degrees(r[0][i]) / r[1][i] for r, i in zip(rows, axis)])
    dof = 3 * n_points - 6
    beyond = int(np.sum(np.abs(t) > stats.t.isf(0.025, dof)))
    assert stats.binom.ppf(TAIL, K, 0.05) <= beyond <= stats.binom.isf(TAIL, K, 0.05), beyond
    rms_stated = np.sqrt(np.mean(np.array([r[1] for r in rows]) ** 2, axis=0))
    err = np.array([r[2] for r in rows])
    U, U_bare = np.array([r[3] for r in rows]), np.array([r[4] for r in rows])
    outside = int(np.sum(err > U))
    print(f"{geometry}: rotation sd {rms_stated} deg, outside U {outside}/{K}, without the frame's term "
          f"{int(np.sum(err > U_bare))}/{K}")
    # U covers the truth at least 95 % of the time: more outside than a 5 % rate leaves with 1e-5 fails
    assert outside <= stats.binom.isf(TAIL, K, 0.05), outside
    # the frame's term is what covers it: without it a fifth and more of the figures are outside
    assert int(np.sum(err > U_bare)) > 0.2 * K
    assert all("registration" in r[7] and r[7]["registration"] > 0 for r in rows)
    # RP's U does not carry the frame's rotation
    assert np.array_equal([r[5] for r in rows], [r[6] for r in rows])


def test_fewer_or_closer_registration_points_give_orientation_ap_a_larger_u(rng):
    """The same cell registered on 8 points over the inset cube, on 8 over a cube half its size and on 4:
    the mean U of orientation AP over drawn registrations grows as the points come closer (the rotation's sd
    doubles when the spread halves) and fewer."""
    cell = _Cell(rng, n_stops=6)
    sigma_mm = float(rng.uniform(0.02, 0.04))
    K = 60
    mean_U, mean_sd = {}, {}
    for name, n, half in (("wide", 8, 500.0), ("closer", 8, 250.0), ("fewer", 4, 500.0)):
        rows = _coverage(rng, cell, n, half, sigma_mm, K)
        mean_U[name] = float(np.mean([r[3] for r in rows]))
        mean_sd[name] = float(np.sqrt(np.mean([np.sum(r[1] ** 2) for r in rows])))
    print(mean_U, mean_sd)
    assert mean_U["closer"] > mean_U["wide"] and mean_U["fewer"] > mean_U["wide"]
    # a box half as wide: the rotation's sd twice (the residuals' rms does not depend on the spread), within
    # what the rms of K fits of 3n - 6 = 18 residual dof leaves
    tol = stats.norm.isf(TAIL) * math.sqrt(2.0 / (18 * K)) * 2
    assert abs(mean_sd["closer"] / mean_sd["wide"] - 2.0) <= 2.0 * tol + 0.15


def test_the_procedures_jackknife_of_its_axis_registration_states_the_rotations_spread(rng):
    """The ISO procedure registers by the circles of joints 1 and 2 and states the rotation's covariance by a
    jackknife of that fit (:func:`procedures.iso9283.rotation_covariance`): over drawn sweeps read with noise,
    the stated sd is at least the spread of the fitted rotations and not far above it (a jackknife errs on
    the safe side), and orientation AP through each frame is within U at the stated rate."""
    from procedures.iso9283 import jackknife_refits, rotation_covariance
    from station.models.kinematics import tool_position
    from station.models.robots import get_robot

    robot = get_robot("industrial-3100")
    q0 = np.asarray(robot.home_q_rad, dtype=float)
    npts = 13

    def sweep(j, amp_deg):
        q = np.repeat(q0[None], npts, axis=0)
        q[:, j] += np.radians(np.linspace(-amp_deg, amp_deg, npts))
        return q

    q1, q2 = sweep(0, float(rng.uniform(20.0, 30.0))), sweep(1, float(rng.uniform(20.0, 30.0)))
    p = np.vstack([tool_position(robot.dh_nominal, q1), tool_position(robot.dh_nominal, q2)])
    cell = _Cell(rng, n_stops=6)
    sigma_mm = float(rng.uniform(0.01, 0.03))
    K = 160
    errs, stated, err_ap, U = [], [], [], []
    for _ in range(K):
        m = p @ cell.R0.T + cell.t0 + sigma_mm * rng.standard_normal(p.shape)

        def fit(keep):
            return register_by_axes(robot.dh_nominal, q1[keep[:npts]], m[:npts][keep[:npts]], q2[keep[npts:]],
                                    m[npts:][keep[npts:]])

        reg = fit(np.ones(2 * npts, bool))
        cov = np.degrees(np.degrees(rotation_covariance(jackknife_refits(fit, 2 * npts), reg)))
        errs.append(np.degrees(rotvec_of(cell.R0.T @ reg.R).ravel()))
        stated.append(np.sqrt(np.diag(cov)))
        # the stops read through this frame
        stops = cell.true + cell.scatter * rng.standard_normal((cell.n, 3))
        read = cell.R0 @ _matrix(stops) @ rotvec_to_matrix(
            math.radians(cell.noise_deg) * rng.standard_normal((cell.n, 3)))
        budget = Budget(trials=2000, seed=int(rng.integers(2**31)), angle_sd_deg=cell.noise_deg,
                        registration_rotation_cov_deg2=tuple(map(tuple, cov)), registration_rotation_dof=2 * npts - 1)
        _, fu = cell.figures(abc_in_base(_quat(read), reg.R), budget)
        j = int(rng.integers(3))
        err_ap.append(abs(fu[f"AP{'abc'[j]}_deg"].value - math.degrees(cell.true[j] - cell.cmd[j])))
        U.append(fu[f"AP{'abc'[j]}_deg"].U)
    emp = np.sqrt(np.mean(np.array(errs) ** 2, axis=0))
    rms_stated = np.sqrt(np.mean(np.array(stated) ** 2, axis=0))
    ratio = rms_stated / emp
    print(f"jackknife sd / spread of the fitted rotations: {ratio}; outside U {int(np.sum(np.array(err_ap) > U))}/{K}")
    z = stats.norm.isf(TAIL / 6) / math.sqrt(2 * K)
    assert np.all(ratio >= 1.0 - z) and np.all(ratio <= 1.6 + z), ratio
    assert int(np.sum(np.array(err_ap) > np.array(U))) <= stats.binom.isf(TAIL, K, 0.05)
