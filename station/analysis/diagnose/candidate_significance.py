"""One candidate extension tested against the residual, the same way for the arm and the trailer.

The model's columns span ``Q`` (orthonormal). A candidate adds the columns
``B``; projected off ``Q`` and scaled, they are fitted to the residual, and
the Wald statistic of that fit, with the covariance the caller's
``cov_of(X, residual)`` gives (robust per pose for the arm, HAC for the
trailer's correlated samples), is what the F threshold judges. A candidate
that does not move the prediction, or that the model's columns already
span, is not testable, with the reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: smallest singular value of a candidate's scaled columns after projection off the model's
COLLINEAR_TOL = 1e-6


@dataclass(frozen=True)
class BlockTest:
    """``why`` is None for a tested block, else ``"no effect"`` or ``"collinear"``."""

    why: str | None
    wald: float = math.nan
    rss_reduction: float = math.nan


def model_basis(M: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the model's columns (scaled first); (rows, 0) without columns."""
    if M.shape[1] == 0:
        return np.zeros((M.shape[0], 0))
    sc = np.linalg.norm(M, axis=0)
    sc[sc == 0] = 1.0
    return np.linalg.qr(M / sc)[0]


def wald_block(B: np.ndarray, r: np.ndarray, Q: np.ndarray, cov_of) -> BlockTest:
    """Wald statistic of the candidate columns ``B`` (rows, k) on the residual ``r`` beyond ``Q``."""
    bn = np.linalg.norm(B, axis=0)
    if np.any(bn <= 1e-12 * math.sqrt(B.shape[0])):
        return BlockTest("no effect")
    Bp = B - Q @ (Q.T @ B)
    if np.linalg.svd(Bp / bn, compute_uv=False)[-1] < COLLINEAR_TOL:
        return BlockTest("collinear")
    X = Bp / np.linalg.norm(Bp, axis=0)
    th, *_ = np.linalg.lstsq(X, r, rcond=None)
    r1 = r - X @ th
    try:
        wald = float(th @ np.linalg.solve(cov_of(X, r1), th))
    except np.linalg.LinAlgError:
        wald = math.nan
    return BlockTest(None, wald, float(r @ r - r1 @ r1))


def refit_step(M: np.ndarray, B: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The linearised refit of model and candidate together on ``r``: the step of every column."""
    full = np.concatenate([M, B], axis=1)
    fsc = np.linalg.norm(full, axis=0)
    fsc[fsc == 0] = 1.0
    step, *_ = np.linalg.lstsq(full / fsc, r, rcond=None)
    return step / fsc
