"""The identification's fast path gives the results of the path it replaced (issue 43 item 5).

The fast path computes the absolute formulation's residual and Jacobian from a forward pass laid out
poses-last and started from the base rotation (:mod:`station.models.frame_pass`), over blocks of poses
whose Jacobians are summed into the normal equations (the solver, the prior's rows, the uncertainties and
correlations work on those) and into the identifiability analysis's ``R`` of the columns that are not fixed
beforehand (QR of the blocks stacked on the running ``R``); it turns rotation vectors with
:mod:`station.models.rotation`. The reference below is the path before: the kinematics' frames and
parameter Jacobian (:mod:`station.models.kinematics`, checked against finite differences in
tests/kinematics) turned by a batched product, the whole Jacobian handed to the solver (normal equations of
its free columns at every step, the prior's rows appended), scipy's rotations, one QR of the whole Jacobian. Both
identify the same random arm (millimetre-size errors in every parameter, a random instrument frame, noise)
from the same poses, few and many, and must agree to rounding: 1e-9 relative on every parameter (1e-9 mm
or rad where the parameter is near zero), the same iterations, parameters fixed and reasons, warnings.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import station.analysis.arm.identification as ident_mod
from fakes.sim.arm_measurements import instrument_frame, measure, random_poses
from station.models import kinematics as kin
from station.models.robots import get_robot


def _reference_absolute_problem(dh, x_base, q, meas):
    """The absolute residual and Jacobian as they were computed before the fast path."""
    F = kin.frames(dh, q)
    p = F[:, -1, :3, 3]
    R = Rotation.from_rotvec(x_base[:3]).as_matrix()
    r = (meas - (p @ R.T + x_base[3:])).reshape(-1)

    def jac():
        n = q.shape[0]
        J = np.zeros((n, 3, kin.N_PARAMS + 6))
        J[:, :, :kin.N_PARAMS] = np.matmul(R, kin.param_jacobian_from_frames(dh, q, F))
        # a small rotation w on the left moves R p by w x (R p): column k is e_k x (R p)
        J[:, :, kin.N_PARAMS:kin.N_PARAMS + 3] = np.cross(np.eye(3)[None], (p @ R.T)[:, None, :]).transpose(0, 2, 1)
        J[:, :, kin.N_PARAMS + 3:] = np.eye(3)
        return J.reshape(3 * n, -1)

    return r, jac()


def _reference_absolute_normal(dh, x_base, q, meas, *, r_cols=None):
    """The whole Jacobian of the path before in place of the blockwise normal equations (the solver then forms
    them from its free columns at every step, the prior's rows are appended to it, the uncertainties and
    correlations come from its columns), and the identifiability's R from one QR of its open columns."""
    r, J = _reference_absolute_problem(dh, x_base, q, meas)
    return r, J, None if r_cols is None else np.linalg.qr(J[:, r_cols], mode="r")


def _reference(monkeypatch):
    monkeypatch.setattr(ident_mod, "_absolute_problem", _reference_absolute_problem)
    monkeypatch.setattr(ident_mod, "_absolute_normal", _reference_absolute_normal)
    monkeypatch.setattr(ident_mod, "rotvec_to_matrix", lambda v: Rotation.from_rotvec(v).as_matrix())
    monkeypatch.setattr(ident_mod, "matrix_to_rotvec", lambda R: Rotation.from_matrix(R).as_rotvec())
    monkeypatch.setattr(ident_mod, "_r_factor", lambda J: np.linalg.qr(J, mode="r"))


def _arm_and_data(rng, n_poses: int, *, calibrated_start: bool):
    nominal = get_robot(str(rng.choice(["rb5-850", "ur10e"])))
    # millimetre-size errors in every length, about a milliradian in every angle (betas included)
    err = rng.normal(0.0, 1.0, (7, 5)) * np.array([1.0, 1e-3, 1.0, 1e-3, 1e-3])
    truth = nominal.dh_nominal + err
    q = random_poses(nominal.joint_limits_rad, n_poses, rng)
    meas = measure(truth, q, instrument_frame(rng), float(rng.uniform(0.005, 0.05)), rng)
    start = nominal.dh_nominal.copy()
    if calibrated_start:
        # a start that is itself a calibration: small offsets where the design has none (judged on the
        # snapped structure, a second Jacobian)
        start += rng.normal(0.0, 0.2, (7, 5)) * np.array([1.0, 1e-3, 1.0, 1e-3, 0.0])
    return start, q, meas


def _assert_same(fast, ref):
    for got, want in ((fast.dh, ref.dh), (fast.base_T, ref.base_T)):
        if want is None:
            assert got is None
            continue
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert fast.iterations == ref.iterations and fast.converged == ref.converged
    assert fast.message.split(" (")[0] == ref.message.split(" (")[0]
    assert fast.identifiability.fixed == ref.identifiability.fixed
    np.testing.assert_array_equal(fast.identifiability.free, ref.identifiability.free)
    np.testing.assert_allclose(fast.identifiability.singular_values, ref.identifiability.singular_values,
                               rtol=1e-9)
    assert list(fast.sigma) == list(ref.sigma)
    np.testing.assert_allclose(list(fast.sigma.values()), list(ref.sigma.values()), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fast.residual_rms_mm, ref.residual_rms_mm, rtol=1e-9)
    assert [w["parameters"] for w in fast.extra["warnings"]] == [w["parameters"] for w in ref.extra["warnings"]]
    assert fast.extra["prior"] == ref.extra["prior"] and fast.extra["held"] == ref.extra["held"]


@pytest.mark.parametrize("method, n_lo, n_hi, calibrated_start", [
    ("absolute", 12, 40, False),
    ("absolute", 600, 1000, False),      # 1,800-3,000 rows: the QR runs in blocks
    ("absolute", 30, 200, True),
    ("distance", 10, 30, False),
])
def test_fast_path_gives_the_replaced_paths_results(rng, monkeypatch, method, n_lo, n_hi, calibrated_start):
    start, q, meas = _arm_and_data(rng, int(rng.integers(n_lo, n_hi + 1)), calibrated_start=calibrated_start)
    ident_mod._reference_names.cache_clear()
    fast = ident_mod.identify(start, q, meas, method=method)
    with monkeypatch.context() as m:
        _reference(m)
        ident_mod._reference_names.cache_clear()
        ref = ident_mod.identify(start, q, meas, method=method)
    ident_mod._reference_names.cache_clear()
    # the fit moved: the comparison is of two solutions, not of two starts
    assert np.abs(ref.dh - start).max() > 1e-3
    _assert_same(fast, ref)


def test_the_blockwise_normal_equations_are_those_of_the_whole_jacobian(rng, monkeypatch):
    """The identification never holds the absolute problem's Jacobian: it sums ``J^T J``, ``J^T r`` and the R of
    the open columns over blocks of poses (one block's memory reused). Any block size, a last block shorter than
    the others, fewer rows than columns: the sums are the whole Jacobian's (the kinematics' own, turned by the
    base rotation) to rounding."""
    nominal = get_robot(str(rng.choice(["rb5-850", "ur10e"])))
    dh = nominal.dh_nominal + rng.normal(0.0, 1.0, (7, 5)) * np.array([1.0, 1e-3, 1.0, 1e-3, 1e-3])
    n = int(rng.integers(3, 700))
    q = random_poses(nominal.joint_limits_rad, n, rng)
    x_base = np.concatenate([rng.normal(0.0, 1.0, 3), rng.normal(0.0, 500.0, 3)])
    meas = measure(dh, q, instrument_frame(rng), 0.05, rng)
    cols = np.sort(rng.choice(kin.N_PARAMS + 6, int(rng.integers(5, 42)), replace=False))
    r_ref, J = _reference_absolute_problem(dh, x_base, q, meas)
    for block in (int(rng.integers(1, n + 1)), int(rng.integers(1, 40)), 512):
        monkeypatch.setattr(ident_mod, "_POSE_BLOCK", block)
        r, N, R = ident_mod._absolute_normal(dh, x_base, q, meas, r_cols=cols)
        scale = float(np.abs(J).max())
        np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(N.JtJ, J.T @ J, rtol=0, atol=1e-12 * scale ** 2 * 3 * n)
        np.testing.assert_allclose(N.Jtr, J.T @ r_ref, rtol=0, atol=1e-12 * scale * float(np.abs(r_ref).max()) * 3 * n)
        Jc = J[:, cols]
        assert R.shape == (min(3 * n, cols.size), cols.size) and np.allclose(R, np.triu(R), rtol=0, atol=0)
        np.testing.assert_allclose(R.T @ R, Jc.T @ Jc, rtol=0, atol=1e-12 * scale ** 2 * 3 * n)
    # the joint angles' cosines are kept between passes over the same poses: poses changed in place are new
    q[int(rng.integers(n)), int(rng.integers(6))] += rng.uniform(0.1, 1.0)
    r_ref, J = _reference_absolute_problem(dh, x_base, q, meas)
    r, N, _ = ident_mod._absolute_normal(dh, x_base, q, meas)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-9 * float(np.abs(J).max()))
    np.testing.assert_allclose(N.JtJ, J.T @ J, rtol=0, atol=1e-12 * float(np.abs(J).max()) ** 2 * 3 * n)
