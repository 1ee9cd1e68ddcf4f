"""`station diagnose motion`: where the station's motion model disagrees with a measured stream near the stops.

``station diagnose motion --stream S --poses P [--program F] [--rate-hz R] [--hold H] [--json D] ...``
    The stream (any format ``station analyze`` reads) is cut into moves
    between the poses of P (``name,x,y,z``, the stream's frame) and their
    approaches along the travel. The baseline (the command's deceleration
    and jerk time, a second-order position loop's frequency and damping) is
    refitted on training moves; ``creep``, ``structural_mode`` and
    ``tracker_drift`` are then tested one at a time and named only when they
    also lower the error of held-out moves (the JSON's ``heldout_moves``).
    The JSON has the core of ``diagnose arm`` (``steps``,
    ``simulation_heldout_rms``, ``final_heldout_rms``, ``gain``,
    ``noise_floor``, ``not_testable``; mm along the travel) and per held-out
    pose POS, time to band (0.1 -> 0.02 mm), PST and MPT, measured,
    simulated (baseline) and extended. The clock is checked as
    ``station analyze`` checks it (the program's ``dwell_s`` lets the dwells
    give the rate); a clock that fails states no time figure and writes no
    model. ``--model-out`` writes the extended motion model for
    ``station simulate iso9283 --motion-model`` (``--model-basis supported``:
    the training-supported one, its unconfirmed effects listed). ``--hold`` takes a held-pose
    record of the same tracker: its noise is fitted (white, wander and its
    time constant, as ``station analyze hold --noise-out``) and the wander
    sets the drift the tracker can put into an approach window (JSON
    ``hold_drift``); where that is below what the held-out test can see, the
    ``tracker_drift`` candidate is not tested (``not_testable`` says why: a
    drift in the stream is then not the tracker's).
"""

from __future__ import annotations

import argparse
import json
import sys


def register_motion(dsub: argparse._SubParsersAction) -> None:
    from app.commands.help_text import plain

    m = dsub.add_parser("motion", help="motion model (profile, loop, creep, mode, drift) against a measured stream",
                        description=plain(__doc__.split("\n\n")[1]))
    m.add_argument("--stream", required=True, metavar="S", help="tracker stream (csv, SpatialAnalyzer export, ...)")
    m.add_argument("--poses", required=True, metavar="P", help="name,x,y,z (mm) of the commanded poses")
    m.add_argument("--program", metavar="FILE", help="the lab's program, as simulate iso9283 --program reads it (its "
                                                     "dwell_s, and rate_hz when stated, check the clock)")
    m.add_argument("--rate-hz", type=float, metavar="R", help="the tracker's sampling rate (overrides the stamps)")
    m.add_argument("--hold", metavar="H", help="a held-pose stream of the same tracker: its fitted wander sets the "
                                              "drift the tracker can show over an approach window; tracker_drift "
                                              "is tested only when that is visible")
    m.add_argument("--alpha", type=float, default=0.01, help="false-discovery rate of each test (default 0.01)")
    m.add_argument("--json", metavar="D", help="write the result as JSON")
    m.add_argument("--report", metavar="R.html", help="write the HTML report (approach curves of held-out moves)")
    m.add_argument("--model-out", metavar="M.json", help="write the extended motion model")
    m.add_argument("--model-basis", choices=("named", "supported"), default="named",
                   help="what --model-out writes: the named model (default: effects confirmed on the held-out "
                        "moves), or the training-supported one (those extended by the effects the training moves' "
                        "F test supports, not confirmed on held-out moves: a dry run's best guess where few moves "
                        "are held out; the file lists them under not_confirmed)")
    m.set_defaults(func=_motion)


def _hold_figures(path, rate_hz) -> dict:
    """The tracker's noise fitted from a held pose (eq. (N2): white, wander sd and time constant), mm and s."""
    from app.commands.analyze_inputs import load_stream
    from station.analysis.iso9283.tracker_noise_fit import fit_tracker_noise
    from station.errors import DataError

    si = load_stream(path, rate_hz=rate_hz, command="diagnose motion --hold")
    if si.refused:
        raise DataError(f"--hold {path}: the wander's time constant would rest on a clock that failed its check "
                        f"({si.refused}); give --rate-hz")
    ok = si.points.valid if si.points.valid is not None else slice(None)
    fit = fit_tracker_noise(si.t_s[ok], si.points.xyz_mm[ok])
    return {"source": str(path), "white_mm": fit.white_um / 1000.0, "wander_mm": fit.wander_um / 1000.0,
            "wander_tau_s": fit.wander_tau_s}


def _motion(args: argparse.Namespace) -> int:
    from app.commands.analyze_inputs import load_stream
    from procedures.motion_diagnosis_report import build_motion_report
    from station.analysis.motion.diagnose import diagnose_motion
    from station.readers.motion_program import read_motion_program
    from station.readers.out_files import check_outputs, write_output
    from station.readers.stream_csv import read_poses_csv
    from station.report import write_report

    check_outputs(args, json="--json", report="--report", model_out="--model-out")
    program = read_motion_program(args.program) if args.program else None
    rate = args.rate_hz if args.rate_hz is not None else (
        program.rate_hz if program is not None and program.rate_stated else None)
    names, poses, _ = read_poses_csv(args.poses)
    si = load_stream(args.stream, rate_hz=rate, command="diagnose motion",
                     wait_s=None if program is None else program.dwell_s)
    hold = _hold_figures(args.hold, rate) if args.hold else None
    ps = si.points
    res = diagnose_motion(si.t_s, ps.xyz_mm, poses, names, valid=ps.valid, alpha=args.alpha,
                          time_refused=si.refused, hold=hold)
    doc = res.to_json()
    doc.update({"stream": str(args.stream), "poses_file": str(args.poses),
                "program": None if program is None else str(args.program),
                "time_base": si.time_note, "hold": hold})
    report = None
    if args.report:
        report = build_motion_report(res, title="Diagnosis of the motion model",
                                     facts={"stream": str(args.stream), "time base": si.time_note})
    if args.json:
        write_output(args.json, json.dumps(doc, indent=2), "--json")
    if report is not None:
        write_report(report, args.report, "--report")
    _print(doc)
    if args.model_out:
        if si.refused:
            print(f"error: the motion model is not written: its times rest on a clock that failed its check "
                  f"({si.refused})", file=sys.stderr)
            return 2
        if args.model_basis == "supported":  # (without a supported model: the named one, nothing unconfirmed)
            model = {**res.motion_model(res.supported), "basis": "training_supported",
                     "not_confirmed": list(res.supported_only)}
        else:
            model = {**doc["extended_model"], "basis": "named"}
        write_output(args.model_out, json.dumps(model, indent=2), "--model-out")
    return 0


def _fmt(v, unit: str, scale: float = 1.0, digits: int = 3) -> str:
    return "n/a" if v is None else f"{v * scale:.{digits}f} {unit}"


def _print(doc: dict) -> None:
    held = ", ".join(f"{m['move']} ({m['from']}->{m['to']})" for m in doc["heldout_moves"])
    print(f"baseline (profile and loop refitted on {doc['n_moves']['train']} training moves): servo "
          f"{doc['baseline']['servo']['frequency_hz']:.3g} Hz, damping {doc['baseline']['servo']['damping']:.3g}; "
          f"held-out RMS {doc['simulation_heldout_rms'] * 1000:.2f} um along the travel "
          f"(held-out moves: {held})")
    for k, s in enumerate(doc["steps"], 1):
        par = ", ".join(f"{n} {v:.4g}" for n, v in s["params"].items())
        print(f"{k:>2}. {s['effect']} ({par}): held-out {s['heldout_rms_before'] * 1000:.2f} -> "
              f"{s['heldout_rms_after'] * 1000:.2f} um ({100 * s['gain']:.1f} %), F {s['statistic']:.1f} > "
              f"{s['threshold']:.1f}, held-out z {s['heldout_t']:.1f} > {s['heldout_threshold']:.1f} (signed ranks"
              + (f" over {s['details']['heldout_blocks']} blocks" if s["details"].get("heldout_blocks") else "")
              + (", cross-fitted: every fold of moves held out once" if s["details"].get("heldout_cross_fitted")
                 else "") + ")")
    if not doc["steps"]:
        print("nothing named: no candidate passed both tests against the baseline")
    for r in doc["remaining_structure"]:  # the last round's candidates that a test or a rule left out
        if r.get("same_as"):
            print(f"    {r['effect']} not named: {r['same_as']}")
    print(f"extended model held-out RMS {doc['final_heldout_rms'] * 1000:.2f} um ({doc['gain_percent']:.1f} % less); "
          f"noise floor {doc['noise_floor'] * 1000:.2f} um")
    if doc.get("time_refused"):
        print(f"time figures refused: {doc['time_refused']}")
    for p in doc["poses"]:
        cells = []
        for kind in ("measured", "simulated", "extended"):
            f = p[kind]
            cells.append(f"{kind} POS {_fmt(f['POS_mm'], 'um', 1000, 1)}, to band {_fmt(f['time_to_band_s'], 's')}, "
                         f"PST {_fmt(f['PST_s'], 's')}, MPT {_fmt(f['MPT_s'], 's')}")
        print(f"{p['pose']} ({p['n_moves']} held-out): " + "; ".join(cells))
    for key, why in doc["not_testable"].items():
        print(f"not testable: {key}: {why}")
    if doc.get("hold_drift"):
        h = doc["hold_drift"]
        print(f"held pose: white {_fmt(h['white_mm'], 'um', 1000, 2)}, wander {_fmt(h['wander_mm'], 'um', 1000, 2)} "
              f"per axis; over a {h['window_s']:.2g} s window the reading drifts {_fmt(h['expected_drift_mm'], 'um', 1000, 2)} "
              f"(the held-out test sees {_fmt(h['visible_mm'], 'um', 1000, 2)})")
