"""Trailer diagnosis: the relaxation's 95 % interval with and without the curvature noise's unseen share, paired.

Run by hand: ``.venv/bin/python bench/bench_trailer_relaxation_paired.py [--draws N] [--seed S] [--psi-sigma RAD]``.

As ``bench_trailer_relaxation_coverage.py`` (same records, same truth), but each record is diagnosed twice:
with the covariance as the diagnosis states it, and with the robust window alone (the propagated share of the
curvature noise that the window cannot see, :mod:`station.analysis.diagnose.trailer_input_noise`, left out:
the interval before that share was added). One simulation serves both, so the comparison costs half.
"""

from __future__ import annotations

import station.analysis.diagnose.trailer as trailer
from bench_trailer_relaxation_coverage import arguments, summary
from fakes.sim.offline_files import simulate_trailer


def _interval(cols, window_only: bool):
    propagated = trailer.unseen_input_meat
    if window_only:
        trailer.unseen_input_meat = lambda *a, **k: 0.0
    try:
        res = trailer.diagnose_trailer(cols["t"], cols["kappa"], cols["psi"], L1_m=1.25, L2_m=2.48,
                                       v_m_s=cols["v"], alpha=0.01)
    finally:
        trailer.unseen_input_meat = propagated
    step = next((s for s in res.steps if s.effect == "hitch_dynamics"), None)
    return None if step is None else (step.params["relaxation_m"], *step.ci["relaxation_m"])


def main() -> None:
    args, seeds = arguments(__doc__)
    for hidden in ((), ("hitch_dynamics",)):
        rows = {"stated": [], "window alone": []}
        for seed in seeds:
            cols, truth = simulate_trailer(hidden=hidden, seed=seed, psi_sigma_rad=args.psi_sigma)
            true = truth["expected_fitted_relaxation_m"]
            for name, window_only in (("stated", False), ("window alone", True)):
                got = _interval(cols, window_only)
                if got is not None:
                    rows[name].append((*got, true))
            print(f"  seed {seed}: truth {true:.4f}; " + "; ".join(
                f"{name} [{r[-1][1]:.4f}, {r[-1][2]:.4f}]" for name, r in rows.items() if r), flush=True)
        for name, r in rows.items():
            print(summary(f"{'+'.join(hidden) or 'nothing hidden'}, {name}", r))


if __name__ == "__main__":
    main()
