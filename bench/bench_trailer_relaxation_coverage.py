"""Trailer diagnosis: coverage of the relaxation's 95 % interval on `station simulate trailer`'s records.

Run by hand: ``.venv/bin/python bench/bench_trailer_relaxation_coverage.py [--draws N] [--seed S]``.

For nothing hidden (the ideal trailer relaxes over L2, fitted driven by the measured curvature) and for a
hidden relaxation of a few cm (fitted driven by the leave-out smoothing), each draw's record is diagnosed and
the interval of its ``hitch_dynamics`` step held against the truth's ``expected_fitted_relaxation_m``: the
share of draws it holds (nominal 0.95), and the fitted value's offset from the truth in units of the
interval's half-width over 1.96 (a mean far from 0 is a bias, a spread far from 1 an interval of the wrong
width). About 10 s a draw on an idle core.
"""

from __future__ import annotations

import argparse

import numpy as np

from fakes.sim.offline_files import simulate_trailer
from station.analysis.diagnose.trailer import diagnose_trailer


def coverage(hidden: tuple, seeds) -> None:
    held, z = 0, []
    for seed in seeds:
        cols, truth = simulate_trailer(hidden=hidden, seed=int(seed))
        res = diagnose_trailer(cols["t"], cols["kappa"], cols["psi"], L1_m=1.25, L2_m=2.48, v_m_s=cols["v"],
                               alpha=0.01)
        step = next((s for s in res.steps if s.effect == "hitch_dynamics"), None)
        if step is None:
            print(f"  seed {seed}: no relaxation named ({res.selected})")
            continue
        lo, hi = step.ci["relaxation_m"]
        fit, true = step.params["relaxation_m"], truth["expected_fitted_relaxation_m"]
        held += lo <= true <= hi
        z.append((fit - true) / ((hi - lo) / 2 / 1.96))
        print(f"  seed {seed}: fitted {fit:.4f} m, interval [{lo:.4f}, {hi:.4f}], truth {true:.4f}"
              f"{'' if lo <= true <= hi else '  OUTSIDE'}", flush=True)
    z = np.array(z)
    print(f"{'+'.join(hidden) or 'nothing hidden'}: held {held} of {z.size}; offset / (half-width / 1.96): "
          f"mean {z.mean():+.2f}, sd {z.std(ddof=1):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20, help="records per case (default 20)")
    ap.add_argument("--seed", type=int, default=None, help="first record's seed (default: drawn)")
    args = ap.parse_args()
    first = args.seed if args.seed is not None else int(np.random.default_rng().integers(2**31 - 10_000))
    seeds = range(first, first + args.draws)
    print(f"seeds {first}..{first + args.draws - 1}")
    coverage((), seeds)
    coverage(("hitch_dynamics",), seeds)


if __name__ == "__main__":
    main()
