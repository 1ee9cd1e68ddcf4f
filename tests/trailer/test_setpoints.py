"""Set points whose acknowledgement was lost: placed by the measured curvature inside their bracket."""

from __future__ import annotations

import numpy as np

from station.analysis.trailer.setpoints import interval_average, place_unacknowledged

RATE_HZ = 10.0
NOISE = 0.0173  # 1/m: the odometry's curvature noise of the trailer tests


def _stream(rng, n_sp: int):
    """Samples at 10 Hz for 120 s, ``n_sp`` set points at random ticks, the measured curvature the
    interval average of the set points plus noise."""
    t = np.arange(1, 1201) / RATE_HZ
    ticks = np.sort(rng.choice(np.arange(20, 1180), n_sp, replace=False))
    t_sp = t[ticks]
    v_sp = rng.uniform(-0.25, 0.25, n_sp)
    fb = np.zeros(t.size)
    kappa = interval_average(t, t_sp, v_sp, fb) + rng.normal(0.0, NOISE, t.size)
    return t, kappa, fb, t_sp, v_sp


def test_a_lost_acknowledgement_is_placed_where_the_curvature_changed(rng):
    n_sp = int(rng.integers(6, 20))
    t, kappa, fb, t_sp, v_sp = _stream(rng, n_sp)
    lost = rng.choice(np.arange(n_sp - 1), size=min(3, n_sp - 2), replace=False)
    ack = np.ones(n_sp, bool)
    ack[lost] = False
    # the timeline a lost acknowledgement gets from the order of sending: the next acknowledged time
    t_seen = t_sp.copy()
    nxt = np.minimum.accumulate(np.where(ack, t_sp, np.inf)[::-1])[::-1]
    t_seen[~ack] = nxt[~ack]
    placed = place_unacknowledged(t, kappa, fb, t_seen, v_sp, ack)
    assert np.array_equal(placed[ack], t_sp[ack])  # acknowledged times are kept
    assert np.all(np.diff(placed) >= 0)  # in send order
    for i in lost:
        step = abs(v_sp[i] - (v_sp[i - 1] if i > 0 else 0.0))
        if step > 8 * NOISE:  # a change the curvature shows: found to the tick (a tick's error costs
            # step^2 / 2 over two samples' intervals against noise of variance NOISE^2 per sample)
            assert abs(placed[i] - t_sp[i]) <= 1.0 / RATE_HZ + 1e-9, (i, placed[i], t_sp[i], step)
        assert t_sp[i - 1] < placed[i] if i > 0 else True
        assert placed[i] <= t_seen[i]
    # the placed set points explain the curvature to its noise
    resid = kappa - interval_average(t, placed, v_sp, fb)
    assert resid[1:].std() < 1.2 * NOISE


def test_nothing_to_place_leaves_the_timeline_as_it_is(rng):
    t, kappa, fb, t_sp, v_sp = _stream(rng, 8)
    assert np.array_equal(place_unacknowledged(t, kappa, fb, t_sp, v_sp, np.ones(8, bool)), t_sp)
    # a lost set point equal to the one before changes nothing: it stays at its bound
    v_sp[4] = v_sp[3]
    kappa = interval_average(t, t_sp, v_sp, fb) + rng.normal(0.0, NOISE, t.size)
    ack = np.ones(8, bool)
    ack[4] = False
    late = t_sp.copy()
    late[4] = t_sp[5]
    assert place_unacknowledged(t, kappa, fb, late, v_sp, ack)[4] == t_sp[5]


def test_a_set_point_after_the_last_acknowledgement_is_placed_at_or_after_its_intended_tick(rng):
    """Under load the unit runs ahead of what the procedure has read: the tick a set point was meant for is
    only the earliest it can have taken effect (seen beside other work: the trailer's L2 came out 6-7 of its
    sigmas long when such set points were taken at their intended ticks)."""
    t, kappa, fb, t_sp, v_sp = _stream(rng, 10)
    v_sp[-1] = v_sp[-2] + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.2)  # a step the curvature shows
    kappa = interval_average(t, t_sp, v_sp, fb) + rng.normal(0.0, NOISE, t.size)
    ack = np.ones(10, bool)
    ack[-1] = False
    lag = float(rng.uniform(1.0, 8.0))  # the unit was this far ahead when the set point was sent
    intended = t_sp.copy()
    intended[-1] = max(t_sp[-2] + 0.1, round((t_sp[-1] - lag) * RATE_HZ) / RATE_HZ)
    bound = t_sp.copy()
    bound[-1] = t[-1]  # nothing acknowledged after it: the end of the record
    placed = place_unacknowledged(t, kappa, fb, bound, v_sp, ack, intended)
    assert abs(placed[-1] - t_sp[-1]) <= 1.0 / RATE_HZ + 1e-9, (placed[-1], t_sp[-1], intended[-1])
    # before its earliest tick it is never placed, whatever the curvature says
    too_late = intended.copy()
    too_late[-1] = t_sp[-1] + 2.0
    assert place_unacknowledged(t, kappa, fb, bound, v_sp, ack, too_late)[-1] >= too_late[-1] - 1e-9
