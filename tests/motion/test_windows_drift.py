"""The reading's drift as the windows measure it: the late dwell's drift rate along the travel, and its change
since the previous rest, against the drift the stream was drawn with.

The tracker's drift is the same vector at every pose, while consecutive moves run along different directions:
the change over a move is the difference of the two rests' drift *velocities*, taken along this move's travel
(the rates along each move's own travel differ by the turn of the direction, not by the drift).
"""

from __future__ import annotations

import numpy as np

from station.analysis.motion.windows import cut_windows

from .motion_stream import draw, make_stream


def _drift_velocity(d: dict, t) -> np.ndarray:
    """The drawn drift's velocity (len(t), 3), mm/s: the derivative of motion_stream's sum of sines."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    out = np.zeros((t.size, 3))
    for j in range(3):
        for m in range(3):
            w = 2 * np.pi / d["drift_periods"][j, m]
            out[:, j] += d["drift_mm"] * w * np.cos(w * t + d["drift_phase"][j, m])
    return out


def test_drift_rate_and_its_change_are_the_drawn_drifts(rng):
    d = draw(rng, effects=("tracker_drift",))
    d["noise_mm"] = 1e-6  # the drift's own figures, not the slope's noise
    s = make_stream(d)
    w = cut_windows(s.t_s, s.xyz_mm, s.poses_mm, s.names)
    v_true = _drift_velocity(d, w.t_late_s)
    rate_true = np.einsum("mi,mi->m", v_true, w.u)
    assert np.sqrt(np.mean((w.drift_mm_s - rate_true) ** 2)) < 0.02 * np.sqrt(np.mean(rate_true ** 2))
    # the change since the previous rest (the move before was a window too), along this move's travel
    k_of = {int(k): j for j, k in enumerate(w.move_index)}
    err, ref = [], []
    for j, k in enumerate(w.move_index):  # loop over windows with a window before
        p = k_of.get(int(k) - 1)
        if p is None:
            continue
        want = float((v_true[j] - v_true[p]) @ w.u[j]) / (w.t_late_s[j] - w.t_late_s[p])
        err.append(w.drift_change_mm_s2[j] - want)
        ref.append(want)
    assert len(ref) >= 10
    err, ref = np.array(err), np.array(ref)
    # the rests' slopes differ from the rate at their mid times by the drift's curvature over a dwell of ~1 s
    # (periods of 30-90 s: a few per cent of the change)
    assert np.sqrt(np.mean(err ** 2)) < 0.1 * np.sqrt(np.mean(ref ** 2)), (err, ref)
