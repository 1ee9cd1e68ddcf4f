"""`station analyze ...`: analyses of recorded data files.

``station analyze iso9283 --stream S.csv --poses P.csv [--limit-mm L] [--json OUT]``

* ``S.csv``: tracker stream ``t,x,y,z`` (s, mm) with optional ``status``
  (rows whose status is not ``0``/``ok``/``valid`` are flagged invalid, e.g. a
  broken beam, and left out with a count) and optional ``a,b,c`` (deg, 6-DOF
  orientation).
* ``P.csv``: commanded poses ``name,x,y,z`` (mm, the stream's frame), optional
  ``a,b,c`` (deg).  The row order is the commanded order of one cycle unless
  ``--order`` says otherwise.

Prints a table and writes the results JSON (:meth:`Iso9283Result.to_dict`).
Exit code 0 when every verdict passes (or no limits were given), 1 when one
fails, 2 on bad input.  This module is the I/O boundary: malformed CSV files
are refused naming the file, line and column.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from station.errors import ConfigError, DataError

#: status values that mean "valid sample" (case-insensitive)
OK_STATUS = ("0", "ok", "valid")
STREAM_REQUIRED = ("t", "x", "y", "z")
STREAM_OPTIONAL_FLOAT = ("a", "b", "c")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="analyse recorded data files")
    asub = p.add_subparsers(dest="analyze_cmd", metavar="ANALYSIS")
    s = asub.add_parser(
        "iso9283",
        help="ISO 9283 pose characteristics from a tracker stream",
        description="Attained poses from a continuous tracker stream (seed 000 method) and the ISO 9283 "
        "characteristics AP, RP, POS, PST, vAP, AD, RD, MPT (+ orientation, drift, AT/RT where the data "
        "carry them), with verdicts.",
    )
    s.add_argument("--stream", required=True, type=Path, help="tracker stream CSV: t,x,y,z[,status][,a,b,c]")
    s.add_argument("--poses", required=True, type=Path, help="commanded poses CSV: name,x,y,z[,a,b,c]")
    s.add_argument("--limit-mm", type=float, default=None,
                   help="manufacturer's position repeatability, mm: RP verdict and the POS/PST limit band")
    s.add_argument("--band", choices=("limit", "own"), default=None,
                   help="POS/PST limit band: the --limit-mm value (default when given) or each pose's own RP")
    s.add_argument("--limit", action="append", default=[], metavar="KEY=VALUE",
                   help="further limits, repeatable, e.g. AP_mm=5 PST_s=0.5 vAP_mm=1.5 MPT_s=6")
    s.add_argument("--order", default=None, help="commanded order of one cycle, e.g. P2,P3,P4,P5,P1")
    s.add_argument("--distance", action="append", default=None, metavar="A,B",
                   help="pose pair for AD/RD (default P2,P4 when present); repeatable")
    s.add_argument("--linear-paths", action="store_true", help="moves are linear: compute AT/RT")
    s.add_argument("--window-s", type=float, default=0.1, help="moving horizon length 2M+1, s (default 0.1)")
    s.add_argument("--velocity-step-s", type=float, default=0.01,
                   help="interval of the velocity of eq. (3), s (default 0.01, the seed's sampling; "
                        "0 = successive samples at any rate)")
    s.add_argument("--assign-tol-mm", type=float, default=25.0,
                   help="largest distance from a stop to its commanded pose, mm (default 25)")
    s.add_argument("--json", type=Path, default=None, help="write the results JSON here")
    s.set_defaults(func=_iso9283)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


# --------------------------------------------------------------------------
# CSV reading (the I/O boundary)
# --------------------------------------------------------------------------


def _header(path: Path) -> list[str]:
    try:
        with open(path, newline="", encoding="utf-8") as f:
            first = f.readline()
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: line 1: not UTF-8 text") from exc
    if not first.strip():
        raise DataError(f"{path}: line 1: empty file or missing header")
    return [h.strip() for h in next(csv.reader([first]))]


def _scan_for_error(path: Path, header: list[str], float_cols: list[str]) -> None:
    """Find the first malformed line and raise a DataError naming it (slow path)."""
    pos = {c: header.index(c) for c in float_cols}
    with open(path, newline="", encoding="utf-8", errors="strict") as f:
        reader = csv.reader(f)
        next(reader)
        for row in reader:
            ln = reader.line_num
            if len(row) != len(header):
                raise DataError(f"{path}: line {ln}: {len(row)} fields, the header has {len(header)}")
            for c, k in pos.items():
                cell = row[k].strip()
                try:
                    float(cell)
                except ValueError:
                    raise DataError(f"{path}: line {ln}, column {c!r}: {cell!r} is not a number") from None
    raise DataError(f"{path}: could not be parsed as CSV")


def _status_ok(value: str) -> bool:
    """``0`` (any numeric zero), ``ok`` or ``valid`` mean a valid sample."""
    v = value.strip().lower()
    if v in OK_STATUS:
        return True
    try:
        return float(v) == 0.0
    except ValueError:
        return False


def read_stream_csv(path: Path) -> dict[str, np.ndarray]:
    """Read a tracker stream CSV into arrays ``t, x, y, z[, a, b, c]`` and ``valid``.

    Raises DataError naming file, line and column for anything malformed,
    including NaN in a row that is not flagged invalid.
    """
    header = _header(path)
    missing = [c for c in STREAM_REQUIRED if c not in header]
    if missing:
        raise DataError(f"{path}: line 1: missing column(s) {', '.join(missing)} (need t,x,y,z)")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise DataError(f"{path}: line 1: duplicate column(s) {', '.join(dup)}")
    floats = list(STREAM_REQUIRED) + [c for c in STREAM_OPTIONAL_FLOAT if c in header]
    abc = [c for c in STREAM_OPTIONAL_FLOAT if c in header]
    if abc and len(abc) != 3:
        raise DataError(f"{path}: line 1: orientation needs all of a,b,c, got {','.join(abc)}")
    has_status = "status" in header
    import pyarrow as pa
    from pyarrow import csv as pacsv

    try:
        types = {c: pa.float64() for c in floats}
        if has_status:
            types["status"] = pa.string()
        table = pacsv.read_csv(
            str(path),
            parse_options=pacsv.ParseOptions(ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(column_types=types, include_columns=floats
                                                 + (["status"] if has_status else []),
                                                 strings_can_be_null=False),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError, UnicodeDecodeError):
        _scan_for_error(path, header, floats)
        raise  # pragma: no cover  (_scan_for_error always raises)
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc})") from exc
    out = {c: table.column(c).to_numpy(zero_copy_only=False).astype(float) for c in floats}
    n = table.num_rows
    if n == 0:
        raise DataError(f"{path}: no data rows after the header")
    if has_status:
        uniq, inv = np.unique(np.asarray(table.column("status").to_pylist(), dtype=str), return_inverse=True)
        valid = np.array([_status_ok(u) for u in uniq], dtype=bool)[inv.ravel()]
    else:
        valid = np.ones(n, bool)
    for c in floats:
        if c == "t":
            bad = ~np.isfinite(out[c])
        else:
            bad = ~np.isfinite(out[c]) & valid
        if bad.any():
            r = int(np.argmax(bad))
            what = "empty or not a number" if np.isnan(out[c][r]) else f"{out[c][r]!r}"
            hint = "" if c == "t" else " (flag such rows with a status instead)"
            raise DataError(f"{path}: line {r + 2}, column {c!r}: {what}{hint}")
    dt = np.diff(out["t"])
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        what = "repeats" if dt[r - 1] == 0 else "is before"
        raise DataError(f"{path}: line {r + 2}, column 't': {out['t'][r]!r} {what} the time on line {r + 1} "
                        f"({out['t'][r - 1]!r}); the stream must be sorted by time without duplicates")
    out["valid"] = valid
    return out


def read_poses_csv(path: Path) -> tuple[list[str], np.ndarray, np.ndarray | None]:
    """Read ``name,x,y,z[,a,b,c]``; returns names, positions (P,3) mm, orientation (P,3) deg or None."""
    header = _header(path)
    need = ("name", "x", "y", "z")
    missing = [c for c in need if c not in header]
    if missing:
        raise DataError(f"{path}: line 1: missing column(s) {', '.join(missing)} (need name,x,y,z)")
    abc = [c for c in STREAM_OPTIONAL_FLOAT if c in header]
    if abc and len(abc) != 3:
        raise DataError(f"{path}: line 1: orientation needs all of a,b,c, got {','.join(abc)}")
    cols = ["x", "y", "z"] + abc
    names, rows = [], []
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        next(reader)
        for row in reader:
            ln = reader.line_num
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise DataError(f"{path}: line {ln}: {len(row)} fields, the header has {len(header)}")
            name = row[header.index("name")].strip()
            if not name:
                raise DataError(f"{path}: line {ln}, column 'name': empty")
            if name in names:
                raise DataError(f"{path}: line {ln}, column 'name': duplicate pose {name!r}")
            vals = []
            for c in cols:
                cell = row[header.index(c)].strip()
                try:
                    v = float(cell)
                except ValueError:
                    raise DataError(f"{path}: line {ln}, column {c!r}: {cell!r} is not a number") from None
                if not math.isfinite(v):
                    raise DataError(f"{path}: line {ln}, column {c!r}: {cell!r} is not finite")
                vals.append(v)
            names.append(name)
            rows.append(vals)
    if not rows:
        raise DataError(f"{path}: no poses after the header")
    arr = np.array(rows)
    return names, arr[:, :3], (arr[:, 3:] if abc else None)


# --------------------------------------------------------------------------
# the command
# --------------------------------------------------------------------------


def _parse_limits(items) -> dict[str, float]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--limit must be KEY=VALUE, got {item!r}")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ConfigError(f"--limit {key.strip()}: {value!r} is not a number") from None
    return out


def _iso9283(args: argparse.Namespace) -> int:
    from station.analysis.iso9283 import analyze_iso9283, check_limits

    limits = _parse_limits(args.limit)
    if args.limit_mm is not None:
        if not (math.isfinite(args.limit_mm) and args.limit_mm > 0):
            raise ConfigError(f"--limit-mm must be a number > 0, got {args.limit_mm!r}")
        limits.setdefault("RP_mm", args.limit_mm)
    limits = check_limits(limits)
    band = args.band or ("limit" if args.limit_mm is not None else "own")
    if band == "limit" and args.limit_mm is None:
        raise ConfigError("--band limit needs --limit-mm")
    names, cmd, cori = read_poses_csv(args.poses)
    data = read_stream_csv(args.stream)
    order = None
    if args.order:
        order = [s.strip() for s in args.order.split(",") if s.strip()]
        unknown = [s for s in order if s not in names]
        if unknown:
            raise ConfigError(f"--order names unknown pose(s) {', '.join(unknown)} (poses: {', '.join(names)})")
    pairs = "auto"
    if args.distance is not None:
        pairs = []
        for item in args.distance:
            ab = [s.strip() for s in item.split(",")]
            if len(ab) != 2 or not all(ab):
                raise ConfigError(f"--distance must be A,B, got {item!r}")
            pairs.append(tuple(ab))
    ori = None
    if "a" in data:
        ori = np.radians(np.stack([data["a"], data["b"], data["c"]], axis=1))
    xyz = np.stack([data["x"], data["y"], data["z"]], axis=1)
    if not data["valid"].all():
        xyz[~data["valid"]] = 0.0  # rows left out by valid; never used
        if ori is not None:
            ori[~data["valid"]] = 0.0
    res = analyze_iso9283(
        data["t"], xyz, cmd, names=names, order=order, valid=data["valid"],
        orientation_rad=ori, commanded_orientation_rad=None if cori is None else np.radians(cori),
        limits=limits, band_mm=args.limit_mm if band == "limit" else None, distance_pairs=pairs,
        linear_paths=bool(args.linear_paths),
        extraction=dict(window_s=args.window_s, velocity_step_s=args.velocity_step_s,
                        assign_tol_mm=args.assign_tol_mm),
    )
    print(format_table(res, args.stream))
    if args.json is not None:
        tmp = args.json.with_name(args.json.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(res.to_dict(), f, indent=1)
            f.write("\n")
        os.replace(tmp, args.json)
        print(f"results written to {args.json}")
    return 1 if res.passed is False else 0


def _n(x, fmt="{:.3f}"):
    return "-" if x is None else fmt.format(x)


def format_table(res, stream_name="stream") -> str:
    """Human-readable summary of an :class:`Iso9283Result`."""
    from station.analysis.iso9283 import conformance_text

    ex = res.extraction
    st = ex.stops
    lines = [
        f"ISO 9283 analysis of {stream_name}: {ex.n_rows} rows ({ex.n_rows - ex.n_used} flagged invalid) at "
        f"{ex.params.rate_hz:.1f} Hz, {ex.n_cycles} cycles, {st.n} stops, {len(ex.missing)} missing, "
        f"{ex.gaps.n} gaps ({int(ex.gaps.splits.sum())} beam breaks)",
        f"window 2M+1 = {2 * ex.params.M + 1} samples, step Mp = {ex.params.Mp}; order "
        f"{','.join(ex.names[k] for k in ex.order)}",
        "",
        f"{'pose':<6}{'n':>5}{'AP_mm':>9}{'RP_mm':>9}{'POS_mm':>9}{'PST_s':>8}{'band_mm':>9} {'src':<7}"
        f"{'vAP_mm':>8}{'dirs':>5}",
    ]
    for name, pr in res.poses.items():
        acc, rep, ovs, md = pr.accuracy, pr.repeatability, pr.overshoot, pr.multidirectional
        lines.append(
            f"{name:<6}{pr.n_cycles:>5}{_n(acc.AP_mm if acc else None):>9}{_n(rep.RP_mm if rep else None):>9}"
            f"{_n(ovs.POS_mm if ovs else None):>9}{_n(ovs.PST_s if ovs else None):>8}"
            f"{_n(ovs.band_mm if ovs else None):>9} {(ovs.band_source if ovs else '-'):<7}"
            f"{_n(md.vAP_mm):>8}{md.n_directions:>5}"
        )
    for d in res.distances:
        lines.append(f"distance {d.pose_a}-{d.pose_b}: Dc {d.Dc_mm:.3f} mm, AD {d.AD_mm:+.3f} mm, "
                     f"RD +/-{_n(d.RD_mm)} mm (n={d.n})")
    for m in res.posing_times:
        lines.append(f"MPT {m.from_pose}->{m.to_pose}: {_n(m.MPT_s)} s (mean of {m.n} of {m.n_available})")
    for pa in res.paths:
        lines.append(f"path {pa.from_pose}->{pa.to_pose}: AT {pa.AT_mm:.3f} mm, RT {_n(pa.RT_mm)} mm (n={pa.n})")
    for name, pr in res.poses.items():
        if pr.orientation is not None:
            o = pr.orientation
            ap = "-" if o.AP_rad is None else ", ".join(f"{math.degrees(v):+.4f}" for v in o.AP_rad)
            rp = ", ".join(f"{math.degrees(v):.4f}" for v in o.RP_rad)
            lines.append(f"orientation {name}: AP(a,b,c) {ap} deg, RP(a,b,c) {rp} deg")
        if pr.drift is not None:
            lines.append(f"drift {name}: dAP {pr.drift.dAP_mm:.4f} mm, dRP {pr.drift.dRP_mm:.4f} mm "
                         f"over {pr.drift.AP_mm.size} blocks")
    if res.verdicts:
        lines.append("")
        for v in res.verdicts:
            mark = "PASS" if v.passed else ("FAIL" if v.passed is False else "N/A ")
            lines.append(f"{mark} {v.characteristic:<8} {v.subject:<8} {_n(v.value, '{:.4f}'):>9} <= {v.limit:g}"
                         + (f"  ({v.note})" if v.note else ""))
        lines.append(f"overall: {'PASS' if res.passed else ('FAIL' if res.passed is False else 'not decided')}")
    for m in ex.missing[:20]:
        lines.append(f"missing: cycle {m.cycle} {m.pose}: {m.reason}")
    if len(ex.missing) > 20:
        lines.append(f"missing: ... {len(ex.missing) - 20} more (see the JSON)")
    for w in res.warnings:
        lines.append(f"warning: {w}")
    if res.partial:
        lines.append("PARTIAL RESULT: some characteristics or stops are missing (see warnings)")
    lines.append(conformance_text(res.iso_reasons))
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    from station.cli import main

    sys.exit(main(["analyze", *sys.argv[1:]]))
