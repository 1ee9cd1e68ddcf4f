"""The stop list's figures computed for many poses at once (issue 47 item 10) against the per-pose formulas.

A stop list of 100,000 poses spent most of its time in per-pose calls: AP and RP
(:func:`position_accuracy`, :func:`position_repeatability`), the scatter of the
stops, a JSON number list per array. The batched forms must give the same
numbers to the bit, on random poses with any number of stops (none, one, many).
"""

from __future__ import annotations

import math

import numpy as np

from station import characteristics as table
from station.analysis.iso9283.characteristics import position_accuracy, position_repeatability
from station.analysis.iso9283.lab_files import stop_scatter_mm
from station.analysis.iso9283.stop_list import _pose_statistics
from station.numeric import finite_list, finite_or_none


def test_pose_statistics_equal_the_per_pose_formulas_to_the_bit(rng):
    K = int(rng.integers(50, 3000))
    centroid = rng.uniform(-1500.0, 1500.0, (K, 3)) + rng.normal(0.0, 0.03, (K, 3))
    P = int(rng.integers(1, 200))
    kps = [rng.permutation(K)[:int(rng.integers(0, 16))] for _ in range(P)]
    cmd = rng.uniform(-1500.0, 1500.0, (P, 3))
    for with_cmd in (True, False):
        stats = _pose_statistics(centroid, kps, cmd if with_cmd else None)
        for kp, (acc, rep, mean), c in zip(kps, stats, cmd):  # loop over poses
            if kp.size == 0:
                assert acc is None and rep is None and mean is None
                continue
            assert np.array_equal(mean, centroid[kp].mean(axis=0))
            if with_cmd:
                want = position_accuracy(centroid[kp], c, kp)
                assert (acc.AP_mm, acc.APx_mm, acc.APy_mm, acc.APz_mm, acc.n) == \
                    (want.AP_mm, want.APx_mm, want.APy_mm, want.APz_mm, want.n)
                assert np.array_equal(acc.mean_mm, want.mean_mm) and np.array_equal(acc.rows, want.rows)
            else:
                assert acc is None
            if kp.size < 2:
                assert rep is None
                continue
            want = position_repeatability(centroid[kp], kp)
            assert (rep.RP_mm, rep.l_bar_mm, rep.S_l_mm, rep.n) == (want.RP_mm, want.l_bar_mm, want.S_l_mm, want.n)
            assert np.array_equal(rep.l_mm, want.l_mm) and np.array_equal(rep.rows, want.rows)


def test_stop_scatter_equals_the_per_pose_sum_to_the_bit(rng):
    for _ in range(10):  # loop over random stop lists
        K = int(rng.integers(1, 2000))
        pose = [f"P{int(x)}" for x in rng.integers(0, max(1, K // int(rng.integers(1, 12))), K)]
        c = rng.uniform(-1000.0, 1000.0, (K, 3))
        arr = np.array(pose, dtype=object)
        dev, dof = 0.0, 0
        for p in dict.fromkeys(pose):  # the poses in order of first appearance, as the pooled sum runs
            m = np.flatnonzero(arr == p)
            if m.size >= 2:
                dev += float(np.sum((c[m] - c[m].mean(axis=0)) ** 2))
                dof += 3 * (m.size - 1)
        assert stop_scatter_mm(c, pose) == (math.sqrt(dev / dof) if dof else 0.0)


def test_finite_list_equals_finite_or_none_per_element(rng):
    a = rng.normal(0.0, 1.0, 3000) * 10.0 ** rng.uniform(-9.0, 9.0, 3000)
    a[rng.random(a.size) < 0.1] = np.nan
    a[rng.random(a.size) < 0.05] = np.inf
    a[rng.random(a.size) < 0.05] = -np.inf
    for nd in (None, 0, 3, 6):
        got = finite_list(a.reshape(-1, 3), nd)
        want = [finite_or_none(x, nd) for x in a]
        assert got == want
        assert [type(x) for x in got] == [type(x) for x in want]


def test_the_kept_rows_of_a_programme_follow_an_added_row():
    before = table.characteristics()
    assert table.characteristics() is before  # kept
    extra = table.Characteristic("XX_test_mm", "mm", "pose", None, "a row of this test only", lambda s: None)
    with table.added(extra):
        assert table.characteristics() == before + (extra,)
    assert table.characteristics() == before
