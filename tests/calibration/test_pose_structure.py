"""The poses' layout (one-joint sweeps or spread) and the folds that respect it (issue 43)."""

from __future__ import annotations

import numpy as np

from fakes.sim.real_like_arms import fanuc_like, rokae_like
from station.analysis.arm.pose_structure import (lone_extremes, pose_structure, structured_folds,
                                                 sweep_end_folds)


def _sweeps(rng, n_per, home_deg):
    home_deg = np.asarray(home_deg, float)
    rows = []
    for j in rng.permutation(6):
        # distinct values, none within a degree of the home angle (a pose at home belongs to every sweep)
        for v in np.sort(home_deg[j] + rng.choice([-1, 1], n_per) * rng.uniform(1, 90, n_per)):
            q = np.array(home_deg, float)
            q[j] = v
            rows.append(q)
    return np.radians(np.array(rows))


def test_sweeps_are_found_in_any_row_order_with_their_ends(rng):
    n_per = int(rng.integers(3, 8))
    q = _sweeps(rng, n_per, rng.uniform(-30, 30, 6))
    perm = rng.permutation(q.shape[0])
    st = pose_structure(q[perm])
    assert st.kind == "sweeps" and st.interpolation_only
    assert sorted(s.joint for s in st.sweeps) == list(range(6))
    for s in st.sweeps:
        assert s.rows.size == n_per
        moved = q[perm][s.rows]
        # only the sweep's joint moves, sorted along it; the ends are its smallest and largest
        assert np.all(np.ptp(np.delete(moved, s.joint, axis=1), axis=0) == 0)
        assert np.all(np.diff(moved[:, s.joint]) > 0)
    assert st.ends.size == 12
    assert st.describe() == f"{q.shape[0]} poses on one-joint sweeps: " + ", ".join(f"J{j} ({n_per})" for j in range(1, 7))


def test_folds_of_sweeps_never_hold_out_an_end_and_cover_the_rest(rng):
    d = fanuc_like(rng, n=36, hidden=False)
    keep = rng.permutation(36)[:int(rng.integers(18, 30))]   # what a random split leaves for training
    q = d.q_rad[np.sort(keep)]
    st = pose_structure(q)
    assert st.kind == "sweeps"
    k = int(rng.integers(2, 7))
    folds = structured_folds(st, k, seed=int(rng.integers(1000)))
    held = np.concatenate(folds)
    assert np.unique(held).size == held.size   # disjoint
    assert np.intersect1d(held, st.ends).size == 0
    assert np.array_equal(np.sort(np.concatenate([held, st.ends])), np.arange(q.shape[0]))
    # every held-out pose lies inside the range of the poses that predict it, joint by joint
    for f in folds:
        rest = np.setdiff1d(np.arange(q.shape[0]), f)
        lo, hi = q[rest].min(axis=0), q[rest].max(axis=0)
        assert np.all((q[f] >= lo - 1e-12) & (q[f] <= hi + 1e-12))
    # the extrapolation folds: each sweep's low ends, then its high ends
    ext = sweep_end_folds(st)
    assert 1 <= len(ext) <= 2 and all(np.isin(f, st.ends).all() for f in ext)


def test_a_joint_moved_by_a_single_pose_is_never_held_out(rng):
    q = _sweeps(rng, 5, np.zeros(6))
    lone = np.zeros((1, 6))
    j = int(rng.integers(6))
    lone[0, j] = np.radians(rng.choice([-1, 1]) * rng.uniform(100, 120))   # beyond its sweep
    q = np.vstack([q, lone])
    st = pose_structure(q)
    assert q.shape[0] - 1 in lone_extremes(q) and q.shape[0] - 1 in st.ends
    assert all(q.shape[0] - 1 not in f for f in structured_folds(st, 5, seed=0))


def test_when_every_pose_ends_a_sweep_no_fold_is_made(rng):
    """Pairs of poses moving one joint from several homes: every pose is a sweep's end, nothing can be held out
    without extrapolating."""
    rows = []
    homes = int(rng.integers(2, 5))
    for _ in range(homes):
        home = rng.uniform(-40, 40, 6)
        for j in range(6):
            for v in (-rng.uniform(5, 40), rng.uniform(5, 40)):
                q = home.copy()
                q[j] += v
                rows.append(q)
    st = pose_structure(np.radians(np.array(rows)))
    assert st.kind == "sweeps" and st.ends.size == len(rows)
    assert structured_folds(st, 5, seed=0) == []
    assert all(f"J{j} ({homes} sweeps, {2 * homes})" in st.describe() for j in range(1, 7)), st.describe()


def test_spread_poses_take_random_folds(rng):
    d = rokae_like(rng, n=int(rng.integers(20, 60)), hidden=False)
    st = pose_structure(d.q_rad)
    assert st.kind == "spread" and not st.interpolation_only and st.ends.size == 0
    folds = structured_folds(st, 5, seed=3)
    assert np.array_equal(np.sort(np.concatenate(folds)), np.arange(d.q_rad.shape[0]))
    assert sweep_end_folds(st) == []
