"""`station run PROCEDURE --config C` and `station run --resume RUN_ID --config C`.

Without ``--arm`` nothing real moves: the procedure's fake cell is started on
loopback (simulated arm, emScon tracker and controller fakes; or the trailer
with its odometry on a pty) and the run's devices point at it. With ``--arm``
the configured device URLs are used as they are (real hardware, or fakes
started with ``station fakes serve station``) and a person answers every
confirmation on the terminal: ``--yes`` (every prompt answered yes) and
``--answers FILE`` (scripted answers) are for dry runs on the fakes only and
are refused with ``--arm``.

The run is assembled in :mod:`app.assemble` and executed by the
application layer (:mod:`procedures.execute`); this module parses arguments
and prints the outcome, verdict first. Exit codes follow ``station analyze``:
0 PASS, 1 a limit failed, 2 bad input, 3 NOT DECIDED (a limit not computed,
fewer cycles than asked), 4 not ISO 9283 conformant with ``--require-iso``,
and 5 the run did not finish (ABORTED: aborted or stopped by a fault,
resumable).
A run killed at any moment (Ctrl-C, ``kill -9``, a fault) is resumed with
``--resume RUN_ID``: the robot is brought back to a known pose, then the run
goes on from its last finished step; with fakes, the same simulated cell
(same seed) is started again.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from procedures.registry import procedure_names


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a procedure (fakes by default; --arm for real hardware)",
                       description="Run a procedure of the config, or resume a stopped run. Without --arm the "
                                   "procedure's fake cell is started on loopback and nothing real moves; with "
                                   "--arm the configured devices are used and a person at the terminal answers "
                                   "every confirmation. The first line printed is the verdict.")
    p.add_argument("procedure", nargs="?", choices=procedure_names(), help="the procedure to run")
    p.add_argument("--config", required=True, help="station config (TOML or JSON)")
    p.add_argument("--robot", default="r1", help="robot key in the config (default r1)")
    p.add_argument("--resume", metavar="RUN_ID", help="resume this run from its last finished step")
    p.add_argument("--run-id", help="id of a new run (default SERIAL-YYYYmmdd-HHMMSS)")
    p.add_argument("--arm", action="store_true", help="use the configured devices: real hardware moves")
    p.add_argument("--yes", action="store_true",
                   help="answer every operator prompt with yes (dry runs on the fakes only; refused with --arm)")
    p.add_argument("--answers", metavar="FILE",
                   help="scripted answers, one 'yes'/'no' (or 'TEXT = yes|no') per prompt in order "
                        "(dry runs on the fakes only; refused with --arm)")
    p.add_argument("--time-scale", type=float, default=None,
                   help="fake cell: simulated s per real s at most (default: full pace; the same figures at any "
                        "pace)")
    p.add_argument("--seed", type=int, default=0, help="fake cell: seed of the simulated world")
    p.add_argument("--json", metavar="OUT", help="write the verdict and the results as JSON")
    p.add_argument("--require-iso", action=argparse.BooleanOptionalAction, default=None,
                   help="a run that is not ISO 9283 conformant is NOT DECIDED (exit 4), not PASS (default: required "
                        "with --arm, an acceptance; a dry run's PASS says it is not conformant)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.set_defaults(func=_cmd_run)


def _cmd_run(args: argparse.Namespace) -> int:
    from app.assemble import RunRequest, run_procedure
    from fakes.station import FULL_PACE
    from station.config import load_config
    from station.runner import AnswerFileOperator

    from station.readers.out_files import check_outputs

    check_outputs(args, json="--json")
    cfg = load_config(args.config)
    # with --arm a run is an acceptance of real hardware: conformance required unless told not; a resumed run
    # keeps what it stored, so only an explicit --require-iso reaches the request (which refuses it)
    acceptance = (None if args.resume and args.require_iso is None else
                  {"require_conformance": args.arm if args.require_iso is None else args.require_iso})
    request = RunRequest(cfg, args.procedure, robot=args.robot, resume=args.resume, run_id=args.run_id,
                         arm=args.arm, yes=args.yes,
                         operator=AnswerFileOperator(args.answers) if args.answers else None,
                         time_scale=FULL_PACE if args.time_scale is None else args.time_scale,
                         seed=args.seed, json_out=args.json, quiet=args.quiet,
                         config_dir=Path(args.config).resolve().parent, acceptance=acceptance)
    outcome = run_procedure(request)
    for line in outcome.lines(config=args.config):
        print(line)
    return outcome.exit_code
