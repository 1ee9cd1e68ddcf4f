"""Benchmark: does the diagnosis's extended model reach unseen poses on lab-shaped sets? (issue 43 item 3)

Run by hand: ``.venv/bin/python bench/bench_diagnosis_lab.py [--draws N] [--seed S] [--none K]``.

Each draw (fakes/sim/real_like_arms.py ``lab_shaped``): an RB5-850 as built,
40 spread poses with 0.05 mm noise, one hidden effect drawn from joint
compliance or encoder eccentricity on J2 or J3, 120 unseen poses. Per draw:
the mean 3-D error on the unseen poses of the model the diagnosis writes
(fitted on the 40), of a plain full DH + Hayati fit of the 40 (scipy
MINPACK), and of an oracle that knows the hidden effect's form (the
calibration's geometry and the true joint-error column fitted together on
the 40); what was named. ``--none K`` adds K draws without a hidden effect
(nothing but geometry may be named there).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.sim.real_like_arms import LAB_EFFECTS, lab_shaped  # noqa: E402
from station.analysis.diagnose import diagnose_arm  # noqa: E402
from station.analysis.diagnose.arm import _geometric_term, _with_geometry  # noqa: E402
from station.analysis.diagnose.arm_fit import fit_report, initial_state, predict  # noqa: E402
from station.analysis.diagnose.terms import Term  # noqa: E402
from station.models.arm_extended import ExtendedArm, terms_from_json  # noqa: E402
from station.models.arm_model_file import model_from_json  # noqa: E402
from tests.calibration.reference_fit import plain_fit, position_error  # noqa: E402


def written_error(res, d) -> float:
    doc = res.extended_model()
    dh_e, B_e, _ = model_from_json(doc)
    arm = ExtendedArm("x", dh_e, B_e, d.robot.joint_limits_rad, terms_from_json(doc["effects"], "m"),
                      gravity_model=d.robot)
    p = arm.predict(d.q_unseen_rad)
    return float(np.linalg.norm(p - d.xyz_unseen_mm, axis=1).mean())


def oracle_error(d) -> float:
    """The calibration's geometry with the true effect's column, fitted together on the measured poses."""
    q = np.vstack([d.q_rad, d.q_unseen_rad])
    meas = np.vstack([d.xyz_mm, d.xyz_unseen_mm])
    tr, te = np.arange(d.q_rad.shape[0]), d.q_rad.shape[0] + np.arange(d.q_unseen_rad.shape[0])
    st = initial_state(d.dh_nominal, q, meas, tr)
    geo, res, _ = _geometric_term(d.dh_nominal, q, meas, tr)
    st = _with_geometry(st, geo, res, d.dh_nominal)
    effect, j = d.hidden[0]
    st = st.with_term(Term(effect, j, "joint", ("x",), d.effect_column[:, None]))
    st, _, _ = fit_report(st, q, meas, tr)
    return float(np.linalg.norm(predict(st, q, te) - meas[te], axis=1).mean())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=16)
    ap.add_argument("--none", type=int, default=4)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--strength", type=float, nargs=2, default=(1.2, 2.0),
                    help="the hidden effect's tool-point RMS, a range in times the noise's 3-D RMS")
    args = ap.parse_args()
    seed = int(np.random.SeedSequence().entropy % (2 ** 31)) if args.seed is None else args.seed
    rng = np.random.default_rng(seed)
    print(f"seed {seed}: RB5-850 as built, 40 poses, 0.05 mm noise, 120 unseen poses, hidden effect "
          f"U{tuple(args.strength)} x the noise (mean 3-D error, mm)")
    print(f"{'hidden':<26}{'written':>8}{'plain':>8}{'oracle':>8}{'w/plain':>8}{'o/plain':>8}  named")
    ratios, oratios, named_ok = [], [], 0
    t0 = time.perf_counter()
    for k in range(args.draws + args.none):
        hidden = LAB_EFFECTS[int(rng.integers(len(LAB_EFFECTS)))] if k < args.draws else None
        d = lab_shaped(rng, hidden, strength=tuple(args.strength))
        res = diagnose_arm(d.dh_nominal, d.q_rad, d.xyz_mm, robot=d.robot)
        w = written_error(res, d)
        dh, B = plain_fit(d.dh_nominal, d.q_rad, d.xyz_mm)
        pl = float(position_error(dh, B, d.q_unseen_rad, d.xyz_unseen_mm).mean())
        names = [f"{e}[{j}]" for e, j in res.selected if e != "geometric"]
        amb = [f"{a['effect']}[{a['joint']}]" for s in res.steps for a in s.ambiguous_with]
        if hidden is not None:
            o = oracle_error(d)
            ratios.append(w / pl)
            oratios.append(o / pl)
            named_ok += f"{hidden[0]}[{hidden[1]}]" in names + amb
            label = f"{hidden[0]}[{hidden[1]}]"
        else:
            o = float("nan")
            label = "none"
        print(f"{label:<26}{w:8.4f}{pl:8.4f}{o:8.4f}{w / pl:8.3f}{o / pl:8.3f}  {', '.join(names) or '-'}"
              + (f" (or {', '.join(amb)})" if amb else ""), flush=True)
    if ratios:
        print(f"written/plain: mean {np.mean(ratios):.3f}, max {np.max(ratios):.3f}; oracle/plain: mean "
              f"{np.mean(oratios):.3f}, max {np.max(oratios):.3f}; named with its joint {named_ok}/{len(ratios)}; "
              f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
