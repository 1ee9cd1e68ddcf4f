"""Is the calibrated geometry better than the nominal model on poses that did not choose it?

The question is answered as the user asks it: for each fold of the training
poses, the geometric calibration (:func:`station.analysis.arm.identification.identify`,
absolute method, the same calibration the diagnosis starts from and writes)
and the nominal model with its base transform (a rigid fit) are both fitted
on the other poses and predict the fold's poses. Per-pose squared 3-D errors
come back paired, mm^2.

The folds come from :mod:`station.analysis.arm.pose_structure`: on one-joint
sweeps every sweep's ends stay in training (interpolation), and the sweep
ends held out as a group give a separate extrapolation figure, reported and
never used to judge.

The folds can judge only where they see geometry: when the nominal model
predicts the poses they held out to the noise (:func:`folds_see_geometry`:
one-joint sweeps whose interior poses lie near the home pose, where a
millimetre-size table error is at its smallest), neither model can be better
there and the answer of the folds is "cannot tell", not "no".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from station.analysis.arm.identification import identify, rigid_fit
from station.errors import DataError, InsufficientDataError
from station.models import kinematics as kin

__all__ = ["FoldErrors", "fold_errors", "beats_nominal", "folds_see_geometry", "FoldSignal"]


@dataclass(frozen=True)
class FoldErrors:
    """Squared 3-D errors (mm^2) of the poses the folds held out: ``nominal`` and ``geometry`` over ``rows``
    (positions in the arrays given); ``failed`` counts folds whose calibration could not be fitted."""

    rows: np.ndarray
    nominal: np.ndarray
    geometry: np.ndarray
    failed: int

    @property
    def rms_nominal(self) -> float:
        return math.sqrt(float(np.mean(self.nominal))) if self.rows.size else math.nan

    @property
    def rms_geometry(self) -> float:
        return math.sqrt(float(np.mean(self.geometry))) if self.rows.size else math.nan


def _sq(p: np.ndarray, meas: np.ndarray) -> np.ndarray:
    return np.sum((p - meas) ** 2, axis=1)


def fold_errors(dh, q: np.ndarray, meas: np.ndarray, folds) -> FoldErrors:
    """Nominal (base fitted) and calibrated geometry, each fitted without a fold, on that fold's poses."""
    n = q.shape[0]
    rows, e_nom, e_geo = [], [], []
    failed = 0
    p_nom = kin.tool_position(dh, q)
    for f in folds:
        keep = np.ones(n, bool)
        keep[f] = False
        try:
            res = identify(dh, q[keep], meas[keep], method="absolute")
        except (InsufficientDataError, DataError):
            failed += 1
            continue
        B0 = rigid_fit(p_nom[keep], meas[keep])
        rows.append(f)
        e_nom.append(_sq(p_nom[f] @ B0[:3, :3].T + B0[:3, 3], meas[f]))
        p = kin.tool_position(res.dh, q[f]) @ res.base_T[:3, :3].T + res.base_T[:3, 3]
        e_geo.append(_sq(p, meas[f]))
    if not rows:
        z = np.zeros(0)
        return FoldErrors(np.zeros(0, dtype=np.int64), z, z, failed)
    return FoldErrors(np.concatenate(rows), np.concatenate(e_nom), np.concatenate(e_geo), failed)


def beats_nominal(fe: FoldErrors) -> bool:
    """The calibrated geometry predicts the held-out poses better on average (geometry is the base of every
    other step, so a lower mean squared error suffices; the joint effects' one-standard-error rule would drop
    it where the folds are few)."""
    return fe.rows.size > 0 and float(np.mean(fe.geometry)) < float(np.mean(fe.nominal))


@dataclass(frozen=True)
class FoldSignal:
    """Whether the nominal model misses the folds' held-out poses by more than the noise: ``statistic`` is the
    mean squared 3-D error of the nominal model there over ``3 s^2`` (``s^2`` the calibration's residual variance
    per coordinate), against ``threshold``, the ``1 - alpha`` quantile of ``F(3 n_held, dof)``."""

    statistic: float
    threshold: float

    @property
    def seen(self) -> bool:
        return self.statistic > self.threshold

    @property
    def blind(self) -> bool:
        """The folds cannot judge: the statistic is defined and not above its threshold."""
        return math.isfinite(self.statistic) and not self.seen


def folds_see_geometry(fe: FoldErrors, s2_mm2: float, dof: float, alpha: float) -> FoldSignal:
    """Do the folds' held-out poses hold any geometric error for the calibration to predict better?

    Under a nominal model that is right on those poses, each held-out coordinate misses by the noise alone
    (variance ``s2_mm2``, estimated with ``dof`` degrees of freedom by the calibration's residual), so the
    nominal model's mean squared 3-D error over ``3 s^2`` follows ``F(3 n_held, dof)`` (its base transform,
    fitted on the other poses, adds a little: the test leans towards "seen", which keeps the folds' veto).
    Where it is not above the ``1 - alpha`` quantile, the folds cannot tell a calibration from the nominal
    model and do not judge."""
    n = int(fe.rows.size)
    if n == 0 or not (s2_mm2 > 0.0) or not (dof > 0.0):
        return FoldSignal(math.nan, math.nan)
    stat = float(np.mean(fe.nominal)) / (3.0 * s2_mm2)
    return FoldSignal(stat, float(stats.f.isf(alpha, 3 * n, dof)))
