"""`station diagnose arm`: where the station's arm model disagrees with measured data, and why (issue 13).

``station diagnose arm --robot NAME|FILE --data A.csv [--json OUT] [--report OUT.html] [--model-out M.json]``
    The arm CSV (``q1..q6`` deg, ``x,y,z`` mm in the instrument frame,
    optional ``t``, ``temperature``, ``load``) is predicted by the station's
    model and split into training and held-out poses spanning the
    workspace. The diagnosis starts from a geometric calibration; the named
    effects are then chosen one by one on the training poses alone (a
    significance test against the noise and a cross-validation inside the
    training poses: nested), and the held-out poses report the gain. When
    geometry cannot be tested nothing else is named. Backlash needs the
    order of motion: a ``t`` column or ``--rows-in-motion-order``; without
    them the answer does not depend on the rows' order. ``--json`` keys:
    ``steps`` (each ``effect``, ``joint``, ``params``, ``ci``,
    ``heldout_rms_before``, ``heldout_rms_after``, ``gain``,
    ``cv_rms_before``, ``cv_rms_after``, ``statistic``, ``threshold``,
    ``ambiguous_with``: candidates of the same residual, with the evidence;
    ``told_apart_from``: those an encompassing test ruled out),
    ``simulation_heldout_rms``, ``final_heldout_rms``,
    ``noise_floor`` (mm) and ``noise_floor_source``, ``selection``,
    ``geometry``, ``stop_reason``, ``remaining_structure``,
    ``not_testable``, ``rejected``, ``fits`` (each fit's convergence),
    ``geometry.cross_validation`` (the calibration against the nominal
    model on poses each fold held out; on one-joint sweeps the folds keep
    every sweep's ends in training and say the test is interpolation only,
    with the sweep ends' extrapolation figure beside it), ``written_model``
    (whether the effects were written: only when, added to the calibration
    of the training poses, they predict the held-out poses no worse than
    the calibration alone; ``geometry``: re-identified with the effects on
    spread poses, held at the calibration on one-joint sweeps),
    ``extended_model`` (the model file ``--model-out`` writes: the chosen
    effects refitted on every pose, read by ``station predict arm`` and
    ``station compensate arm``). Exit code 3: a fit did not converge (the
    results are still written, marked). Nothing is written unless
    everything succeeded.

``station diagnose trailer --l1 L1 --l2 L2 --data T.csv [--sampling S] [--json OUT] [--report OUT.html]``
    The trailer CSV (``t,kappa,psi``, optional ``v``, ``kappa_cmd``) is
    predicted by the patent's static model (seed 003 eq. (23)) from the
    nominal link lengths (m), split by time blocks spanning the record, and
    ``link_lengths``, ``hitch_angle_offset``, ``curvature_gain`` and
    ``hitch_dynamics`` are selected one by one while a test against the
    noise finds structure (see :mod:`station.analysis.diagnose.trailer`).
    Curvature and speed are averages over the interval ending at ``t``, as
    odometry reports them (``--sampling point`` for instantaneous values).
    An ideal trailer relaxes over L2 (eq. (D)), which the static model
    leaves out: a ``hitch_dynamics`` step consistent with L2 says so
    (``details.ideal_trailer``) and is no effect beyond the ideal trailer.
    Same JSON keys as the arm; RMS and ``noise_floor`` in rad of the joint
    angle, ``extended_model`` the fitted lengths, offset, gain and relaxation.
"""

from __future__ import annotations

import argparse
import json
import math


def register(sub: argparse._SubParsersAction) -> None:
    from app.commands.help_text import plain

    p = sub.add_parser("diagnose", help="find, name and fix what the station's model gets wrong")
    dsub = p.add_subparsers(dest="diagnose_cmd", metavar="WHAT")
    a = dsub.add_parser("arm", help="arm model against measured tool points",
                        description=plain(__doc__.split("\n\n")[1]))
    a.add_argument("--robot", required=True, help="library model (industrial-3100, ur5e, ...) or a JSON model file")
    a.add_argument("--data", required=True, metavar="CSV", help="q1..q6 (deg), x,y,z (mm), optional t,temperature,load")
    a.add_argument("--heldout-fraction", type=float, default=0.25, help="share of poses held out (default 0.25)")
    a.add_argument("--alpha", type=float, default=0.05, help="false-discovery rate of each selection round")
    a.add_argument("--rows-in-motion-order", action="store_true",
                   help="the rows are in the order the arm visited them (backlash testable without a t column)")
    a.add_argument("--folds", type=int, default=5, help="folds of the cross-validation that chooses the effects")
    a.add_argument("--seed", type=int, default=0, help="seed of the held-out split and the folds (default 0)")
    a.add_argument("--json", metavar="OUT", help="write the result as JSON")
    a.add_argument("--report", metavar="OUT.html", help="write the HTML report")
    a.add_argument("--model-out", metavar="M.json",
                   help="write the extended model (table, base, named effects) for station predict/compensate")
    a.set_defaults(func=_arm)
    t = dsub.add_parser("trailer", help="the static trailer model (seed 003) against a measured record",
                        description=plain(__doc__.split("\n\n")[2]))
    t.add_argument("--l1", required=True, type=float, metavar="L1", help="nominal front link length, m")
    t.add_argument("--l2", required=True, type=float, metavar="L2", help="nominal rear link length, m")
    t.add_argument("--data", required=True, metavar="CSV", help="t,kappa,psi (s, 1/m, rad), optional v,kappa_cmd")
    t.add_argument("--sampling", default="interval", choices=("interval", "point"),
                   help="curvature/speed rows are averages over the interval ending at t "
                        "(odometry, default) or instantaneous values")
    t.add_argument("--heldout-fraction", type=float, default=0.25, help="share of the record held out (default 0.25)")
    t.add_argument("--alpha", type=float, default=0.05, help="false-discovery rate of each selection round")
    t.add_argument("--json", metavar="OUT", help="write the result as JSON")
    t.add_argument("--report", metavar="OUT.html", help="write the HTML report")
    t.set_defaults(func=_trailer)


#: exit code when a fit of the diagnosis did not converge
EXIT_NOT_CONVERGED = 3


def _arm(args: argparse.Namespace) -> int:
    import sys

    import numpy as np

    from procedures.diagnosis_report import build_report
    from station.analysis.diagnose import diagnose_arm
    from station.models.arm_model_file import resolve_arm
    from station.readers.arm_csv import read_arm_csv
    from station.report import write_report

    from station.readers.out_files import check_outputs, write_output

    check_outputs(args, json="--json", report="--report", model_out="--model-out")
    arm = resolve_arm(args.robot)
    data = read_arm_csv(args.data)
    from station.analysis.arm.screen import screen_arm_poses

    screen_arm_poses(arm.dh, np.radians(data.q_deg), data.xyz_mm, source=data.source, lines=data.lines)
    res = diagnose_arm(arm.dh, np.radians(data.q_deg), data.xyz_mm, t_s=data.t_s, temperature_c=data.temperature_c,
                       load_kg=data.load_kg, robot=arm.spec, heldout_fraction=args.heldout_fraction,
                       alpha=args.alpha, rows_in_motion_order=args.rows_in_motion_order, folds=args.folds,
                       seed=args.seed)
    doc = res.to_json()
    doc["robot"], doc["data"] = arm.name, str(args.data)
    gravity = arm.spec.name if arm.spec is not None else None
    doc["extended_model"] = res.extended_model(name=f"{arm.name} diagnosed", gravity_model=gravity,
                                               joint_limits_rad=arm.joint_limits_rad)
    report = build_report(res, title=f"Diagnosis of {arm.name}", facts={"data": str(args.data)}) if args.report else None
    if args.json:
        write_output(args.json, json.dumps(doc, indent=2), "--json")
    if args.model_out:
        write_output(args.model_out, json.dumps(doc["extended_model"], indent=2), "--model-out")
    if report is not None:
        write_report(report, args.report, "--report")
    _print(doc)
    if not doc["converged"]:
        bad = "; ".join(f"{f['fit']}: {f['message']}" for f in doc["fits"] if not f["converged"])
        print(f"error: a fit did not converge ({bad}); exit code {EXIT_NOT_CONVERGED}", file=sys.stderr)
        return EXIT_NOT_CONVERGED
    return 0


def _trailer(args: argparse.Namespace) -> int:
    from procedures.diagnosis_report import build_trailer_report
    from station.analysis.diagnose.trailer import diagnose_trailer
    from station.readers.trailer_csv import read_trailer_csv
    from station.report import write_report

    from station.readers.out_files import check_outputs, write_output

    check_outputs(args, json="--json", report="--report")
    data = read_trailer_csv(args.data)
    res = diagnose_trailer(data["t"], data["kappa"], data["psi"], L1_m=args.l1, L2_m=args.l2,
                           v_m_s=data.get("v"), kappa_cmd=data.get("kappa_cmd"), sampling=args.sampling,
                           heldout_fraction=args.heldout_fraction, alpha=args.alpha)
    doc = res.to_json()
    doc["nominal"], doc["data"] = {"L1_m": args.l1, "L2_m": args.l2}, str(args.data)
    report = build_trailer_report(res, title="Diagnosis of the trailer model",
                                  facts={"data": str(args.data)}) if args.report else None
    if args.json:
        write_output(args.json, json.dumps(doc, indent=2), "--json")
    if report is not None:
        write_report(report, args.report, "--report")
    _print_trailer(doc)
    return 0


def _print_trailer(doc: dict) -> None:
    n = doc["n_samples"]
    print(f"static model (seed 003 eq. (23)) held-out RMS {doc['simulation_heldout_rms']:.5f} rad "
          f"({n['train']} training, {n['heldout']} held-out samples)")
    for k, s in enumerate(doc["steps"], 1):
        par = ", ".join(f"{name} {val:.5g} [{s['ci'][name][0]:.5g}, {s['ci'][name][1]:.5g}]"
                        for name, val in s["params"].items())
        amb = "".join(f"; same residual as {a['effect']}" for a in s["ambiguous_with"])
        print(f"{k:>2}. {s['effect']} ({par}): held-out {s['heldout_rms_before']:.5f} -> "
              f"{s['heldout_rms_after']:.5f} rad ({100 * s['gain']:.1f} %), W/k {s['statistic']:.1f} > "
              f"{s['threshold']:.1f}{amb}")
        ideal = s.get("details", {}).get("ideal_trailer")
        if s["effect"] == "hitch_dynamics" and ideal is not None:
            L2 = s["details"]["relaxation_expected_m"]
            print(f"    {'consistent with' if ideal else 'unlike'} the ideal trailer's relaxation over L2 = {L2:.4f} m "
                  f"(eq. (D)): " + ("its own dynamics, which the static model of eq. (23) leaves out; not an effect "
                                    "beyond the ideal trailer" if ideal else "the hitch's own dynamics"))
    if not doc["steps"]:
        print("nothing significant: the static model explains the data to the noise")
    print(f"extended model held-out RMS {doc['final_heldout_rms']:.5f} rad ({doc['gain_percent']:.1f} % less); "
          f"noise floor {doc['noise_floor']:.5f} rad")
    left = [c for c in doc["remaining_structure"] if c.get("significant")]
    if left:
        print("significant but not improving held-out data: " + ", ".join(c["candidate"] for c in left))
    for key, why in doc["not_testable"].items():
        print(f"not testable: {key}: {why}")


def _mm(v) -> str:
    return "n/a" if v is None else f"{v:.4f} mm"


def _print_geometry_cv(cv: dict) -> None:
    """How geometry was judged: the calibration against the nominal model on poses the folds held out."""
    if not cv:
        return
    print(f"geometry cross-validated on {cv['poses']}: the calibration fitted without each of {cv['folds']} folds "
          f"predicts its {cv['held_out_poses']} poses at {_mm(cv['rms_geometry_mm'])} RMS, the nominal model at "
          f"{_mm(cv['rms_nominal_mm'])}")
    if cv["kind"] == "interpolation":
        print(f"  {cv['statement']}")
    ex = cv.get("extrapolation")
    if ex:
        print(f"  extrapolation (the sweeps' ends held out, {ex['held_out_poses']} poses; reported, not judged): "
              f"calibration {_mm(ex['rms_geometry_mm'])}, nominal {_mm(ex['rms_nominal_mm'])} RMS")


def _print(doc: dict) -> None:
    print(f"simulation held-out RMS {doc['simulation_heldout_rms']:.4f} mm "
          f"({doc['n_poses']['train']} training, {doc['n_poses']['heldout']} held-out poses)")
    print(f"selection: {doc['selection']}")
    print(f"row order: {doc['row_order']}")
    for k, s in enumerate(doc["steps"], 1):
        joint = f" joint {s['joint']}" if s["joint"] else ""
        amb = "".join(f"; same residual as {a['effect']}" + (f" joint {a['joint']}" if a["joint"] else "")
                      for a in s["ambiguous_with"])
        amb += "".join(f"; told apart from {a['effect']}" + (f" joint {a['joint']}" if a["joint"] else "")
                       for a in s.get("told_apart_from", []))
        print(f"{k:>2}. {s['effect']}{joint}: held-out {s['heldout_rms_before']:.4f} -> {s['heldout_rms_after']:.4f} mm "
              f"({100 * s['gain']:.1f} %), W/k {s['statistic']:.1f} > {s['threshold']:.1f}{amb}")
    if not doc["steps"]:
        print("nothing significant: the model explains the data to the noise")
    g = doc["gain_percent"]
    print(f"extended model held-out RMS {doc['final_heldout_rms']:.4f} mm ({g:.1f} % less); "
          f"noise floor {doc['noise_floor']:.4f} mm (from {doc['noise_floor_source']})")
    if doc.get("stop_reason"):
        print(f"stopped: {doc['stop_reason']}")
    _print_geometry_cv(doc.get("geometry", {}).get("cross_validation") or {})
    for w in doc.get("geometry", {}).get("warnings", []):
        print(f"warning (geometry): {w['message']}")
    if doc.get("written_model"):
        print(f"model written: {doc['written_model']['note']}")
    left = [c for c in doc["remaining_structure"] if c.get("significant")]
    if left:
        print("significant but not lowering the cross-validated error of the training poses: "
              + ", ".join(c["candidate"] for c in left))
    for key, why in doc.get("rejected", {}).items():
        print(f"not named: {key}: {why}")
    for key, why in doc["not_testable"].items():
        print(f"not testable: {key}: {why}")
    if not math.isfinite(doc["final_heldout_rms"]):
        print("warning: non-finite held-out RMS")
