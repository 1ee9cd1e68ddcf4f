"""`station calibrate arm`: kinematic calibration from an arm measurement CSV (seed 002).

The data (``q1..q6`` deg, ``x,y,z`` mm in the instrument's frame) are split
as the seed splits them (the first pose is the reference, the last poses are
held out), the model's identifiable parameters are identified on the
training poses, and the seed's figures are reported for both parts. Nothing
is written unless everything succeeded.
"""

from __future__ import annotations

import argparse
import json
import math
import sys


#: exit code of a fit that did not converge (the result is still printed and written, marked "converged": false)
EXIT_NOT_CONVERGED = 3


def _names(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def add_parser(csub) -> None:
    from app.commands.help_text import plain

    a = csub.add_parser("arm", help="kinematic parameters of an arm from measured tool points (seed 002)",
                        description=plain(__doc__.split("\n\n", 1)[1]),
                        epilog="exit codes: 0 done; 2 refused (bad input, or --strict and the poses cannot see a "
                               f"parameter); {EXIT_NOT_CONVERGED} the fit did not converge (results written, marked)")

    a.add_argument("--robot", required=True, help="library model (rb5-850, ur5e, ...) or a JSON model file")
    a.add_argument("--data", required=True, metavar="CSV", help="q1..q6 (deg), x,y,z (mm), optional t,temperature,load")
    a.add_argument("--method", default="distance", choices=("distance", "absolute"),
                   help="distance errors (no robot-to-instrument transform; seed eq. (9)-(16)) or absolute")
    a.add_argument("--test-fraction", type=float, default=None,
                   help="share of the poses held out for testing (default: the seed's 13 of 63)")
    a.add_argument("--split", default="tail", choices=("tail", "random", "spread"),
                   help="which poses are held out: the last ones (default), a random draw (--seed), or poses "
                        "spread over the workspace")
    a.add_argument("--seed", type=int, default=None, help="seed of --split random and --folds (printed)")
    a.add_argument("--folds", type=int, default=None, metavar="K",
                   help="also cross-validate: K folds, each held out once; mean and spread of the held-out error")
    a.add_argument("--strict", action="store_true",
                   help="refuse poses that cannot see a parameter well-spread poses would (default: fix it, say why)")
    a.add_argument("--fix", type=_names, default=[], metavar="NAMES",
                   help="parameters held at their start, comma-separated (a5,theta5,dTCP,...)")
    a.add_argument("--free", type=_names, default=[], metavar="NAMES",
                   help="parameters identified in preference to a redundant partner or a structural fix (dTCP,...)")
    a.add_argument("--max-iter", type=int, default=100, help="iteration limit of the solver (default 100)")
    a.add_argument("--ur-calibration", metavar="CONF", help="start from the UR model plus this calibration.conf")
    a.add_argument("--ur-deltas", metavar="OUT",
                   help="also write the result as UR calibration deltas (identifies a plain DH model: no beta)")
    a.add_argument("--json", metavar="OUT", help="write the result as JSON")
    a.add_argument("--report", metavar="OUT.html", help="write the HTML report")
    a.set_defaults(func=_arm)


def _arm(args: argparse.Namespace) -> int:
    import numpy as np

    from procedures.arm_calibration_report import build_report
    from station.analysis.arm.calibration import calibrate_arm, calibration_json, cross_validate
    from station.models.arm_model_file import read_ur_calibration, resolve_arm, ur_deltas, write_ur_calibration
    from station.readers.arm_csv import read_arm_csv
    from station.report import write_report

    from station.readers.out_files import check_outputs, write_output

    check_outputs(args, json="--json", report="--report", ur_deltas="--ur-deltas")
    arm = resolve_arm(args.robot)
    name, dh0, limits = arm.name, arm.dh, arm.joint_limits_rad
    if args.ur_calibration:
        dh0 = read_ur_calibration(args.ur_calibration, dh0)
    data = read_arm_csv(args.data)
    from station.analysis.arm.calibration import check_joint_limits
    from station.analysis.arm.screen import screen_arm_poses

    if limits is not None:
        check_joint_limits(np.radians(data.q_deg), np.asarray(limits, dtype=float))
    screen_arm_poses(dh0, np.radians(data.q_deg), data.xyz_mm, source=data.source, lines=data.lines)
    seed = args.seed
    if seed is None and (args.split == "random" or args.folds):
        seed = int(np.random.SeedSequence().entropy % (2 ** 31))
    q = np.radians(data.q_deg)
    cal = calibrate_arm(dh0, q, data.xyz_mm, method=args.method,
                        test_fraction=args.test_fraction, joint_limits_rad=limits,
                        use_beta=not args.ur_deltas, split_kind=args.split, seed=seed, strict=args.strict,
                        fix=args.fix, free=args.free, max_iter=args.max_iter)
    doc = calibration_json(cal, name=f"{name} calibrated", joint_limits_rad=limits)
    doc["split"] = {"kind": args.split if args.test_fraction != 0 else "none", "seed": seed}
    if args.folds:
        doc["cross_validation"] = cross_validate(dh0, q, data.xyz_mm, folds=args.folds, seed=seed,
                                                method=args.method, joint_limits_rad=limits,
                                                use_beta=not args.ur_deltas, strict=args.strict, fix=args.fix,
                                                free=args.free, max_iter=args.max_iter)
    deltas = ur_deltas(cal.dh, dh0) if args.ur_deltas else None
    report = build_report(cal, title=f"Kinematic calibration of {name}",
                          facts={"data": str(args.data), "robot": str(args.robot)}) if args.report else None
    # everything computed: now write
    if args.json:
        write_output(args.json, json.dumps(doc, indent=2), "--json")
    if deltas is not None:
        write_ur_calibration(args.ur_deltas, deltas)
    if report is not None:
        write_report(report, args.report, "--report")
    _print(doc)
    converged = doc["converged"] and doc.get("cross_validation", {}).get("all_converged", True)
    if not converged:
        print(f"error: the fit did not converge ({doc['message']}); exit code {EXIT_NOT_CONVERGED}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _print(doc: dict) -> None:
    tr, te = doc["train"], doc["test"]

    def red(d):
        return 100.0 * (1.0 - d["mean_abs_after_mm"] / d["mean_abs_before_mm"]) if d["mean_abs_before_mm"] else math.nan

    sp = doc.get("split", {})
    seed = f", seed {sp['seed']}" if sp.get("seed") is not None else ""
    n_held = len(doc.get("held", {}))
    print(f"method {doc['method']}: {len(doc['identified'])} parameters identified ({n_held} of them held at the "
          f"start by the prior), {len(doc['fixed'])} fixed, "
          f"condition number {doc['condition_number']:.1f}, {doc['iterations']} iterations ({doc['message']}); "
          f"split {sp.get('kind', 'tail')}{seed}")
    print(f"{'':<8}{'mean before':>13}{'mean after':>12}{'max before':>12}{'max after':>11}{'less':>8}")
    for label, d in (("train", tr), ("test", te)):
        if d is None:
            continue
        print(f"{label:<8}{d['mean_abs_before_mm']:>13.4f}{d['mean_abs_after_mm']:>12.4f}"
              f"{d['max_abs_before_mm']:>12.4f}{d['max_abs_after_mm']:>11.4f}{red(d):>7.1f}%")
    print(f"(mm; {doc['errors_are']})")
    for nm, why in doc["fixed"].items():
        if why.startswith("fixed at its start: these poses cannot see") or why.startswith("fixed as asked"):
            print(f"fixed: {nm}: {why}")
    for nm, why in doc.get("held", {}).items():
        print(f"held: {nm}: {why}")
    for note in doc.get("heldout_coverage", []):
        print(f"held-out poses: {note}")
    for w in doc.get("warnings", []):
        print(f"warning: {w['message']}")
    alt = doc.get("alternative")
    if alt:
        te_alt = f", test {alt['test_mean_after_mm']:.4f} mm" if "test_mean_after_mm" in alt else ""
        print(f"alternative: with {', '.join(alt['fix'])} fixed: train {alt['train_mean_after_mm']:.4f} mm{te_alt} "
              f"(rerun with --fix {','.join(alt['fix'])})")
    for w in doc.get("warnings", []):
        if w["kind"] == "correlated" and not (alt and set(w["parameters"]) & set(alt["fix"])):
            print(f"alternative: --fix {w['parameters'][1]} (or {w['parameters'][0]}) if its value matters on its own")
    cv = doc.get("cross_validation")
    if cv:
        print(f"cross-validation ({cv['k']} folds, seed {cv['seed']}): held-out mean {cv['mean_mm']:.4f} mm, "
              f"sd over folds {cv['sd_mm']:.4f} mm")
        for f in cv["folds"]:
            for note in f["coverage"]:
                print(f"  fold {f['fold']}: {note}")
