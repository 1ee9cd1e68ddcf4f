"""`station predict arm`: a calibrated or extended arm model evaluated at joint angles.

``station predict arm --model M.json --joints Q.csv --out P.csv [--rows-in-motion-order]``
    ``M.json`` is a library robot or an arm model file (``station calibrate
    arm --json`` output, or the extended model of ``station diagnose arm
    --model-out``, effects included). ``Q.csv`` has ``q1..q6`` (deg) and, as
    the model's effects need them, ``t`` (s), ``temperature`` (degC),
    ``load`` (kg) and ``dir1..dir6`` (sign of each joint's last motion, for
    backlash; or ``--rows-in-motion-order``). ``P.csv`` gets ``q1..q6`` and
    the modelled tool points ``x,y,z`` (mm; in the instrument frame when the
    model has a base transform, else the robot's base frame): an arm CSV
    any other tool can compare with measured points.
"""

from __future__ import annotations

import argparse

from app.commands.help_text import plain


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="evaluate a calibrated or extended model at joint angles")
    psub = p.add_subparsers(dest="predict_cmd", metavar="WHAT")
    a = psub.add_parser("arm", help="tool points of an arm model at joint angles", description=plain(__doc__.split("\n\n")[1]))
    a.add_argument("--model", required=True, metavar="M.json", help="library robot or (extended) arm model file")
    a.add_argument("--joints", required=True, metavar="Q.csv", help="q1..q6 (deg), optional t,temperature,load,dir1..dir6")
    a.add_argument("--out", required=True, metavar="P.csv", help="q1..q6, x,y,z (mm)")
    a.add_argument("--rows-in-motion-order", action="store_true",
                   help="the rows are in the order the arm moves through them (backlash directions from it)")
    a.set_defaults(func=_arm)


def context(arm, cols: dict, q_rad, rows_in_motion_order: bool, source: str) -> dict:
    """The keyword arguments the extended model's effects need, from the file's columns; DataError if missing."""
    import numpy as np

    from station.errors import DataError
    from station.models.arm_extended import motion_directions
    from station.readers.arm_columns_csv import DIR_COLS

    needs = arm.needs
    kw = {"t_s": cols.get("t"), "temperature_c": cols.get("temperature"), "load_kg": cols.get("load")}
    if "dir1" in cols:
        kw["last_dir"] = np.column_stack([cols[c] for c in DIR_COLS])
    elif rows_in_motion_order:
        kw["last_dir"] = motion_directions(q_rad)
    missing = []
    if "direction" in needs and "last_dir" not in kw:
        missing.append("dir1..dir6 (or --rows-in-motion-order) for backlash")
    if "t" in needs and kw["t_s"] is None:
        missing.append("t for the warm-up drift")
    if "temperature" in needs and kw["temperature_c"] is None:
        missing.append("temperature for the thermal drift")
    if missing:
        raise DataError(f"{source}: the model's effects need {'; '.join(missing)}")
    return kw


def _arm(args: argparse.Namespace) -> int:
    import numpy as np

    from station.errors import DataError
    from station.models.arm_model_file import resolve_arm
    from station.readers.arm_columns_csv import CONTEXT_COLS, Q_COLS, read_columns_csv, write_columns_csv

    from station.readers.out_files import check_outputs

    check_outputs(args, out="--out")
    arm = resolve_arm(args.model).extended()
    cols = read_columns_csv(args.joints, Q_COLS, CONTEXT_COLS)
    q_deg = np.column_stack([cols[c] for c in Q_COLS])
    q = np.radians(q_deg)
    lim = arm.joint_limits_rad
    bad = (q < lim[:, 0] - 1e-9) | (q > lim[:, 1] + 1e-9)
    if bad.any():
        k, j = map(int, np.argwhere(bad)[0])
        raise DataError(f"{args.joints}:{k + 2}: q{j + 1} = {q_deg[k, j]:.3f} deg is outside the model's limits")
    p = arm.predict(q, **context(arm, cols, q, args.rows_in_motion_order, str(args.joints)))
    out = {c: q_deg[:, i] for i, c in enumerate(Q_COLS)}
    out.update(x=p[:, 0], y=p[:, 1], z=p[:, 2])
    write_columns_csv(args.out, out)
    frame = "instrument frame" if arm.base_T is not None else "robot base frame"
    effects = ", ".join(f"{t.effect}" + (f"[{t.joint}]" if t.joint else "") for t in arm.terms) or "none"
    print(f"{q.shape[0]} poses predicted by {arm.name} ({frame}; effects: {effects}) -> {args.out}")
    return 0
