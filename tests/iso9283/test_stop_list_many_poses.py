"""A stop list of many poses says what is short of ISO 9283 in one sentence, not one line per pose."""

from __future__ import annotations

import numpy as np

from station.analysis.iso9283.characteristics import MOST_LISTED
from station.analysis.iso9283.stop_list import analyze_stop_list


def _list(rng, n_poses: int, cycles: int):
    cmd = rng.uniform(-1000.0, 1000.0, (n_poses, 3))
    names = [f"Q{i}" for i in range(n_poses)]
    pose = [names[i] for _ in range(cycles) for i in range(n_poses)]
    cycle = [c + 1 for c in range(cycles) for _ in range(n_poses)]
    pts = np.concatenate([cmd + rng.normal(0.0, 0.02, cmd.shape) for _ in range(cycles)])[:, None, :]
    return analyze_stop_list(pose, cycle, pts, commanded_mm=cmd, names=names)


def test_many_short_poses_are_counted_in_one_warning_and_one_reason(rng):
    n = int(rng.integers(MOST_LISTED + 1, 400))
    cycles = int(rng.integers(2, 30))
    res = _list(rng, n, cycles)
    short = [w for w in res.warnings if "prescribes 30" in w]
    assert short == [f"{n} poses of fewer than 30 cycles (" + ", ".join(f"Q{i} {cycles}" for i in range(MOST_LISTED))
                     + f" and {n - MOST_LISTED} more); ISO 9283 prescribes 30"]
    assert not res.iso_conformant
    assert res.iso_reasons[0] == ("fewer than 30 cycles at " + ", ".join(f"Q{i} {cycles}" for i in range(MOST_LISTED))
                                  + f" and {n - MOST_LISTED} more")
    assert len(res.poses) == n and all(p.n_cycles == cycles for p in res.poses.values())


def test_a_few_short_poses_are_each_named(rng):
    n = int(rng.integers(1, MOST_LISTED + 1))
    cycles = int(rng.integers(2, 30))
    res = _list(rng, n, cycles)
    assert [w for w in res.warnings if "prescribes 30" in w] == [
        f"Q{i}: {cycles} cycles; ISO 9283 prescribes 30" for i in range(n)]
    assert res.iso_reasons[0] == "fewer than 30 cycles at " + ", ".join(f"Q{i} {cycles}" for i in range(n))
