"""Trailer diagnosis: coverage of the relaxation's 95 % interval on `station simulate trailer`'s records.

Run by hand: ``.venv/bin/python bench/bench_trailer_relaxation_coverage.py [--draws N] [--seed S] [--psi-sigma RAD]``.

For nothing hidden (the ideal trailer relaxes over L2, fitted driven by the measured curvature) and for a
hidden relaxation of a few cm (fitted driven by the leave-out smoothing), each draw's record is diagnosed and
the interval of its ``hitch_dynamics`` step held against the truth's ``expected_fitted_relaxation_m``: the
share of draws it holds (nominal 0.95), and the fitted value's offset from the truth in units of the
interval's half-width over 1.96 (a mean far from 0 is a bias, a spread far from 1 an interval of the wrong
width). About 10 s a draw on an idle core. ``--psi-sigma``: a precise joint-angle sensor (say 0.0005 rad
against the default U(0.002, 0.005)), where the curvature's noise, filtered by the relaxation, dominates the
scatter of the fitted relaxation (the case a robust window alone made 30 % too narrow).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import stats

from fakes.sim.offline_files import simulate_trailer
from station.analysis.diagnose.trailer import diagnose_trailer


def summary(name: str, rows: list) -> str:
    """``rows`` of ``(fitted, lo, hi, truth)``: the share held (with its binomial interval) and the offsets."""
    held = sum(lo <= true <= hi for _, lo, hi, true in rows)
    z = np.array([(fit - true) / ((hi - lo) / 2 / 1.96) for fit, lo, hi, true in rows])
    n = len(rows)
    lo = stats.beta.ppf(0.025, held, n - held + 1) if held > 0 else 0.0
    hi = stats.beta.ppf(0.975, held + 1, n - held) if held < n else 1.0
    return (f"{name}: held {held} of {n} ({100 * held / n:.1f} %, 95 % Clopper-Pearson {100 * lo:.1f}-"
            f"{100 * hi:.1f} %); offset / (half-width / 1.96): mean {z.mean():+.2f}, sd {z.std(ddof=1):.2f}")


def arguments(doc: str) -> tuple[argparse.Namespace, range]:
    """The benches' options and the seeds they give."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--draws", type=int, default=20, help="records per case (default 20)")
    ap.add_argument("--seed", type=int, default=None, help="first record's seed (default: drawn)")
    ap.add_argument("--psi-sigma", type=float, default=None,
                    help="joint-angle sensor noise, rad (default: drawn, U(0.002, 0.005))")
    args = ap.parse_args()
    first = args.seed if args.seed is not None else int(np.random.default_rng().integers(2**31 - 10_000))
    print(f"seeds {first}..{first + args.draws - 1}")
    return args, range(first, first + args.draws)


def coverage(hidden: tuple, seeds, psi_sigma_rad=None) -> None:
    rows = []
    for seed in seeds:
        cols, truth = simulate_trailer(hidden=hidden, seed=int(seed), psi_sigma_rad=psi_sigma_rad)
        res = diagnose_trailer(cols["t"], cols["kappa"], cols["psi"], L1_m=1.25, L2_m=2.48, v_m_s=cols["v"],
                               alpha=0.01)
        step = next((s for s in res.steps if s.effect == "hitch_dynamics"), None)
        if step is None:
            print(f"  seed {seed}: no relaxation named ({res.selected})")
            continue
        lo, hi = step.ci["relaxation_m"]
        fit, true = step.params["relaxation_m"], truth["expected_fitted_relaxation_m"]
        rows.append((fit, lo, hi, true))
        print(f"  seed {seed}: fitted {fit:.4f} m, interval [{lo:.4f}, {hi:.4f}], truth {true:.4f}"
              f"{'' if lo <= true <= hi else '  OUTSIDE'}", flush=True)
    print(summary("+".join(hidden) or "nothing hidden", rows))


def main() -> None:
    args, seeds = arguments(__doc__)
    coverage((), seeds, args.psi_sigma)
    coverage(("hitch_dynamics",), seeds, args.psi_sigma)


if __name__ == "__main__":
    main()
