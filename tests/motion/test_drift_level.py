"""The size of the reading's drift that a dry run adds: what consecutive rests share.

A motion model's ``tracker_drift`` once sized the dry run's drift from the rests' drift *rates* alone, with
periods assumed (10-40 s): on the look-alike of issue 42's UR arm, whose reading wanders over 1-3 s, that made a
drift of ~17 um per axis, and the dry run's rests scattered 13-22 um per axis against the arm's 5.6-7.5 um.
:func:`station.analysis.motion.diagnose.drift_level_sd` now measures the drift's size: the scatter of the rests
about their pose's mean that consecutive rests share. A stop's scatter and a wander shorter than the time between
rests are not shared; a slow drift is. The dry run's drift (:func:`station.models.motion_effects.approach_offsets_mm`)
has that size, and its periods are scaled so its rate is the measured one. Thresholds are set from each stream's
own scatter (the sum over ``n`` pairs of products of independent deviations has a standard deviation of
``sigma^2 / sqrt(n)``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from station.analysis.motion.diagnose import drift_level_sd
from station.analysis.motion.windows import cut_windows
from station.models.motion_effects import KIND, approach_offsets_mm, check_motion_model

from .motion_stream import draw, drift_at, make_stream
from .real_arm import draw as arm_draw, make as arm_make

#: standard deviations of the shared sum's noise allowed
Z = 4.0


def _scatter_and_pairs(w) -> tuple[float, int]:
    """The rests' scatter per axis about their pose's mean (mm) and the number of consecutive pairs."""
    to = np.asarray(w.to_pose, dtype=object)
    dev = np.concatenate([w.p_end_mm[to == p] - w.p_end_mm[to == p].mean(axis=0) for p in set(w.to_pose)])
    pairs = int(np.count_nonzero(np.diff(np.sort(w.move_index)) == 1))
    return float(np.sqrt(np.mean(dev ** 2))), pairs


def test_a_slow_drift_is_what_consecutive_rests_share(rng):
    """A hidden drift of 30-90 s periods: the estimate is the drift's own shared variance at the rests (the
    estimator applied to the drift alone), within the noise the stops' scatter and wander add to the sum."""
    d = draw(rng, effects=("tracker_drift",))
    s = make_stream(d)
    w = cut_windows(s.t_s, s.xyz_mm, s.poses_mm, s.names)
    clean = make_stream(dict(d, effects=()))
    w0 = cut_windows(clean.t_s, clean.xyz_mm, clean.poses_mm, clean.names)
    sigma_s, n = _scatter_and_pairs(w0)           # the stops' own scatter and wander
    # the drift alone at the rests (the late dwells' mean times), through the same estimator
    wd = replace(w, p_end_mm=drift_at(d, w.t_late_s))
    c_true = drift_level_sd(wd) ** 2
    sigma_d = math.sqrt(c_true)
    c = drift_level_sd(w) ** 2
    tol = Z * (sigma_s ** 2 + 2.0 * sigma_s * sigma_d) / math.sqrt(n)
    assert abs(c - c_true) <= tol, (c, c_true, tol, sigma_s, n)
    # ... and the drift is what the estimate sees: well above the same stream's estimate without it
    assert drift_level_sd(w0) ** 2 <= Z * sigma_s ** 2 / math.sqrt(n)
    assert c > 4.0 * drift_level_sd(w0) ** 2


def test_a_wander_between_rests_is_not_shared(rng):
    """The look-alike of issue 42's arm (stop scatter 4-7 um, the tracker's 2-3 um wander of 1-3 s), 30 cycles:
    the shared part is the noise of the sum, not the rests' scatter."""
    d = arm_draw(rng)
    cycles = 30
    d = dict(d, cycles=cycles, overhead_s=rng.uniform(0.0, 0.08, 2 * cycles))
    ra = arm_make(d)
    w = cut_windows(ra.t_s, ra.xyz_mm, ra.poses_mm, ["P1", "P2"])
    sigma, n = _scatter_and_pairs(w)
    assert n >= 2 * cycles - 2
    assert drift_level_sd(w) ** 2 <= Z * sigma ** 2 / math.sqrt(n), (drift_level_sd(w), sigma, n)


def _model(drift: dict):
    return check_motion_model({"kind": KIND, "version": 1,
                               "servo": {"frequency_hz": 12.0, "damping": 0.7, "jerk_time_s": 0.0},
                               "deceleration_mm_s2": 1500.0, "effects": {"tracker_drift": drift}})


def test_the_dry_runs_drift_has_the_measured_size_and_rate(rng):
    """A model's drift of ``level_sd_mm`` and ``rate_sd_mm_per_s``: over the seeds (the sinusoids' phases and
    relative periods), the offsets have that variance per axis and their rate that variance; a level of 0 adds
    nothing; a model without a level (older files) keeps its rate. 20 seeds x 3 axes over 100 of the drift's rms
    periods each: two close periods of one axis beat slowly, so one seed's spread alone is not the model's."""
    level, rate = rng.uniform(0.002, 0.03), rng.uniform(0.0005, 0.01)
    model = _model({"shrinkage": 1.0, "rate_sd_mm_per_s": rate, "level_sd_mm": level})
    t = np.linspace(0.0, 100.0 * 2.0 * np.pi * level / rate, 100_000)
    var, var_rate = [], []
    for seed in rng.integers(2**31, size=20):
        off = approach_offsets_mm(t, [], model, int(seed))
        var.append(np.var(off, axis=0))
        var_rate.append(np.var(np.gradient(off, t, axis=0), axis=0))
    assert float(np.mean(var)) == pytest.approx(level ** 2, rel=0.1)
    assert float(np.mean(var_rate)) == pytest.approx(rate ** 2, rel=0.1)
    seed = int(rng.integers(2**31))
    none = approach_offsets_mm(t[:1000], [], _model({"shrinkage": 1.0, "rate_sd_mm_per_s": rate,
                                                     "level_sd_mm": 0.0}), seed)
    assert not none.any()
    # a file written before the level was measured: the rate alone, with the periods assumed (each sinusoid's
    # amplitude from its own period), over the same seeds
    tt = np.linspace(0.0, 4000.0, 100_000)
    older = _model({"shrinkage": 1.0, "rate_sd_mm_per_s": rate})
    var_rate = [np.var(np.gradient(approach_offsets_mm(tt, [], older, int(sd)), tt, axis=0), axis=0)
                for sd in rng.integers(2**31, size=20)]
    assert float(np.mean(var_rate)) == pytest.approx(rate ** 2, rel=0.1)
