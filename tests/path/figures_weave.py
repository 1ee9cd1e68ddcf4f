"""By hand: the weave's and the reorientation's figures on the simulated cell of the industrial arm, draw by draw.

    .venv/bin/python -m tests.path.figures_weave SEED DRAWS

Each draw: a world of its own seed, a weave of random amplitude (1-3 mm), frequency (0.6-1.5 Hz), base speed
(8-15 mm/s) and vertices a period (4, 8, 12), 3 cycles, and the line at 50 % with and without a random turn of
the tool (10-30 deg either side); for each, the figures of what the controller commanded, of what the tracker
reads of the true arm (noise aside) and of the tracker's stream, with the stream's U.
"""

from __future__ import annotations

import sys

import numpy as np

from fakes.sim.clock import ManualClock
from fakes.sim.world import ISO_CUBE_CENTRE_MM, make_world
from station.analysis.path.analysis import analyze_path
from station.analysis.path.path_file import parse_paths
from station.programs.path_builders import iso_path_tests
from tests.path import fakerun


def _figures(world, pt, seed) -> str:
    r = fakerun.run(world, pt)
    spec = parse_paths({"paths": [pt.path]})[0]
    ok = np.ones(r.t.size, bool)
    out = []
    for label, xyz, noise in (("cmd", r.commanded, 1e-6), ("truth", r.read_truth, 1e-6),
                              ("stream", r.measured, r.noise)):
        res = analyze_path(spec, r.t, xyz, ok, noise_sd_mm=noise, trials=60, seed=seed)
        figs = " ".join(f"{k} {v:+.4f}" + (f" (U {res.uncertainty[k].U:.4f})" if label == "stream" else "")
                        for k, v in res.figures.items())
        out.append(f"{label} [{res.n_cycles} cycles] {figs}")
    return "; ".join(out)


def main(seed: int, draws: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(draws):  # loop over draws
        s = int(rng.integers(2**31))
        wv = {"weave_amplitude_mm": float(rng.uniform(1, 3)), "weave_frequency_Hz": float(rng.uniform(0.6, 1.5)),
              "weave_speed_mm_s": float(rng.uniform(8, 15)), "weave_periods": 6,
              "weave_points_per_period": int(rng.choice([4, 8, 12]))}
        turn = float(rng.uniform(10.0, 30.0))
        world = make_world("industrial-3100", seed=s, clock=ManualClock())
        tests = iso_path_tests(world.robot, ISO_CUBE_CENTRE_MM, 400.0, cycles=3, speed_fracs=(0.5,),
                               kinds=("weaving", "reorientation", "line"), weave=wv, reorient_deg=turn)
        print(f"world {s}: weave {wv['weave_amplitude_mm']:.2f} mm {wv['weave_frequency_Hz']:.2f} Hz "
              f"{wv['weave_speed_mm_s']:.1f} mm/s N {wv['weave_points_per_period']}: {_figures(world, tests[0], s)}")
        print(f"world {s}: turn +/-{turn:.1f} deg: {_figures(world, tests[1], s)}")
        print(f"world {s}: line, no turn: {_figures(world, tests[2], s)}", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]))
