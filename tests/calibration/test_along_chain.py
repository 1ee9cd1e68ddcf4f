"""The way along a plan's joint path (:func:`station.analysis.arm.pose_planning.along_chain`).

A chain of random joint waypoints is drawn each run; the arm is put at a
random fraction of a random move (plus a disturbance below the tolerance)
and sent to a random waypoint: the way must start at the end of its move
that faces the goal and pass every waypoint between in order, back or
forward; an arm off the chain gets None.
"""

from __future__ import annotations

import numpy as np
import pytest

from station.analysis.arm.pose_planning import along_chain

TOL_DEG = 0.05


def _chain(rng, m):
    return rng.uniform(-170.0, 170.0, (m, 6))


def test_the_way_starts_on_the_move_the_arm_stands_on_and_passes_every_waypoint_to_the_goal(rng):
    for _ in range(300):
        m = int(rng.integers(2, 12))
        w = _chain(rng, m)
        j = int(rng.integers(0, m - 1))
        goal = int(rng.integers(0, m))
        s = float(rng.uniform(0.05, 0.95))
        q = w[j] + s * (w[j + 1] - w[j]) + rng.uniform(-0.5, 0.5, 6) * TOL_DEG
        way = along_chain(w, q, goal, TOL_DEG)
        expect = w[j + 1:goal + 1] if j < goal else w[goal:j + 1][::-1]
        assert np.array_equal(way, expect), (j, goal)


def test_an_arm_at_a_waypoint_or_at_the_goal_drives_nothing_twice(rng):
    m = int(rng.integers(3, 12))
    w = _chain(rng, m)
    goal = int(rng.integers(0, m))
    assert along_chain(w, w[goal] + rng.uniform(-0.5, 0.5, 6) * TOL_DEG, goal, TOL_DEG).shape == (0, 6)
    k = int(rng.integers(0, m))
    if k == goal:
        return
    way = along_chain(w, w[k], goal, TOL_DEG)
    # from the waypoint it stands at, every waypoint between, the goal last
    assert np.array_equal(way, w[k + 1:goal + 1] if k < goal else w[goal:k][::-1])


def test_an_arm_off_the_chain_is_not_on_it_and_a_goal_off_the_chain_is_refused(rng):
    m = int(rng.integers(2, 12))
    w = _chain(rng, m)
    j = int(rng.integers(0, m - 1))
    q = w[j] + 0.5 * (w[j + 1] - w[j])
    d = w[j + 1] - w[j]
    off = np.zeros(6)
    off[int(rng.integers(0, 6))] = 1.0
    off -= (off @ d) / (d @ d) * d  # across the move (perpendicular to it in joint space)
    off *= 20 * TOL_DEG / np.max(np.abs(off))
    assert along_chain(w[j:j + 2], q + off, 0, TOL_DEG) is None
    with pytest.raises(ValueError, match="no waypoint"):
        along_chain(w, q, m, TOL_DEG)
