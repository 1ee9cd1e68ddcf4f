"""How a set of poses is laid out, and cross-validation folds that respect it.

Lab sets come in two shapes: poses spread over the joint space, and
one-joint sweeps (one joint moved at a time from a home pose, the others
held). A random fold of sweeps holds out sweep ends, where any fit of the
geometry extrapolates beyond the range the other poses span; a random fold
of spread poses does not. :func:`sweeps` finds the sweeps, and
:func:`structured_folds` keeps every sweep's two ends (and any pose that alone
holds a joint's smallest or largest angle) in training so each
fold asks the model to interpolate, as the question "does it predict poses
that did not choose it?" means inside the range of the data.
:func:`sweep_end_folds` gives the extrapolation folds (each sweep's low
ends, then its high ends, held out), reported as extrapolation.

Pure functions: joint angles (rad) in, row indices out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Sweep", "PoseStructure", "sweeps", "pose_structure", "structured_folds", "sweep_end_folds",
           "lone_extremes", "SAME_ANGLE_RAD",
           "MIN_SWEEP_POSES"]

#: joint angles closer than this are the same (a held joint read back by the controller), rad
SAME_ANGLE_RAD = 1e-3
#: fewest distinct values of the moved joint that make a sweep (two: both are ends)
MIN_SWEEP_POSES = 2


@dataclass(frozen=True)
class Sweep:
    """Poses that differ only in joint ``joint`` (0-based), sorted by it; ``rows[0]``, ``rows[-1]`` the ends."""

    joint: int
    rows: np.ndarray

    @property
    def ends(self) -> tuple[int, int]:
        return int(self.rows[0]), int(self.rows[-1])


@dataclass(frozen=True)
class PoseStructure:
    """``kind`` is ``"sweeps"`` when most poses lie on one-joint sweeps, else ``"spread"``; ``extremes`` the
    rows that alone hold the smallest or largest angle of a joint (a sweep's end, a joint moved by one pose)."""

    kind: str
    sweeps: tuple
    n_poses: int
    extremes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def ends(self) -> np.ndarray:
        """Rows beyond which a sweep, or a joint moved by a single pose, has no other pose (sorted, unique)."""
        rows = [e for s in self.sweeps for e in s.ends] + [int(e) for e in self.extremes]
        return np.unique(np.array(rows, dtype=np.int64))

    @property
    def interpolation_only(self) -> bool:
        """Cross-validation that respects the poses can only ask for interpolation (sweeps)."""
        return self.kind == "sweeps"

    def describe(self) -> str:
        if self.kind != "sweeps":
            return f"{self.n_poses} poses spread over the joint space"
        parts = []
        for j in sorted({s.joint for s in self.sweeps}):
            sw = [s for s in self.sweeps if s.joint == j]
            n = sum(s.rows.size for s in sw)
            parts.append(f"J{j + 1} ({n})" if len(sw) == 1 else f"J{j + 1} ({len(sw)} sweeps, {n})")
        return f"{self.n_poses} poses on one-joint sweeps: {', '.join(parts)}"


def sweeps(q_rad: np.ndarray, tol_rad: float = SAME_ANGLE_RAD) -> list[Sweep]:
    """Groups of at least :data:`MIN_SWEEP_POSES` poses that agree (to ``tol_rad``) in every joint but one
    and take distinct values of that one; a pose can end sweeps of several joints (the home pose)."""
    q = np.asarray(q_rad, dtype=float)
    n, nj = q.shape
    keys = np.round(q / tol_rad).astype(np.int64)
    out = []
    for j in range(nj):
        others = np.delete(keys, j, axis=1)
        _, inv, counts = np.unique(others, axis=0, return_inverse=True, return_counts=True)
        inv = inv.reshape(-1)
        for g in np.flatnonzero(counts >= MIN_SWEEP_POSES):
            rows = np.flatnonzero(inv == g)
            if np.unique(keys[rows, j]).size < MIN_SWEEP_POSES:
                continue
            out.append(Sweep(j, rows[np.argsort(q[rows, j], kind="stable")]))
    return out


def pose_structure(q_rad: np.ndarray, tol_rad: float = SAME_ANGLE_RAD) -> PoseStructure:
    """Sweeps when at least half the poses lie on one."""
    q = np.asarray(q_rad, dtype=float)
    sw = sweeps(q, tol_rad)
    on = np.zeros(q.shape[0], bool)
    for s in sw:
        on[s.rows] = True
    kind = "sweeps" if sw and on.sum() >= 0.5 * q.shape[0] else "spread"
    if kind != "sweeps":
        return PoseStructure(kind, (), q.shape[0])
    return PoseStructure(kind, tuple(sw), q.shape[0], lone_extremes(q, tol_rad))


def lone_extremes(q_rad: np.ndarray, tol_rad: float = SAME_ANGLE_RAD) -> np.ndarray:
    """Rows whose angle of some joint is beyond every other row's by more than ``tol_rad`` (at either end):
    holding such a row out leaves that end of the joint's range to extrapolation."""
    q = np.asarray(q_rad, dtype=float)
    out = set()
    if q.shape[0] < 2:
        return np.zeros(0, dtype=np.int64)
    for j in range(q.shape[1]):
        order = np.argsort(q[:, j], kind="stable")
        v = q[order, j]
        if v[1] - v[0] > tol_rad:
            out.add(int(order[0]))
        if v[-1] - v[-2] > tol_rad:
            out.add(int(order[-1]))
    return np.array(sorted(out), dtype=np.int64)


def structured_folds(structure: PoseStructure, k: int, seed: int) -> list[np.ndarray]:
    """``k`` folds of positions ``0..n-1`` (seeded). On sweeps no sweep end, nor a pose alone at the end of a
    joint's range, is ever held out (they stay in training, so every held-out pose lies inside the range of
    the poses that predict it); the other poses
    are dealt to the folds in random order. Spread poses: random folds."""
    n = structure.n_poses
    keep = structure.ends if structure.kind == "sweeps" else np.zeros(0, dtype=np.int64)
    pool = np.setdiff1d(np.arange(n), keep)
    if pool.size == 0:
        return []   # every pose ends a sweep: none can be held out without extrapolating
    perm = np.random.default_rng(seed).permutation(pool)
    return [np.sort(f) for f in np.array_split(perm, min(k, perm.size)) if f.size]


def sweep_end_folds(structure: PoseStructure) -> list[np.ndarray]:
    """Extrapolation folds of sweeps: every sweep's low end, then every sweep's high end (an end shared by
    sweeps, the home pose, is left in training). Empty for spread poses."""
    if structure.kind != "sweeps":
        return []
    low = [s.ends[0] for s in structure.sweeps]
    high = [s.ends[1] for s in structure.sweeps]
    shared = set(low) & set(high) | {e for e in low if low.count(e) > 1} | {e for e in high if high.count(e) > 1}
    folds = [np.array(sorted({e for e in side if e not in shared}), dtype=np.int64) for side in (low, high)]
    return [f for f in folds if f.size]
