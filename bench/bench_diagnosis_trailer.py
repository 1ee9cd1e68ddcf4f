"""Trailer diagnosis: time for 10 minutes of 20 Hz data, and rates of misses and false discoveries.

Run by hand: ``.venv/bin/python bench/bench_diagnosis_trailer.py [--draws N] [--alpha A]``.

* timing: a 10-minute, 20 Hz record (12,001 samples) of the physical trailer
  (relaxation L2, the seed's profiles on the offline simulated trailer) plus
  one of the generator's records with an offset and a link-length error;
* rates: for each candidate effect hidden alone at ``U(0.2, 0.35)`` x the
  noise RMS (3-minute, 20 Hz records), the share of draws where it was not
  named, by a step or as explaining the same residual as one (miss), and the
  share where a step named another effect without naming the hidden one as
  ambiguous with it (false discovery); the null case counts any selection.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fakes.sim.trailer import record_commands
from fakes.sim.trailer_diagnosis_data import make_trailer_case
from station.analysis.diagnose.trailer import EFFECTS, diagnose_trailer


def named(res, effect: str) -> bool:
    return any(s.effect == effect or any(a["effect"] == effect for a in s.ambiguous_with) for s in res.steps)


def timing() -> None:
    rec = record_commands([("H", 0.2), ("C", 0.2), ("L", 0.2), ("H", -0.15), ("C", -0.2), ("L", 0.1),
                           ("H", 0.1), ("C", 0.1)], rate_hz=20.0, settle_s=12.0, duration_s=63.0,
                          noise=0.003, rng=np.random.default_rng())
    n = 12001
    t, k, p, v = (rec[c][:n] for c in ("t", "kappa", "psi", "v"))
    t0 = time.perf_counter()
    res = diagnose_trailer(t, k, p, L1_m=1.25, L2_m=2.48, v_m_s=v)
    dt = time.perf_counter() - t0
    print(f"physical trailer, {t.size} samples ({t[-1] - t[0]:.0f} s at 20 Hz): {dt:.2f} s; "
          f"selected {res.selected}; held-out {res.simulation_heldout_rms:.4f} -> {res.final_heldout_rms:.4f} rad")
    for s in res.steps:
        if s.effect == "hitch_dynamics":
            print(f"  relaxation {s.params['relaxation_m']:.4f} m, 95 % CI {s.ci['relaxation_m']}, "
                  f"the ideal trailer's L2 {s.details['relaxation_expected_m']:.4f} m "
                  f"(consistent: {s.details['ideal_trailer']})")
    rng = np.random.default_rng()
    d = make_trailer_case(["hitch_angle_offset", "link_lengths"], rng, duration_s=600.0, strength=(1.0, 1.0))
    t0 = time.perf_counter()
    res = diagnose_trailer(d["t"], d["kappa"], d["psi"], L1_m=1.25, L2_m=2.48, v_m_s=d["v"], sampling="point")
    print(f"generator record, {d['t'].size} samples: {time.perf_counter() - t0:.2f} s; selected {res.selected}")


def rates(draws: int, alpha: float, strength: tuple) -> None:
    rng = np.random.default_rng()
    print(f"{draws} draws per case, alpha {alpha} per round, 3-minute 20 Hz records, strength U{strength} x noise")
    for hidden in [None, *EFFECTS]:
        miss = false = 0
        t0 = time.perf_counter()
        for _ in range(draws):
            d = make_trailer_case([] if hidden is None else [hidden], rng, strength=strength)
            res = diagnose_trailer(d["t"], d["kappa"], d["psi"], L1_m=1.25, L2_m=2.48, v_m_s=d["v"], alpha=alpha,
                                   sampling="point")  # the generator's curvature is at each stamp
            if hidden is not None and not named(res, hidden):
                miss += 1
            if any(s.effect != hidden and not any(a["effect"] == hidden for a in s.ambiguous_with)
                   for s in res.steps):
                false += 1
        el = time.perf_counter() - t0
        print(f"  {hidden or 'nothing':<20s} misses {miss / draws:6.1%}   false discoveries {false / draws:6.1%}"
              f"   ({el / draws * 1e3:.0f} ms per draw)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--strength", type=float, nargs=2, default=(0.2, 0.35), metavar=("LO", "HI"),
                    help="effect RMS / noise RMS drawn uniformly in [LO, HI]")
    ap.add_argument("--no-timing", action="store_true")
    a = ap.parse_args()
    if not a.no_timing:
        timing()
    rates(a.draws, a.alpha, tuple(a.strength))


if __name__ == "__main__":
    main()
