"""`station simulate iso9283 --out DIR`: an offline ISO 9283 run on the simulated cell
(:mod:`fakes.sim.iso_run`; this module parses the arguments).

The world (:func:`fakes.sim.world.make_world`, on a ``ManualClock`` so it runs
as fast as the machine computes) drives its arm through the cycles of seed
000 sec. 3.1.3: the arm waits at P1 while the tracker starts measuring, then
visits P2, P3, P4, P5, P1 in every cycle with fine stops and a dwell at each
pose, at rated speed (synchronised joint moves at 100 % of the rated joint
speeds, or straight lines at the rated TCP speed with ``--move linear``).
Commanded poses are seed 000 Table 2 (the cube fitted to the arm's reach for other arms, e.g.
``--robot ur5e``) with one tool orientation (the one the
nominal inverse kinematics finds for P1 from the home pose).

Files written to DIR:

* ``stream.csv``: ``t,x,y,z,status``: the tracker stream (device time s,
  mm in the tracker frame); ``status`` 0 = valid, 1 = beam broken (then
  x, y, z are ``nan``). Every sample the tracker produced is there.
* ``poses.csv``: ``name,x,y,z``: the commanded positions in the tracker
  frame.
* ``truth.json``: the true attained positions per stop (base and tracker
  frames), the tracker's base transform, the error effects, servo and
  scatter parameters, and the stop timing, for people and tests.
"""

from __future__ import annotations

import argparse
import math

from station.errors import ConfigError


def _parse_break(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise ConfigError(f"--beam-break must be START:END in seconds after the recording starts, got {text!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and 0 <= a < b):
        raise ConfigError(f"--beam-break needs 0 <= START < END, got {text!r}")
    return a, b


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="offline runs of the simulated cell")
    ssub = p.add_subparsers(dest="simulate_cmd", metavar="RUN")
    s = ssub.add_parser("iso9283", help="ISO 9283 cycles P1..P5 (seed 000) -> tracker stream CSV")
    s.add_argument("--out", required=True, metavar="DIR", help="output directory (created if missing)")
    s.add_argument("--cycles", type=int, default=3, help="number of cycles P2,P3,P4,P5,P1 (default 3)")
    s.add_argument("--dwell", type=float, default=0.5, help="dwell at each pose, s (default 0.5)")
    s.add_argument("--rate", type=float, default=1000.0, help="tracker rate, Hz, 10-3000 (default 1000)")
    s.add_argument("--seed", type=int, default=0, help="seed of the simulated world (default 0)")
    s.add_argument("--robot", default="industrial-3100", help="robot model (default industrial-3100)")
    s.add_argument("--wait", type=float, default=4.0, help="initial wait at P1 while measuring, s (default 4)")
    s.add_argument("--move", choices=("joint", "linear"), default="joint", help="move type between poses")
    s.add_argument("--effects", choices=("realistic", "none"), default="realistic",
                   help="error effects of the true arm (default realistic)")
    s.add_argument("--beam-break", action="append", default=[], metavar="START:END",
                   help="beam break, seconds after the recording starts (repeatable)")
    s.set_defaults(func=_run_iso9283)


def _run_iso9283(args: argparse.Namespace) -> int:
    from fakes.sim.iso_run import simulate_iso9283

    summary = simulate_iso9283(
        args.out,
        cycles=args.cycles,
        dwell_s=args.dwell,
        rate_hz=args.rate,
        seed=args.seed,
        robot=args.robot,
        wait_s=args.wait,
        move=args.move,
        effects=args.effects,
        beam_breaks=[_parse_break(b) for b in args.beam_break],
    )
    print(
        f"wrote {summary['stream_csv']} ({summary['n_samples']} samples, {summary['n_invalid']} invalid, "
        f"{summary['duration_s']:.1f} s at {summary['rate_hz']:g} Hz)"
    )
    print(f"wrote {summary['poses_csv']} (5 commanded poses, tracker frame)")
    print(f"wrote {summary['truth_json']} ({summary['n_stops']} stops = {summary['cycles']} cycles x 5 poses)")
    return 0


