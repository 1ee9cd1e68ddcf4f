"""Time stamps that cannot be a time base are found; good ones (jitter, lost samples) are not refused."""

from __future__ import annotations

import numpy as np
import pytest

from station.analysis.iso9283.time_base import check_time_stamps, sample_index_time
from station.errors import DataError


def test_good_stamps_with_jitter_and_lost_samples_pass(rng):
    rate = float(rng.choice([10.0, 100.0, 1000.0]))
    n = 5000
    t = np.arange(n) / rate + rng.uniform(-0.2, 0.2, n) / rate
    keep = np.ones(n, bool)
    a = int(rng.integers(100, 4000))
    keep[a:a + int(rng.integers(5, 300))] = False  # a beam break drops samples
    chk = check_time_stamps(t[keep])
    assert chk.ok, chk.problems
    assert chk.n_lost == pytest.approx(int((~keep).sum()), abs=2)
    assert chk.median_step_s == pytest.approx(1 / rate, rel=0.05)


def test_coarse_stamps_repeat(rng):
    rate = 100.0
    t = np.floor(np.arange(3000) / rate * (1 + rng.uniform(-1e-3, 1e-3)) + rng.uniform(0, 1))  # 1 s resolution
    chk = check_time_stamps(t)
    (p,) = chk.problems
    first = 1 + int(np.argmax(np.diff(t) == 0))
    assert p.row == first and "repeats" in p.text and "coarser than the sample spacing" in p.text
    assert chk.resolution_s == 1.0 and chk.n_repeats > 2900
    assert "np." not in p.text


def test_stamps_in_bursts_disagree_with_the_sample_count(rng):
    # a logger stamping on receipt: packets of 10 samples every 0.1 s, 1 ms apart inside a packet
    n = 2000
    t = (np.arange(n) // 10) * 0.1 + (np.arange(n) % 10) * 0.001 + rng.uniform(0, 1e-4, n)
    chk = check_time_stamps(np.sort(t))
    (p,) = chk.problems
    assert p.row is None and "the stamps come in bursts" in p.text


def test_stamps_whose_step_disagrees_with_the_count(rng):
    # a stamping clock that slips against the samples: 40 % of the steps 40 % long (not gaps: no lost samples)
    n = 2000
    steps = np.where(rng.random(n - 1) < 0.4, 0.014, 0.010)
    chk = check_time_stamps(np.concatenate([[0.0], np.cumsum(steps)]))
    (p,) = chk.problems
    assert p.row is None and "disagrees with the sample count" in p.text and "0.01 s" in p.text


def test_stamps_going_back(rng):
    t = np.arange(100) * 0.01
    i = int(rng.integers(5, 95))
    t[i] = t[i - 2]
    chk = check_time_stamps(t)
    assert chk.problems[0].row == i and "time goes back" in chk.problems[0].text


def test_sample_index_time():
    assert np.array_equal(sample_index_time(4, 2.0), [0.0, 0.5, 1.0, 1.5])
    with pytest.raises(DataError, match="rate_hz must be a finite number > 0"):
        sample_index_time(4, 0.0)
