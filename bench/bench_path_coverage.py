"""How often each path figure's U covers the truth of a simulated arm (the ~95 % claim of issue 44).

    .venv/bin/python bench/bench_path_coverage.py [DRAWS_PER_KIND] [SEED]

The arm is the tests' own (tests/path/simarm.py: lines, full circles,
rectangles with and without blend, weaving; random servo lag, corner rounding,
overshoot, velocity ripple, weave errors, tracker noise 5-20 um), written apart
from station.analysis.path. Prints, per figure, the fraction of draws with
|figure - truth| <= U and its binomial 95 % interval, and the median U.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.analysis.path.analysis import analyze_path  # noqa: E402
from station.analysis.path.path_file import parse_paths  # noqa: E402
from tests.path import simarm  # noqa: E402


def main(draws: int = 40, seed: int = 1) -> None:
    rng = np.random.default_rng(seed)
    hits: dict[str, list] = {}
    for kind, make in simarm.KINDS.items():  # loop over path kinds
        for _ in range(draws):  # loop over draws
            noise = rng.uniform(0.005, 0.02)
            sim = make(rng, n_cycles=10, noise=noise)
            spec = parse_paths({"paths": [sim.path]})[0]
            r = analyze_path(spec, sim.t, sim.meas, np.ones(sim.t.size, bool), noise_sd_mm=noise,
                             seed=int(rng.integers(2**31)))
            for fig, truth in sim.truth.items():  # loop over figures
                fu = r.uncertainty[fig]
                hits.setdefault(fig, []).append((abs(r.figures[fig] - truth) <= fu.U, fu.U,
                                                 r.figures[fig] - truth))
    print(f"{'figure':12s} {'covered':>8s} {'95% interval':>16s} {'median U':>10s} {'median |err|':>12s}  draws")
    for fig, h in hits.items():  # loop over figures
        ok = np.array([x[0] for x in h])
        n, k = ok.size, int(ok.sum())
        p = k / n
        half = 1.96 * np.sqrt(max(p * (1 - p), 1e-9) / n)
        print(f"{fig:12s} {p:8.3f} [{max(p - half, 0):.3f}, {min(p + half, 1):.3f}] "
              f"{np.median([x[1] for x in h]):10.4g} {np.median(np.abs([x[2] for x in h])):12.4g}  {n}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 40, int(sys.argv[2]) if len(sys.argv) > 2 else 1)
