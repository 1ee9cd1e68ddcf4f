"""Each path figure lies within its stated U of the truth of a simulated arm (tests/path/simarm.py).

The draws are random (the test's rng); each kind is drawn a few times and a
binomial threshold is set from the ~95 % the U claims, for the family of
checks a suite run makes (about 40 figure-kinds): with 6 draws, 3 or more
inside (P(fewer | p = 0.95) = 9e-5 each, 3e-3 for the family; at p = 0.9,
1.3e-3 each). A U that covers half the time fails it one run in three. The
coverage itself is measured in bench/bench_path_coverage.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from station.analysis.path.analysis import analyze_path
from station.analysis.path.path_file import parse_paths
from tests.path import simarm

DRAWS = 6
MIN_INSIDE = 3


@pytest.mark.parametrize("kind", sorted(simarm.KINDS))
def test_figures_within_U_of_truth(kind, rng):
    inside: dict[str, int] = {}
    for _ in range(DRAWS):  # loop over draws
        noise = rng.uniform(0.005, 0.02)
        sim = simarm.KINDS[kind](rng, n_cycles=5, noise=noise)
        spec = parse_paths({"paths": [sim.path]})[0]
        r = analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), noise_sd_mm=noise, trials=60,
                         seed=int(rng.integers(2**31)))
        assert r.n_cycles == 5, r.notes
        for fig, truth in sim.truth.items():  # loop over figures
            fu = r.uncertainty[fig]
            assert fu.U > 0
            inside[fig] = inside.get(fig, 0) + int(abs(r.figures[fig] - truth) <= fu.U)
    assert all(v >= MIN_INSIDE for v in inside.values()), inside


def test_a_rectangle_from_the_end_of_its_start_blend_counts_every_cycle(rng):
    """A stream that begins where the start corner's blend ends (no lead-in), on a small rectangle: every cycle
    counts and nothing is reported broken. The cycle's mark once sat at 1 % of the length (4-4.4 mm here, inside
    the 6-8 mm blend): the first turn was lost and the last reported broken (CI, session seed 2262091302)."""
    sim = simarm.rectangle(rng, n_cycles=5, noise=0.01, blend=True, sides_mm=(100, 110), blend_mm=(6.0, 8.0))
    spec = parse_paths({"paths": [sim.path]})[0]
    r = analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), noise_sd_mm=0.01, trials=30,
                     seed=int(rng.integers(2**31)))
    assert r.n_cycles == 5 and not r.broken, r.notes
    assert r.figures["CR_mm"] is not None and r.figures["CO_mm"] is not None


def test_beam_break_mid_path_leaves_that_cycle_out_with_the_reason(rng):
    sim = simarm.line(rng, n_cycles=5, noise=0.01)
    valid = np.ones(sim.t.size, bool)
    starts = np.flatnonzero(np.diff(sim.t) > 0.2) + 1  # the cycles' first samples
    a = starts[1] + (starts[2] - starts[1]) // 2
    valid[a:a + 30] = False
    spec = parse_paths({"paths": [sim.path]})[0]
    r = analyze_path(spec, sim.t, np.where(valid[:, None], sim.meas, np.nan), valid, noise_sd_mm=0.01, trials=50)
    assert r.n_cycles == 4
    assert len(r.broken) == 1 and "beam broke" in r.broken[0].reason
    assert r.figures["AT_mm"] is not None


def test_refused_clock_refuses_the_time_figures_only(rng):
    sim = simarm.weave(rng, n_cycles=4, noise=0.01)
    spec = parse_paths({"paths": [sim.path]})[0]
    r = analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), noise_sd_mm=0.01, trials=50,
                     clock_refused="stamps coarser than the motion")
    assert r.figures["WF_percent"] is None and r.refused["WF_percent"] == "stamps coarser than the motion"
    assert abs(r.figures["WS_percent"] - sim.truth["WS_percent"]) <= max(r.uncertainty["WS_percent"].U, 0.5)


def test_one_cycle_is_not_enough(rng):
    sim = simarm.line(rng, n_cycles=1, noise=0.01)
    spec = parse_paths({"paths": [sim.path]})[0]
    r = analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), noise_sd_mm=0.01, trials=20)
    assert r.figures["AT_mm"] is None and "1 complete cycle" in r.refused["AT_mm"]


def test_reorientation_AT_RT_within_U_of_truth(rng):
    inside = {"AT_mm": 0, "RT_mm": 0}
    for _ in range(DRAWS):  # loop over draws
        noise = rng.uniform(0.005, 0.02)
        sim = simarm.reorientation(rng, n_cycles=5, noise=noise)
        spec = parse_paths({"paths": [sim.path]})[0]
        abc = sim.abc + rng.standard_normal(sim.abc.shape) * 0.001  # the angles' own noise, deg
        r = analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), abc_deg=abc, noise_sd_mm=noise,
                         trials=60, seed=int(rng.integers(2**31)))
        assert r.n_cycles == 5, r.notes
        for fig in inside:  # loop over figures
            inside[fig] += int(abs(r.figures[fig] - sim.truth[fig]) <= r.uncertainty[fig].U)
    assert all(v >= MIN_INSIDE for v in inside.values()), inside


def test_reorientation_without_angles_is_refused_clearly(rng):
    import pytest as _pytest

    from station.errors import DataError

    sim = simarm.reorientation(rng, n_cycles=2, noise=0.01)
    spec = parse_paths({"paths": [sim.path]})[0]
    with _pytest.raises(DataError, match="no angles"):
        analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), noise_sd_mm=0.01)
