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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.analysis.arm.identification import identify, rigid_fit
from station.errors import DataError, InsufficientDataError
from station.models import kinematics as kin

__all__ = ["FoldErrors", "fold_errors", "beats_nominal"]


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
