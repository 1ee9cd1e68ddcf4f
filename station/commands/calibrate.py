"""`station calibrate ...`: calibrations from recorded data.

``station calibrate trailer --data T.csv [--method M] [--json OUT]``
    Link lengths L1, L2 of the two-link trailer (seed 003) from a CSV with
    a header and columns ``t,kappa,psi`` (s, 1/m, rad) and optionally ``v``
    (m/s) and ``kappa_cmd`` (1/m, the commanded curvature in force, which
    ``dynamic`` uses as an instrument when it explains the measured one);
    rows in time order; curvature and speed are averages over the interval
    ending at ``t`` as odometry reports them (``--sampling point`` for
    instantaneous values). Methods: ``M1``..``M24`` (seed Table 3),
    ``odr`` (orthogonal distance regression on eq. (23)), ``dynamic`` (the
    joint-angle dynamics; needs ``v``), ``auto`` (default: ``dynamic`` if the
    file has ``v``, else ``M17``). Prints the result; ``--json`` writes it
    with the keys ``method``, ``L1_m``, ``L2_m``, ``L1_sigma_m``,
    ``L2_sigma_m`` (standard uncertainties), ``L1_L2_corr``,
    ``condition_number``, ``n_samples``, ``details``, ``warnings``.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from station.analysis.trailer_estimate import estimate_trailer
from station.errors import ConfigError, DataError

TRAILER_COLUMNS = ("t", "kappa", "psi")
#: optional columns: speed (m/s), commanded curvature (1/m, the set points in force)
OPTIONAL_COLUMNS = ("v", "kappa_cmd")
TRAILER_METHODS = tuple(f"M{i}" for i in range(1, 25)) + ("odr", "dynamic", "auto")
#: refuse files larger than this many rows (a month of 10 Hz data)
MAX_ROWS = 30_000_000


def read_trailer_csv(path) -> dict[str, np.ndarray]:
    """Read a trailer CSV (``t,kappa,psi`` [+ ``v``, ``kappa_cmd``]); DataError names the bad row/column.

    Extra columns are ignored. Rows must be in strictly increasing time.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read {path}: {exc.strerror or exc}") from exc
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise DataError(f"{path}: line {line}: not UTF-8 text") from None
    with io.StringIO(text, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration as exc:
            raise DataError(f"{path} is empty (expected a header t,kappa,psi[,v])") from exc
        except csv.Error as exc:
            raise DataError(f"{path}: {exc}") from exc
        names = [h.strip() for h in header]
        missing = [c for c in TRAILER_COLUMNS if c not in names]
        if missing:
            raise DataError(f"{path}: missing column(s) {missing}; the header is {names} "
                            "(expected t,kappa,psi and optionally v)")
        wanted = list(TRAILER_COLUMNS) + [c for c in OPTIONAL_COLUMNS if c in names]
        idx = {c: names.index(c) for c in wanted}
        cols = {c: [] for c in wanted}
        try:
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not x.strip() for x in row):
                    continue
                if len(row) > len(names):
                    raise DataError(f"{path} line {line_no}: {len(row)} fields, the header has {len(names)}")
                if len(cols["t"]) >= MAX_ROWS:
                    raise DataError(f"{path}: more than {MAX_ROWS} rows")
                for c in wanted:
                    try:
                        value = float(row[idx[c]])
                    except IndexError as exc:
                        raise DataError(f"{path} line {line_no}: {len(row)} fields, no column {c!r}") from exc
                    except ValueError as exc:
                        raise DataError(f"{path} line {line_no}, column {c!r}: "
                                        f"{row[idx[c]]!r} is not a number") from exc
                    if not math.isfinite(value):
                        raise DataError(f"{path} line {line_no}, column {c!r}: {value} is not finite")
                    cols[c].append(value)
        except csv.Error as exc:
            raise DataError(f"{path}: {exc}") from exc
    data = {c: np.asarray(v, dtype=float) for c, v in cols.items()}
    t = data["t"]
    if t.size >= 2:
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise DataError(f"{path}: t must increase strictly; row {int(bad[0]) + 3} (t={t[bad[0] + 1]}) "
                            f"does not follow row {int(bad[0]) + 2} (t={t[bad[0]]})")
    return data


def write_trailer_csv(path, t, kappa, psi, v=None, kappa_cmd=None) -> None:
    """Write a trailer CSV (``t,kappa,psi`` [+ ``v``, ``kappa_cmd``]) in s, 1/m, rad, m/s."""
    cols = [np.asarray(t, float), np.asarray(kappa, float), np.asarray(psi, float)]
    header = ["t", "kappa", "psi"]
    for name, extra in (("v", v), ("kappa_cmd", kappa_cmd)):
        if extra is not None:
            cols.append(np.broadcast_to(np.asarray(extra, float), cols[0].shape))
            header.append(name)
    if len({c.shape for c in cols}) != 1 or cols[0].ndim != 1:
        raise DataError("t, kappa, psi (and v) must be 1-D arrays of one length")
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(zip(*(c.tolist() for c in cols)))


def format_estimate(est) -> str:
    """Human-readable lines of a TrailerEstimate."""
    lines = [
        f"method            {est.method}" + (f"  ({est.details['label']})" if "label" in est.details else ""),
        f"L1                {est.L1_m:.4f} m  +- {est.L1_sigma_m:.4f} m (1 sigma)",
        f"L2                {est.L2_m:.4f} m  +- {est.L2_sigma_m:.4f} m (1 sigma)",
        f"correlation       {est.L1_L2_corr:+.3f}",
        f"condition number  {est.condition_number:.4g}",
        f"samples           {est.n_samples}",
    ]
    if "input" in est.details:
        lines.append(f"input             {est.details['input']}")
    for w in est.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def register(sub: argparse._SubParsersAction) -> None:
    from station.commands.help_text import plain

    p = sub.add_parser("calibrate", help="calibrations from recorded data")
    csub = p.add_subparsers(dest="calibrate_cmd", metavar="WHAT")
    t = csub.add_parser("trailer", help="link lengths of the two-link trailer (seed 003)",
                        description=plain(__doc__.split("\n\n")[1]))
    t.add_argument("--data", required=True, metavar="CSV", help="t,kappa,psi[,v] in s, 1/m, rad, m/s")
    t.add_argument("--method", default="auto", choices=TRAILER_METHODS,
                   help="M1..M24 (seed Table 3), odr, dynamic, or auto (default)")
    t.add_argument("--sampling", default="interval", choices=("interval", "point"),
                   help="curvature/speed rows are averages over the interval ending at t "
                        "(odometry, default) or instantaneous values (method dynamic)")
    t.add_argument("--no-command", action="store_true",
                   help="ignore a kappa_cmd column (method dynamic uses it as an instrument)")
    t.add_argument("--json", metavar="OUT", help="write the result as JSON")
    t.set_defaults(func=_trailer)
    from station.commands.calibrate_arm import add_parser as add_arm

    add_arm(csub)


def _trailer(args: argparse.Namespace) -> int:
    data = read_trailer_csv(args.data)
    method = args.method
    if method == "auto":
        method = "dynamic" if "v" in data else "M17"
    if method == "dynamic" and "v" not in data:
        raise DataError(f"{args.data}: method 'dynamic' needs the speed column v")
    if method not in TRAILER_METHODS:
        raise ConfigError(f"unknown method {method!r}")
    est = estimate_trailer(data, method, sampling=args.sampling, use_command=not args.no_command)
    print(format_estimate(est))
    if args.json:
        out = est.to_json()
        out["data"] = str(args.data)
        try:
            Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
        except OSError as exc:
            raise DataError(f"cannot write {args.json}: {exc.strerror or exc}") from exc
    return 0


__all__ = ["register", "read_trailer_csv", "write_trailer_csv", "format_estimate", "TRAILER_METHODS",
           "TRAILER_COLUMNS", "OPTIONAL_COLUMNS"]
