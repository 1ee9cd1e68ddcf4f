"""How the fake controller's path following shows in the path figures, over seeds (run by hand).

For each seed: a simulated industrial arm (realistic errors, servo, stop scatter) runs ISO path programmes
through the fake controller's RAPID interpreter; the path analysis of the tracker's stream (in the base frame
by the true registration) is compared with the analysis of what the tracker reads of the true motion, noise
aside. Prints each figure, its truth, |difference| / U, and the share of draws inside U per figure.

    .venv/bin/python bench/bench_path_fakes.py --seeds 6 --speed 0.5
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.sim.clock import ManualClock  # noqa: E402
from fakes.sim.world import ISO_CUBE_CENTRE_MM, make_world  # noqa: E402
from station.analysis.path.analysis import analyze_path  # noqa: E402
from station.analysis.path.path_file import parse_paths  # noqa: E402
from station.programs.path_builders import iso_path_tests  # noqa: E402
from tests.path import fakerun  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--speed", type=float, default=0.5)
    ap.add_argument("--cycles", type=int, default=3)
    ap.add_argument("--kinds", default="line,rectangle_blend,circle_small")
    a = ap.parse_args()
    inside: dict[str, list[bool]] = {}
    t0 = time.time()
    for seed in range(a.seeds):
        world = make_world("industrial-3100", seed=seed, clock=ManualClock())
        for pt in iso_path_tests(world.robot, ISO_CUBE_CENTRE_MM, 400.0, cycles=a.cycles, speed_fracs=(a.speed,),
                                 kinds=tuple(a.kinds.split(","))):
            r = fakerun.run(world, pt)
            spec = parse_paths({"paths": [pt.path]})[0]
            ok = np.ones(r.t.size, bool)
            m = analyze_path(spec, r.t, r.measured, ok, noise_sd_mm=r.noise, trials=100, seed=seed)
            tr = analyze_path(spec, r.t, r.read_truth, ok, noise_sd_mm=1e-6, trials=10, seed=seed)
            for fig, v in m.figures.items():
                U = m.uncertainty[fig].U
                inside.setdefault(f"{pt.kind}.{fig}", []).append(abs(v - tr.figures[fig]) <= U)
                print(f"seed {seed} {pt.path['name']:<20} {fig:<11} {v:10.4f} truth {tr.figures[fig]:10.4f} "
                      f"U {U:.4f} |d|/U {abs(v - tr.figures[fig]) / U:.2f}")
    print("\nshare inside U:")
    for k, v in inside.items():
        print(f"  {k:<30} {np.mean(v):.2f} of {len(v)}")
    print(f"{time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
