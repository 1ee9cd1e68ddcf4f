"""Held-out poses that span the workspace (not the tail of the file)."""

from __future__ import annotations

import numpy as np
from scipy.cluster.vq import kmeans2

from station.errors import DataError, InsufficientDataError

__all__ = ["workspace_split", "MIN_POSES"]

#: fewest poses a diagnosis accepts (a base transform and a held-out part need them)
MIN_POSES = 12


def workspace_split(q_rad: np.ndarray, xyz_mm: np.ndarray, heldout_fraction: float = 0.25,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(train, heldout)`` row indices (sorted).

    The poses are clustered (k-means on the standardised joint angles and
    measured points, one cluster per held-out pose) and the member nearest to
    each cluster's centre is held out, so the held-out poses sit all over the
    workspace the data cover and every one has training poses around it.
    The clustering's start is seeded: the split is a property of the data.
    """
    n = q_rad.shape[0]
    if not (0.05 <= heldout_fraction <= 0.5):
        raise DataError(f"`heldout_fraction` must be in [0.05, 0.5], got {heldout_fraction!r}")
    if n < MIN_POSES:
        raise InsufficientDataError(f"a diagnosis needs at least {MIN_POSES} poses, got {n}")
    k = max(3, int(round(heldout_fraction * n)))
    X = np.column_stack([q_rad, xyz_mm])
    sd = X.std(axis=0)
    X = (X - X.mean(axis=0)) / np.where(sd > 0, sd, 1.0)
    centres, label = kmeans2(X, k, minit="++", seed=np.random.default_rng(seed))
    chosen: list[int] = []
    taken = np.zeros(n, bool)
    for c in range(k):
        members = np.flatnonzero(label == c)
        if members.size == 0:
            continue
        m = members[np.argmin(np.sum((X[members] - centres[c]) ** 2, axis=1))]
        chosen.append(int(m))
        taken[m] = True
    while len(chosen) < k:  # empty clusters: the pose farthest from those held out
        d = np.min(np.sum((X[:, None, :] - X[None, chosen, :]) ** 2, axis=2), axis=1)
        d[taken] = -1.0
        m = int(np.argmax(d))
        chosen.append(m)
        taken[m] = True
    return np.flatnonzero(~taken), np.sort(np.array(chosen))
