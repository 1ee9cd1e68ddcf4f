"""The way back along a batch's joint path (:func:`station.analysis.arm.pose_planning.retrace`).

A chain of random joint waypoints is drawn each run; the arm is put at a
random fraction of a random move (plus a disturbance below the tolerance),
and the way back must start at that move's first waypoint and pass every
earlier one in reverse order; an arm off the chain gets None.
"""

from __future__ import annotations

import numpy as np

from station.analysis.arm.pose_planning import retrace

TOL_DEG = 0.05


def _chain(rng, m):
    return rng.uniform(-170.0, 170.0, (m, 6))


def test_the_way_back_starts_on_the_move_the_arm_stands_on_and_passes_every_earlier_waypoint(rng):
    for _ in range(200):
        m = int(rng.integers(2, 12))
        w = _chain(rng, m)
        j = int(rng.integers(0, m - 1))
        s = float(rng.uniform(0.05, 0.95))
        q = w[j] + s * (w[j + 1] - w[j]) + rng.uniform(-0.5, 0.5, 6) * TOL_DEG
        back = retrace(w, q, TOL_DEG)
        assert back is not None
        assert np.array_equal(back, w[j::-1])


def test_an_arm_at_a_waypoint_or_at_the_start_needs_no_detour(rng):
    m = int(rng.integers(3, 12))
    w = _chain(rng, m)
    assert retrace(w, w[0] + rng.uniform(-0.5, 0.5, 6) * TOL_DEG, TOL_DEG).shape == (0, 6)
    k = int(rng.integers(1, m))
    back = retrace(w, w[k], TOL_DEG)
    # the earliest move that holds it ends there: back from its start, nothing driven to where it stands
    assert np.array_equal(back, w[k - 1::-1])


def test_an_arm_off_the_chain_is_not_on_it(rng):
    m = int(rng.integers(2, 12))
    w = _chain(rng, m)
    j = int(rng.integers(0, m - 1))
    q = w[j] + 0.5 * (w[j + 1] - w[j])
    axis = int(rng.integers(0, 6))
    d = w[j + 1] - w[j]
    # a step across the move (perpendicular to it in joint space), far beyond the tolerance
    off = np.zeros(6)
    off[axis] = 1.0
    off -= (off @ d) / (d @ d) * d
    off *= 20 * TOL_DEG / np.max(np.abs(off))
    assert retrace(w[j:j + 2], q + off, TOL_DEG) is None
    assert retrace(np.zeros((0, 6)), q, TOL_DEG) is None
