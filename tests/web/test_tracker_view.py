"""The live plot's numbers from synthetic samples with known speed, poses and gaps."""

import numpy as np
import pytest

from app.web.tracker_view import MAX_POINTS, tracker_window


def test_speed_distance_and_counters_are_the_samples(rng):
    rate = float(rng.uniform(200, 1000))
    v = float(rng.uniform(50, 500))  # mm/s along a random direction
    n = int(rate * 8)
    t = np.arange(n) / rate
    drop = rng.choice(np.arange(10, n - 10), size=int(rng.integers(1, 6)), replace=False)
    keep = np.ones(n, bool)
    keep[drop] = False  # lost samples: each leaves one gap (drops are isolated or adjacent)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    xyz = t[:, None] * v * u
    status = np.zeros(n, np.int8)
    flagged = rng.choice(n, size=int(rng.integers(0, 20)), replace=False)
    status[flagged] = 2
    # registration: a random rotation and offset; the commanded pose is the base-frame point at t = 8 s
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    off = rng.normal(scale=1000, size=3)
    end_base = (xyz[-1] - off) @ R  # x_tracker = R x_base + off
    out = tracker_window(t[keep], xyz[keep], status[keep], window_s=3.0, poses_mm=end_base[None, :],
                         R=R, t_mm=off)
    gaps = np.count_nonzero(np.diff(t[keep]) > 1.5 / rate)
    assert out["n"] == keep.sum() and out["flagged"] == np.count_nonzero(status[keep])
    assert out["gaps"] == gaps and abs(out["rate_hz"] - rate) < 1e-6 * rate
    assert len(out["t"]) <= MAX_POINTS and -3.0 <= out["t"][0] < -2.9 and out["t"][-1] <= 0
    assert np.allclose(out["speed_mm_s"], v, rtol=1e-3)
    # distance to the pose falls linearly to ~0 at the end of the window
    d = np.array(out["dist_mm"])
    assert np.allclose(d, -np.array(out["t"]) * v, atol=v / rate * 2)


def test_no_registration_no_distance_and_few_samples():
    out = tracker_window(np.arange(10) * 0.01, np.zeros((10, 3)), np.zeros(10))
    assert out["dist_mm"] is None and out["speed_mm_s"] == [0.0] * len(out["t"])
    assert tracker_window([0.0], [[0, 0, 0]], [0])["t"] == []
    with pytest.raises(ValueError, match="same length"):
        tracker_window(np.arange(3), np.zeros((2, 3)), np.zeros(3))
