"""Laser tracker measurement model: the MPE as a systematic error, the reading noise, frames, timing, beam breaks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from fakes.sim.tracker import TrackerModel
from station.errors import ConfigError
from station.models.tracker_noise import TrackerNoise


def _pose(rng):
    yaw = rng.uniform(-np.pi, np.pi)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    T[:3, 3] = rng.uniform(-3000, 3000, 3)
    return T


def _static(p):
    p = np.asarray(p, dtype=float)
    return lambda t: np.tile(p, (np.size(t), 1))


@pytest.mark.parametrize("rate", [5.0, 3001.0, float("nan"), -10.0])
def test_rate_outside_range_refused(rate):
    with pytest.raises(ConfigError, match="rate_hz"):
        TrackerModel(np.eye(4), rate)


def test_bad_configuration_refused():
    with pytest.raises(ConfigError, match="base_T_tracker"):
        TrackerModel(np.ones((4, 4)))
    with pytest.raises(ConfigError, match="mpe_a_um"):
        TrackerModel(np.eye(4), mpe_a_um=-1)
    with pytest.raises(ConfigError, match="latency_s"):
        TrackerModel(np.eye(4), latency_s=float("inf"))
    with pytest.raises(ConfigError, match="beam break"):
        TrackerModel(np.eye(4), beam_breaks=[(2.0, 1.0)])
    for rate in (10.0, 3000.0):
        assert TrackerModel(np.eye(4), rate).rate_hz == rate


@pytest.mark.parametrize("distance_m", [1.5, 8.0])
def test_accuracy_is_a_systematic_error_of_the_session(distance_m, rng):
    """The MPE is drawn once per tracker (offset sd a/2, scale and angles sd b/2 ppm / urad): over many
    trackers the error of one point has per-coordinate variance (a/2)^2 + (b R / 2)^2 (chi-square test); within
    one tracker it is the same at every sample (the mean reading is off by it, not the sample scatter)."""
    a, b = rng.uniform(5, 30), rng.uniform(2, 10)
    direction = rng.normal(size=3)
    p_trk = direction / np.linalg.norm(direction) * distance_m * 1000.0
    m = 400
    errs = np.array([TrackerModel(np.eye(4), 100.0, mpe_a_um=a, mpe_b_um_per_m=b, noise=TrackerNoise(0.0),
                                  seed=int(s)).reading(p_trk[None])[0] - p_trk
                     for s in rng.integers(0, 1 << 30, m)])
    var = ((a / 2) ** 2 + (b * distance_m / 2) ** 2) * 1e-6
    assert math.sqrt(var) <= TrackerModel(np.eye(4), mpe_a_um=a, mpe_b_um_per_m=b).sigma_mm(distance_m * 1000) + 1e-12
    chi2 = float(np.sum(errs ** 2)) / var  # 3 m degrees of freedom (the coordinates' shares differ, the sum not)
    assert stats.chi2.ppf(1e-5, 3 * m) < chi2 < stats.chi2.ppf(1 - 1e-5, 3 * m)
    # one tracker: a fixed error, plus the reading noise only
    T = _pose(rng)
    noise = TrackerNoise(white_um=rng.uniform(0.3, 2.0))
    tr = TrackerModel(T, 1000.0, mpe_a_um=a, mpe_b_um_per_m=b, noise=noise, seed=int(rng.integers(1 << 30)))
    p_base = T[:3, :3] @ p_trk + T[:3, 3]
    xyz, valid = tr.measure(tr.sample_times(0.0, 5.0), _static(p_base))
    res = xyz - tr.reading(p_trk[None])[0]
    n = res.shape[0]
    sig = noise.white_um * 1e-3
    for k in range(3):
        chi2 = float(np.sum(res[:, k] ** 2)) / sig ** 2
        assert stats.chi2.ppf(1e-5, n) < chi2 < stats.chi2.ppf(1 - 1e-5, n)


def test_reading_noise_is_white_plus_wander(rng):
    """Eq. (N1): the lag-1 difference has variance 2 (w^2 + g^2 (1 - phi)), a long lag 2 (w^2 + g^2), and
    the same instants measured in chunks give the same readings (the wander is drawn by index)."""
    rate = float(rng.choice([100.0, 333.3333, 1000.0]))
    noise = TrackerNoise(white_um=rng.uniform(0.3, 1.5), wander_um=rng.uniform(1.0, 4.0),
                         wander_tau_s=rng.uniform(0.3, 2.0))
    tr = TrackerModel(_pose(rng), rate, noise=noise, seed=int(rng.integers(1 << 30)))
    duration = 600.0
    t = tr.sample_times(0.0, duration)
    x = tr.measure(t, _static([1000.0, 2000.0, 500.0]))[0]
    x = (x - x.mean(axis=0)) * 1e3  # um
    n = x.shape[0]
    d1 = np.diff(x, axis=0)
    want1 = 2 * noise.semivariogram_um2(1.0 / rate)
    # lag-1 differences are nearly independent: n - 1 draws per axis, 3 axes
    chi2 = float(np.sum(d1 ** 2)) / want1
    assert stats.chi2.ppf(1e-5, 3 * (n - 1)) * 0.98 < chi2 < stats.chi2.ppf(1 - 1e-5, 3 * (n - 1)) * 1.02
    # total variance: about duration / (2 tau) independent wander values per axis
    k_eff = 3 * duration / (2 * noise.wander_tau_s)
    tot = float(np.mean(x ** 2))
    assert abs(tot / noise.total_um ** 2 - 1) < 6 / math.sqrt(k_eff)
    # correlation at lag tau: g^2 e^-1 / (w^2 + g^2)
    lag = int(round(noise.wander_tau_s * rate))
    c = float(np.mean(x[:-lag] * x[lag:])) / tot
    assert abs(c - noise.wander_um ** 2 * math.exp(-lag / (noise.wander_tau_s * rate)) / noise.total_um ** 2) \
        < 6 / math.sqrt(k_eff)
    parts = [tr.measure(t[i: i + 70001], _static([1000.0, 2000.0, 500.0]))[0] for i in range(0, t.size, 70001)]
    np.testing.assert_array_equal(np.concatenate(parts), tr.measure(t, _static([1000.0, 2000.0, 500.0]))[0])


def test_frame_latency_and_time_grid(rng):
    T = _pose(rng)
    latency = 0.0123
    offset = rng.uniform(-100, 100)
    tr = TrackerModel(T, 250.0, mpe_a_um=0.0, mpe_b_um_per_m=0.0, latency_s=latency, clock_offset_s=offset,
                      noise=TrackerNoise(0.0))
    t = tr.sample_times(3.0, 5.0)
    dev = tr.device_time(t)
    k = dev * 250.0
    np.testing.assert_allclose(k, np.round(k), atol=1e-6)  # the device's own grid
    assert t[0] >= 3.0 and t[-1] < 5.0 and t.size == 500
    vel = np.array([100.0, -50.0, 20.0])

    def moving(tt):
        return np.outer(tt, vel) + 1000.0

    xyz, valid = tr.measure(t, moving)
    p_base = moving(t - latency)
    expect = (p_base - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(xyz, expect, atol=1e-9)
    np.testing.assert_allclose(tr.to_tracker_frame(p_base), expect, atol=1e-9)


def test_scheduled_beam_breaks_exactly_in_their_windows(rng):
    breaks = [(1.2345, 1.5), (2.0, 2.25), (2.2, 2.4)]
    tr = TrackerModel(_pose(rng), 1000.0, beam_breaks=breaks[:2])
    tr.add_beam_break(*breaks[2])  # added while running (fault injection)
    t = tr.sample_times(0.0, 4.0)
    xyz, valid = tr.measure(t, _static([1000.0, 2000.0, 500.0]))
    inside = np.zeros(t.size, dtype=bool)
    for a, b in breaks:
        inside |= (t >= a) & (t < b)
    np.testing.assert_array_equal(valid, ~inside)
    assert np.isnan(xyz[~valid]).all() and np.isfinite(xyz[valid]).all()
    assert (~valid).sum() == pytest.approx(1000 * (0.2655 + 0.4), abs=2)


def test_random_breaks_rate_and_reproducibility(rng):
    rate_per_h = 600.0
    tr = TrackerModel(_pose(rng), 100.0, random_breaks_per_hour=rate_per_h, random_break_duration_s=(0.1, 0.3),
                      seed=int(rng.integers(1 << 30)))
    t = tr.sample_times(0.0, 7200.0)
    f = _static([500.0, 500.0, 500.0])
    xyz, valid = tr.measure(t, f)
    # the same instants measured in chunks give the same values and the same breaks
    parts = [tr.measure(t[i : i + 77777], f) for i in range(0, t.size, 77777)]
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), valid)
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), xyz)
    # the breaks drawn ~ Poisson(rate * 2 h)
    lam = rate_per_h * 2
    drawn = tr.random_breaks(0.0, 7200.0)
    drawn = drawn[(drawn[:, 0] >= 0.0) & (drawn[:, 0] < 7200.0)]
    assert stats.poisson.ppf(1e-4, lam) <= len(drawn) <= stats.poisson.ppf(1 - 1e-4, lam)
    # the samples show one start per break, except where breaks overlap (one longer break) or leave a gap
    # shorter than a sample interval between them (about 3 % of the starts fall inside another break: the
    # visible count is not Poisson(rate * 2 h), and seed 66385 saw 1,056 starts of 1,095 breaks drawn)
    starts = np.flatnonzero(np.diff(valid.astype(int)) == -1)
    order = drawn[np.argsort(drawn[:, 0])]
    end_so_far = np.maximum.accumulate(order[:, 1])
    gap = order[1:, 0] - end_so_far[:-1]
    assert int(np.sum(gap >= 1.0 / 100.0)) <= starts.size <= int(np.sum(gap > 0.0)) + 1
    frac = 1 - valid.mean()
    assert frac == pytest.approx(lam * 0.2 / 7200.0, rel=0.25)


def test_a_point_comes_out_the_same_whatever_batch_carries_it(rng):
    """A stream's batches depend on the host's timing; a point's tracker-frame coordinates must not (a matrix
    product rounded a row by one ulp depending on where it fell in the batch, and a resumed run differed)."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 1, 3)).as_matrix()
    T[:3, 3] = rng.normal(0, 2000, 3)
    model = TrackerModel(T)
    p = rng.normal(0, 1000, (257, 3))
    whole = model.to_tracker_frame(p)
    cuts = np.sort(rng.choice(np.arange(1, 257), size=12, replace=False))
    parts = np.concatenate([model.to_tracker_frame(c) for c in np.split(p, cuts)])
    assert np.array_equal(whole, parts)
    assert all(np.array_equal(model.to_tracker_frame(p[k:k + 1])[0], whole[k]) for k in range(0, 257, 16))
