"""Benchmark: does the stated uncertainty of AP and RP cover the truth 95 % of the time (k = 2)?

Run by hand: ``.venv/bin/python bench/bench_uncertainty.py [--tests 400] [--trials 20000] [--seed N]``.

Each simulated ISO test (:func:`fakes.sim.iso_stops.simulate_pose_test`)
draws a robot (true AP up to 1 mm, scatter sd 5-50 um per principal axis,
oriented at random), a tracker 2-5 m away with an MPE of 5-25 um + 2-10 um/m,
and a registration fitted on 8 fiducials measured by that tracker.  The budget
states the drawn MPE and the fitted registration (what a station knows, not
the truth).  For 5, 10 and 30 cycles the bench reports how often
``|figure - truth| <= U`` (the stated interval figure +/- U), how often the
truth lies in the Monte Carlo 95 % coverage interval, the same for the
first-order law's U (t factor of its effective degrees of freedom), the
binomial 3-sigma band of a 95 % coverage for that many tests, and the mean
``U / figure``.  Time per figure is printed; no assertion.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from fakes.sim.iso_stops import simulate_pose_test
from station.analysis.uncertainty import Budget, pose_uncertainty


def run(tests: int, trials: int, seed: int, cycles=(5, 10, 30)) -> list[dict]:
    rows = []
    for n in cycles:  # loop over cycle counts
        rng = np.random.default_rng([seed, n])
        hit = {k: np.zeros(tests, bool) for k in ("AP", "RP", "AP_int", "RP_int", "AP_gum", "RP_gum")}
        rel = {"AP": [], "RP": []}
        t0 = time.perf_counter()
        for i in range(tests):  # loop over simulated tests
            sim = simulate_pose_test(rng, n)
            budget = Budget(instrument_a_um=sim.mpe_a_um, instrument_b_um_per_m=sim.mpe_b_um_per_m, trials=trials,
                            seed=i).with_registration(sim.registration, sim.fiducials_mm)
            fu = pose_uncertainty(sim.measured_mm, sim.commanded_mm, budget, f"P1#{i}")
            for key, truth in (("AP", sim.AP_true_mm), ("RP", sim.RP_true_mm)):
                f = fu[f"{key}_mm"]
                hit[key][i] = abs(f.value - truth) <= f.U
                hit[key + "_int"][i] = f.interval[0] <= truth <= f.interval[1]
                hit[key + "_gum"][i] = abs(f.value - truth) <= f.U_gum
                rel[key].append(f.U / max(f.value, 1e-12))
        dt = (time.perf_counter() - t0) / tests
        band = 3.0 * math.sqrt(0.95 * 0.05 / tests)
        rows.append(dict(n=n, tests=tests, band=band, s_per_test=dt,
                         **{k: float(v.mean()) for k, v in hit.items()},
                         U_rel_AP=float(np.median(rel["AP"])), U_rel_RP=float(np.median(rel["RP"]))))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tests", type=int, default=400, help="simulated ISO tests per cycle count")
    ap.add_argument("--trials", type=int, default=20_000, help="Monte Carlo trials per figure")
    ap.add_argument("--seed", type=int, default=None, help="seed (default: drawn and printed)")
    a = ap.parse_args()
    seed = a.seed if a.seed is not None else int(np.random.SeedSequence().entropy % 2**31)
    print(f"bench_uncertainty: seed {seed}, {a.tests} tests per cycle count, {a.trials} MC trials per figure")
    print(f"{'n':>3} {'cover AP':>9} {'cover RP':>9} {'int AP':>7} {'int RP':>7} {'GUM AP':>7} {'GUM RP':>7} "
          f"{'95% band':>13} {'U/AP':>6} {'U/RP':>6} {'s/test':>7}")
    for r in run(a.tests, a.trials, seed):
        print(f"{r['n']:>3} {r['AP']:>9.3f} {r['RP']:>9.3f} {r['AP_int']:>7.3f} {r['RP_int']:>7.3f} "
              f"{r['AP_gum']:>7.3f} {r['RP_gum']:>7.3f} {0.95 - r['band']:>6.3f}-{min(1.0, 0.95 + r['band']):.3f} "
              f"{r['U_rel_AP']:>6.3f} {r['U_rel_RP']:>6.3f} {r['s_per_test']:>7.3f}")


if __name__ == "__main__":
    main()
