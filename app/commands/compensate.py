"""`station compensate arm`: the joint angles that put the tool on wanted points, with a calibrated model.

``station compensate arm --model M.json --targets T.csv --out Q.csv``
    ``T.csv`` has the wanted tool points ``x,y,z`` (mm; in the instrument
    frame when the model has a base transform, else the robot's base
    frame), optionally ``q1..q6`` (deg: a start on the wanted branch, e.g.
    the nominal program's angles) and the context the effects need (``t``,
    ``temperature``, ``load``, ``dir1..dir6``). Without ``q1..q6`` the
    start is the inverse kinematics of the model's table from the middle of
    the joint limits. ``Q.csv`` gets ``q1..q6`` (the commands to send),
    ``x,y,z`` (the targets) and ``residual_mm`` (what the model still
    misses; exit code 3 when a target is missed by more than ``--tol-mm``).
"""

from __future__ import annotations

import argparse

from app.commands.help_text import plain

#: exit code when a target cannot be reached within --tol-mm (Q.csv is written all the same)
EXIT_MISSED = 3


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="joint angles that put the tool on wanted points with a calibrated model")
    csub = p.add_subparsers(dest="compensate_cmd", metavar="WHAT")
    a = csub.add_parser("arm", help="joint commands for wanted tool points", description=plain(__doc__.split("\n\n")[1]),
                        epilog=f"exit codes: 0 every target reached; 2 refused; {EXIT_MISSED} a target missed")
    a.add_argument("--model", required=True, metavar="M.json", help="library robot or (extended) arm model file")
    a.add_argument("--targets", required=True, metavar="T.csv",
                   help="x,y,z (mm), optional q1..q6 (deg, start), t,temperature,load,dir1..dir6")
    a.add_argument("--out", required=True, metavar="Q.csv", help="q1..q6 (deg), x,y,z, residual_mm")
    a.add_argument("--tol-mm", type=float, default=0.001, help="largest residual accepted (default 0.001 mm)")
    a.set_defaults(func=_arm)


def _arm(args: argparse.Namespace) -> int:
    import sys

    import numpy as np

    from app.commands.predict import context
    from station.models import kinematics as kin
    from station.models.arm_model_file import resolve_arm
    from station.readers.arm_columns_csv import CONTEXT_COLS, Q_COLS, XYZ_COLS, read_columns_csv, write_columns_csv

    from station.readers.out_files import check_outputs

    check_outputs(args, out="--out")
    arm = resolve_arm(args.model).extended()
    cols = read_columns_csv(args.targets, XYZ_COLS, Q_COLS + CONTEXT_COLS)
    tgt = np.column_stack([cols[c] for c in XYZ_COLS])
    n = tgt.shape[0]
    lim = arm.joint_limits_rad
    if "q1" in cols:
        q0 = np.clip(np.radians(np.column_stack([cols[c] for c in Q_COLS])), lim[:, 0], lim[:, 1])
    else:
        B = np.eye(4) if arm.base_T is None else arm.base_T
        in_base = (tgt - B[:3, 3]) @ B[:3, :3]
        q0 = kin.ik(arm.dh, in_base, joint_limits_rad=lim, n_restarts=8).q_rad
    kw = context(arm, cols, q0, False, str(args.targets))
    q, resid = arm.compensate(tgt, q0, **kw)
    out = {c: np.degrees(q[:, i]) for i, c in enumerate(Q_COLS)}
    out.update(x=tgt[:, 0], y=tgt[:, 1], z=tgt[:, 2], residual_mm=resid)
    write_columns_csv(args.out, out)
    missed = int(np.sum(resid > args.tol_mm))
    print(f"{n} targets compensated with {arm.name}: largest residual {resid.max():.2e} mm -> {args.out}")
    if missed:
        print(f"error: {missed} target(s) missed by more than {args.tol_mm:g} mm (see residual_mm); "
              f"exit code {EXIT_MISSED}", file=sys.stderr)
        return EXIT_MISSED
    return 0
