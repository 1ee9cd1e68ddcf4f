"""`station simulate iso9283|arm|trailer --out DIR`: offline data of the simulated cell, with the truth beside.

* ``arm``: an arm measurement CSV for ``calibrate arm`` / ``diagnose arm``
  (:mod:`fakes.sim.offline_files`): ``arm.csv`` and ``truth.json``;
* ``trailer``: a trailer record for ``calibrate trailer`` / ``diagnose trailer``:
  ``trailer.csv`` and ``truth.json``;
* ``hold``: a robot holding one pose, measured by the tracker, for ``analyze hold``:
  ``stream.csv`` (``t,x,y,z``) and ``truth.json``;
* ``iso9283``: an ISO 9283 run (:mod:`fakes.sim.iso_run`), as follows.

This module parses the arguments and writes the files; what the ISO 9283 run
simulates (the world, its cycles and the files written to DIR) is told in
:mod:`fakes.sim.iso_run`.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from station.errors import ConfigError
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

#: the supported tracker rates as the options' help says them
_RATES = f"{TRACKER_RATE_RANGE_HZ[0]:g}-{TRACKER_RATE_RANGE_HZ[1]:g}"


def _parse_break(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(f"--beam-break must be START:END in seconds after the recording starts, got {text[:40]!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
        raise ConfigError(f"--beam-break needs 0 <= START < END, got {text[:40]!r}")
    return a, b


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="offline data of the simulated cell, with the truth beside")
    ssub = p.add_subparsers(dest="simulate_cmd", metavar="RUN")
    s = ssub.add_parser("iso9283", help="ISO 9283 cycles P1..P5 (seed 000) -> tracker stream CSV",
                        description="Simulate the ISO 9283 pose cycles of seed 000 (P2, P3, P4, P5, P1 from a wait "
                                    "at P1) on the simulated cell, offline, and write DIR/stream.csv (t s, x,y,z "
                                    "mm, tracker frame), DIR/poses.csv (the commanded poses, tracker frame) and "
                                    "DIR/truth.json (the true stops and their AP and RP, the drawn world).")
    s.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    s.add_argument("--program", default=None, metavar="FILE",
                   help="replay a lab's program instead of the seed's cycles: poses, order, moves, dwell, cycles, "
                        "payload, rate (TOML or JSON; the README's file formats); --cycles, --dwell, --rate, "
                        "--wait and --move are then the program's")
    s.add_argument("--cycles", type=int, default=None, help="number of cycles P2,P3,P4,P5,P1, 1-100 (default 3)")
    s.add_argument("--dwell", type=float, default=None, help="dwell at each pose, s, 0-60 (default 0.5)")
    s.add_argument("--rate", type=float, default=None, help=f"tracker rate, Hz, {_RATES} (default 1000)")
    s.add_argument("--seed", type=int, default=0, help="seed of the simulated world, 0-4294967295 (default 0)")
    s.add_argument("--robot", default=None, help="robot model (default industrial-3100, or the program's)")
    s.add_argument("--wait", type=float, default=None, help="initial wait at P1 while measuring, s, 0-600 (default 4)")
    s.add_argument("--move", choices=("joint", "linear"), default=None, help="move type between poses (default joint)")
    s.add_argument("--tracker-noise", default=None, metavar="FILE",
                   help="the tracker's reading noise (white, wander, latency), e.g. the fit `analyze hold "
                        "--noise-out` wrote (default: the measured Leica figures, 0.6 um white, 2 um wander, 1 s)")
    s.add_argument("--effects", choices=("realistic", "none"), default="realistic",
                   help="error effects of the true arm (default realistic)")
    s.add_argument("--beam-break", action="append", default=[], metavar="START:END",
                   help="beam break, seconds after the recording starts (repeatable)")
    s.add_argument("--motion-model", metavar="M.json",
                   help="extended motion model (station diagnose motion --model-out): the arm's loop and profile, "
                        "its creep and structural mode, the tracker's drift")
    s.set_defaults(func=_run_iso9283)
    a = ssub.add_parser("arm", help="an arm measured at random poses -> arm CSV for calibrate/diagnose arm",
                        description="A true arm (the library model plus drawn errors) measured by a laser tracker "
                        "in a random frame at random poses, in order. Writes DIR/arm.csv (q1..q6 deg, x,y,z mm, "
                        "t s, temperature degC, load kg) and DIR/truth.json (the drawn errors, the tracker frame, "
                        "the noise, the noise-free points and the figures calibrate arm prints on them, with U).")
    a.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    a.add_argument("--robot", default="industrial-3100", help="library robot model (default industrial-3100)")
    a.add_argument("--poses", type=int, default=80, help="number of measured poses, 10-20000 (default 80)")
    a.add_argument("--effects", choices=("geometric", "realistic", "none"), default="geometric",
                   help="errors of the true arm: geometric only (what calibrate arm identifies, default), "
                        "realistic (also compliance, backlash, thermal drift, encoder eccentricity: what diagnose "
                        "arm finds), or none")
    a.add_argument("--seed", type=int, default=0, help="seed of the drawn arm and measurements (default 0)")
    a.set_defaults(func=_run_arm)
    t = ssub.add_parser("trailer", help="a trailer record -> trailer CSV for calibrate/diagnose trailer",
                        description="A front unit driving a smooth random path with its trailer; the hitch angle "
                        "and the path curvature measured with noise. Writes DIR/trailer.csv (t s, kappa 1/m, psi "
                        "rad, v m/s) and DIR/truth.json (link lengths and the hidden effects).")
    t.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    t.add_argument("--hidden", action="append", default=[], metavar="EFFECT",
                   choices=("link_lengths", "hitch_angle_offset", "curvature_gain", "hitch_dynamics"),
                   help="an effect drawn into the record (repeatable): link_lengths, hitch_angle_offset, "
                        "curvature_gain, hitch_dynamics")
    t.add_argument("--duration", type=float, default=180.0, help="length of the record, s, 30-1800 (default 180)")
    t.add_argument("--seed", type=int, default=0, help="seed of the drawn record (default 0)")
    t.set_defaults(func=_run_trailer)
    h = ssub.add_parser("hold", help="a held pose measured by the tracker -> stream CSV for analyze hold",
                        description="A robot standing at one pose while the tracker measures it: the tool drifts "
                        "slowly (the arm warming up) and the tracker adds its noise. Writes DIR/stream.csv "
                        "(t s, x,y,z mm) and DIR/truth.json (position, drift, noise).")
    h.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    h.add_argument("--duration", type=float, default=60.0, help="length of the hold, s, 3-14400 (default 60)")
    h.add_argument("--rate", type=float, default=100.0, help=f"tracker rate, Hz, {_RATES} (default 100)")
    h.add_argument("--seed", type=int, default=0, help="seed of the drawn hold (default 0)")
    h.add_argument("--tracker-noise", default=None, metavar="FILE",
                   help="the tracker's reading noise file (default: the measured Leica figures)")
    h.set_defaults(func=_run_hold)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


#: longest simulated hold, s (a warm-up is watched for an hour or two)
MAX_HOLD_S = 4 * 3600.0
#: most poses of a simulated arm measurement (what the arm CSV reader takes)
MAX_ARM_POSES = 20_000
#: longest simulated trailer record, s (calibrate and diagnose trailer use minutes)
MAX_TRAILER_S = 1800.0


def _run_hold(args: argparse.Namespace) -> int:
    import csv

    from fakes.sim.offline_files import simulate_hold
    from fakes.sim.sim_bounds import check_real, check_samples, check_seed
    from station.readers.out_files import output_file

    duration = check_real(args.duration, "--duration", 3.0, MAX_HOLD_S, " s")
    rate = check_real(args.rate, "--rate", *TRACKER_RATE_RANGE_HZ, " Hz")
    check_seed(args.seed)
    check_samples(duration * rate + 1, f"--duration {duration:g} s at --rate {rate:g} Hz")
    noise = _tracker_noise(args)
    _out_dir(args.out, create=False)
    cols, truth = simulate_hold(seed=args.seed, duration_s=duration, rate_hz=rate, noise=noise)
    out = _out_dir(args.out)
    with output_file(out / "stream.csv", "--out", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "x", "y", "z"])
        for t, p in zip(cols["t"], cols["xyz_mm"]):
            w.writerow([repr(float(t))] + [repr(float(v)) for v in p])
    _write_truth(out / "truth.json", truth)
    print(f"wrote {out / 'stream.csv'} ({cols['t'].size} samples over {args.duration:g} s at {args.rate:g} Hz)")
    nz = truth["tracker_noise"]
    print(f"wrote {out / 'truth.json'} (drift {np.linalg.norm(truth['drift_mm_per_min']):.4f} mm/min, noise "
          f"{truth['noise_mm']:.4f} mm: white {nz['white_um']:g} um, wander {nz['wander_um']:g} um over "
          f"{nz['wander_tau_s']} s)")
    return 0


def _out_dir(text: str, *, create: bool = True) -> Path:
    from station.readers.out_files import output_dir

    return output_dir(text, "--out", create=create)


def _write_truth(path: Path, truth: dict) -> None:
    from station.readers.out_files import write_output

    write_output(path, json.dumps(truth, indent=1) + "\n", "--out")


def _run_arm(args: argparse.Namespace) -> int:
    from fakes.sim.offline_files import simulate_arm
    from station.readers.arm_csv import write_arm_csv

    from fakes.sim.sim_bounds import check_int, check_seed

    check_int(args.poses, "--poses", 10, MAX_ARM_POSES)
    check_seed(args.seed)
    _out_dir(args.out, create=False)
    cols, truth = simulate_arm(args.robot, n=args.poses, effects=args.effects, seed=args.seed)
    out = _out_dir(args.out)
    write_arm_csv(out / "arm.csv", cols["q_deg"], cols["xyz_mm"], t=cols["t"], temperature=cols["temperature"],
                  load=cols["load"])
    _write_truth(out / "truth.json", truth)
    print(f"wrote {out / 'arm.csv'} ({args.poses} poses of {truth['robot']}, errors: {args.effects})")
    print(f"wrote {out / 'truth.json'} (the drawn errors, the tracker frame, the noise {truth['noise_mm']:.4f} mm; "
          "under figures: what calibrate arm prints on this file, stated on the noise-free points, with U)")
    return 0


def _run_trailer(args: argparse.Namespace) -> int:
    from fakes.sim.offline_files import simulate_trailer
    from app.commands.calibrate import write_trailer_csv

    from fakes.sim.sim_bounds import check_real, check_seed

    duration = check_real(args.duration, "--duration", 30.0, MAX_TRAILER_S, " s")
    check_seed(args.seed)
    _out_dir(args.out, create=False)
    cols, truth = simulate_trailer(hidden=tuple(dict.fromkeys(args.hidden)), seed=args.seed, duration_s=duration)
    out = _out_dir(args.out)
    write_trailer_csv(out / "trailer.csv", cols["t"], cols["kappa"], cols["psi"], v=cols["v"])
    _write_truth(out / "truth.json", truth)
    print(f"wrote {out / 'trailer.csv'} ({cols['t'].size} samples over {args.duration:g} s)")
    print(f"wrote {out / 'truth.json'} (L1 {truth['L1_m']:.4f} m, L2 {truth['L2_m']:.4f} m; hidden: "
          f"{', '.join(truth['hidden']) or 'none'})")
    return 0


def _tracker_noise(args: argparse.Namespace):
    """The world options of ``--tracker-noise`` (read before anything is simulated)."""
    if args.tracker_noise is None:
        return None
    from station.models.tracker_noise import read_tracker_noise

    return read_tracker_noise(args.tracker_noise, "--tracker-noise")


def _run_iso9283(args: argparse.Namespace) -> int:
    breaks = [_parse_break(b) for b in args.beam_break]
    noise = _tracker_noise(args)
    options = {} if noise is None else {"tracker_noise": noise}
    if args.program is not None:
        return _run_program(args, breaks, options)
    from fakes.sim.iso_run import simulate_iso9283
    from station.models.motion_model_file import read_motion_model

    motion = read_motion_model(args.motion_model) if args.motion_model else None
    summary = simulate_iso9283(
        args.out,
        cycles=3 if args.cycles is None else args.cycles,
        dwell_s=0.5 if args.dwell is None else args.dwell,
        rate_hz=1000.0 if args.rate is None else args.rate,
        seed=args.seed,
        robot=args.robot or "industrial-3100",
        wait_s=4.0 if args.wait is None else args.wait,
        move=args.move or "joint",
        effects=args.effects,
        beam_breaks=breaks,
        world_options=options,
        motion_model=motion,
    )
    print(
        f"wrote {summary['stream_csv']} ({summary['n_samples']} samples, {summary['n_invalid']} invalid, "
        f"{summary['duration_s']:.1f} s at {summary['rate_hz']:g} Hz)"
    )
    print(f"wrote {summary['poses_csv']} (5 commanded poses, tracker frame)")
    print(f"wrote {summary['truth_json']} ({summary['n_stops']} stops = {summary['cycles']} cycles x 5 poses)")
    return 0


def _run_program(args: argparse.Namespace, breaks, options: dict) -> int:
    from fakes.sim.program_run import simulate_program
    from station.readers.motion_program import read_motion_program

    given = [o for o, v in (("--cycles", args.cycles), ("--dwell", args.dwell), ("--rate", args.rate),
                            ("--wait", args.wait), ("--move", args.move)) if v is not None]
    if given:
        raise ConfigError(f"{given[0]} and --program: the program sets the cycles, dwell, rate, wait and moves "
                          f"(edit the program, or leave --program out)")
    from station.models.motion_model_file import read_motion_model

    program = read_motion_program(args.program)
    motion = read_motion_model(args.motion_model) if args.motion_model else None
    _out_dir(args.out, create=False)
    summary = simulate_program(args.out, program, seed=args.seed, robot=args.robot, effects=args.effects,
                               beam_breaks=breaks, world_options=options, motion_model=motion)
    n_poses = len(program.poses)
    print(
        f"wrote {summary['stream_csv']} ({summary['n_samples']} samples, {summary['n_invalid']} invalid, "
        f"{summary['duration_s']:.1f} s at {summary['rate_hz']:g} Hz)"
    )
    print(f"wrote {summary['poses_csv']} ({n_poses} commanded poses, tracker frame)")
    print(f"wrote {summary['truth_json']} ({summary['n_stops']} stops = {summary['cycles']} cycles x "
          f"{len(program.order)} moves of {program.source})")
    return 0


