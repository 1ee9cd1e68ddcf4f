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
from pathlib import Path


def add_parser(csub) -> None:
    from app.commands.help_text import plain

    a = csub.add_parser("arm", help="kinematic parameters of an arm from measured tool points (seed 002)",
                        description=plain(__doc__.split("\n\n", 1)[1]))
    a.add_argument("--robot", required=True, help="library model (rb5-850, ur5e, ...) or a JSON model file")
    a.add_argument("--data", required=True, metavar="CSV", help="q1..q6 (deg), x,y,z (mm), optional t,temperature,load")
    a.add_argument("--method", default="distance", choices=("distance", "absolute"),
                   help="distance errors (no robot-to-instrument transform; seed eq. (9)-(16)) or absolute")
    a.add_argument("--test-fraction", type=float, default=None,
                   help="share of the poses after the first held out for testing (default: the seed's 13 of 63)")
    a.add_argument("--ur-calibration", metavar="CONF", help="start from the UR model plus this calibration.conf")
    a.add_argument("--ur-deltas", metavar="OUT",
                   help="also write the result as UR calibration deltas (identifies a plain DH model: no beta)")
    a.add_argument("--json", metavar="OUT", help="write the result as JSON")
    a.add_argument("--report", metavar="OUT.html", help="write the HTML report")
    a.set_defaults(func=_arm)


def _arm(args: argparse.Namespace) -> int:
    import numpy as np

    from procedures.arm_calibration_report import build_report
    from station.analysis.arm.calibration import calibrate_arm, calibration_json
    from station.models.arm_model_file import load_arm, read_ur_calibration, ur_deltas, write_ur_calibration
    from station.readers.arm_csv import read_arm_csv
    from station.report import write_report

    name, dh0, limits, _ = load_arm(args.robot)
    if args.ur_calibration:
        dh0 = read_ur_calibration(args.ur_calibration, dh0)
    data = read_arm_csv(args.data)
    from station.analysis.arm.calibration import check_joint_limits
    from station.analysis.arm.screen import screen_arm_poses

    if limits is not None:
        check_joint_limits(np.radians(data.q_deg), np.asarray(limits, dtype=float))
    screen_arm_poses(dh0, np.radians(data.q_deg), data.xyz_mm, source=data.source, lines=data.lines)
    cal = calibrate_arm(dh0, np.radians(data.q_deg), data.xyz_mm, method=args.method,
                        test_fraction=args.test_fraction, joint_limits_rad=limits,
                        use_beta=not args.ur_deltas)
    doc = calibration_json(cal, name=f"{name} calibrated", joint_limits_rad=limits)
    deltas = ur_deltas(cal.dh, dh0) if args.ur_deltas else None
    report = build_report(cal, title=f"Kinematic calibration of {name}",
                          facts={"data": str(args.data), "robot": str(args.robot)}) if args.report else None
    # everything computed: now write
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=2), encoding="utf-8")
    if deltas is not None:
        write_ur_calibration(args.ur_deltas, deltas)
    if report is not None:
        write_report(report, args.report)
    _print(doc)
    return 0


def _print(doc: dict) -> None:
    tr, te = doc["train"], doc["test"]

    def red(d):
        return 100.0 * (1.0 - d["mean_abs_after_mm"] / d["mean_abs_before_mm"]) if d["mean_abs_before_mm"] else math.nan

    print(f"method {doc['method']}: {len(doc['identified'])} parameters identified, {len(doc['fixed'])} fixed, "
          f"condition number {doc['condition_number']:.1f}, {doc['iterations']} iterations ({doc['message']})")
    print(f"{'':<8}{'mean before':>13}{'mean after':>12}{'max before':>12}{'max after':>11}{'less':>8}")
    for label, d in (("train", tr), ("test", te)):
        if d is None:
            continue
        print(f"{label:<8}{d['mean_abs_before_mm']:>13.4f}{d['mean_abs_after_mm']:>12.4f}"
              f"{d['max_abs_before_mm']:>12.4f}{d['max_abs_after_mm']:>11.4f}{red(d):>7.1f}%")
    print(f"(mm; {doc['errors_are']})")
