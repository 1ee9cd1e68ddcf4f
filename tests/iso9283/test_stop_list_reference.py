"""The batched stop-list path (issue 47 item 10) against the per-pose reference it replaced.

:mod:`tests.iso9283.stop_list_reference` keeps the reader, the analysis and the JSON as they were,
one row and one pose at a time. On random stop lists (approach labels, several reflectors, far
stops, missing and repeated cycles, limits, distance pairs) the station's results must give the
same JSON text to the last digit, the same refusals with the same words, and the JSON written in
pieces must be the text ``json.dumps`` gives of the whole.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from station.analysis.iso9283.stop_list import analyze_stop_list
from station.errors import DataError
from station.json_pieces import Pieces, dump_json
from station.numeric import finite_list, finite_or_none
from station.readers.stop_list import read_stop_list
from station.readers.stream_csv import read_poses_csv
from tests.iso9283 import stop_list_reference as ref


def _random_list(rng):
    """A stop list as arrays: a few to a few hundred poses, each with its own cycles, approaches and faults."""
    P = int(rng.integers(1, 300)) if rng.random() < 0.7 else int(rng.integers(1, 6))
    names = [f"P{int(i)}" for i in rng.permutation(10 * P)[:P]]
    cmd = rng.uniform(-1500.0, 1500.0, (P, 3))
    R = int(rng.choice([1, 1, 3, 4]))
    shape = rng.normal(0.0, 40.0, (R, 3))  # the reflectors on the flange
    labels = ["+x", "-y", "+z"][:int(rng.integers(1, 4))] if rng.random() < 0.4 else None
    n_cyc = int(rng.integers(1, 35))
    pose, cycle, app, pts = [], [], [], []
    for i, name in enumerate(names):  # loop over poses: their stops
        if rng.random() < 0.03:
            continue  # a pose without a stop
        for c in range(1, n_cyc + 1):
            if rng.random() < 0.05:
                continue  # a missing stop
            for lab in (labels or [None]):
                if lab is not None and lab != labels[0] and rng.random() < 0.5:
                    continue
                cyc = c if rng.random() > 0.01 or lab is not None else int(rng.integers(1, n_cyc + 1))
                pose.append(name)
                cycle.append(cyc)
                app.append(lab)
                off = 100.0 if rng.random() < 0.02 else 0.0  # far from its pose
                pts.append(cmd[i] + shape + rng.normal(0.0, 0.03, (R, 3)) * 10.0 ** rng.uniform(-2, 1) + off)
    if not pose:
        pose, cycle, app, pts = [names[0]], [1], [labels and labels[0]], [cmd[0] + shape]
    order = rng.permutation(len(pose)) if rng.random() < 0.5 else np.arange(len(pose))
    pts = np.array(pts)[order]
    refl = tuple(f"S{j}" for j in range(R)) if R > 1 else ("",)
    return dict(pose=[pose[k] for k in order], cycle=np.array(cycle)[order], points_mm=pts,
                approach=None if labels is None else [app[k] for k in order], reflectors=refl,
                commanded_mm=cmd if rng.random() < 0.8 else None, names=names)


def _options(rng, names):
    limits = {}
    for key in ("AP_mm", "RP_mm", "vAP_mm", "RPa_deg", "AD_mm", "RD_mm", "PST_s"):
        if rng.random() < 0.3:
            limits[key] = float(rng.uniform(0.01, 0.5))
    pairs = "auto"
    if len(names) >= 2 and rng.random() < 0.5:
        pairs = [tuple(str(x) for x in rng.choice(names, 2, replace=False)) for _ in range(int(rng.integers(1, 3)))]
    return dict(limits=limits, distance_pairs=pairs, assign_tol_mm=float(rng.choice([25.0, 0.05, 1.0])))


def _run(analyze, to_dict, args, opts):
    try:
        res = analyze(args["pose"], args["cycle"], args["points_mm"],
                      commanded_mm=args["commanded_mm"], names=args["names"] if args["commanded_mm"] is not None else None,
                      approach=args["approach"], reflectors=args["reflectors"], **opts)
    except (DataError, ValueError) as exc:
        return f"{type(exc).__name__}: {exc}"
    return json.dumps(to_dict(res), indent=1)


def test_the_json_of_random_stop_lists_equals_the_per_pose_reference_to_the_last_digit(rng):
    for _ in range(25):  # loop over random stop lists
        args = _random_list(rng)
        if args["names"] and rng.random() < 0.2:
            args["names"] = args["names"][:]  # the same poses
        opts = _options(rng, list(dict.fromkeys(args["pose"])) if args["commanded_mm"] is None else args["names"])
        want = _run(ref.analyze_stop_list, ref.result_to_dict, args, opts)
        got = _run(analyze_stop_list, lambda r: r.to_dict(), args, opts)
        assert got == want


def _csv(rng, args) -> list[list[str]]:
    header = ["pose", "cycle", "x", "y", "z"]
    R = args["points_mm"].shape[1]
    if R > 1:
        header.append("reflector")
    if args["approach"] is not None:
        header.append("approach")
    rows = [header]
    for k, p in enumerate(args["pose"]):  # loop over stops: a row per reflector
        for j in rng.permutation(R):
            row = [p, str(int(args["cycle"][k]))] + [f"{v:.{int(rng.integers(1, 9))}f}" for v in args["points_mm"][k, j]]
            if R > 1:
                row.append(args["reflectors"][j])
            if args["approach"] is not None:
                row.append(args["approach"][k])
            rows.append(row)
    return rows


#: what a fault puts in a cell
_FAULTS = ["", " ", "x", "1e400", "nan", "-inf", "2e6", "1.5", "-1", "1000001", "7", "P1", "\"q,\"", "1_0", " 3 ",
           "0x10", "+x"]


def _read_both(path):
    out = []
    for reader in (ref.read_stop_list, read_stop_list):
        try:
            sl = reader(path)
        except DataError as exc:
            out.append(f"DataError: {exc}")
            continue
        out.append((sl.pose, sl.cycle.tolist(), sl.points_mm.tolist(), sl.reflectors, sl.approach, sl.lines.tolist(),
                    sl.source, sl.points_mm.dtype, sl.cycle.dtype, sl.lines.dtype))
    return out


def test_the_reader_gives_the_reference_stops_and_refusals(rng, tmp_path):
    path = tmp_path / "stops.csv"
    for trial in range(60):  # loop over random files, most with faults
        args = _random_list(rng)
        if args["points_mm"].shape[0] > 400:
            continue
        rows = _csv(rng, args)
        for _ in range(int(rng.integers(0, 3)) if trial % 4 else 0):  # faults in random cells and lines
            i = int(rng.integers(0, len(rows)))
            kind = rng.random()
            if kind < 0.6:
                rows[i] = rows[i][:]
                rows[i][int(rng.integers(0, len(rows[i])))] = str(rng.choice(_FAULTS))
            elif kind < 0.75:
                # a row twice (the header when nothing else is left: an earlier fault cut the list short)
                rows.insert(i, rows[i][:] if i or len(rows) < 2 else rows[1][:])
            elif kind < 0.85:
                rows[i] = rows[i][:-1]  # a field short
            elif kind < 0.92 and i:
                rows[i] = []  # an empty line
            else:
                del rows[max(i, 1):]  # cut short (perhaps no stops at all)
        text = "\n".join(",".join(r) for r in rows) + ("\n" if rng.random() < 0.8 else "")
        if rng.random() < 0.2:
            text = text.replace("\n", "\r\n")
        path.write_text(text, encoding="utf-8")
        want, got = _read_both(path)
        if isinstance(want, str):
            assert got == want
        else:
            assert got[:7] == want[:7] and got[7:] == want[7:]


def test_the_poses_reader_gives_the_reference_poses_and_refusals(rng, tmp_path):
    path = tmp_path / "poses.csv"
    for trial in range(80):  # loop over random files, most with faults
        P = int(rng.integers(0, 40))
        header = ["name", "x", "y", "z"] + (["a", "b", "c"] if rng.random() < 0.3 else [])
        if rng.random() < 0.05:
            header = header[:5]  # a without b, c
        rows = [header] + [[f"P{i}"] + [f"{v:.{int(rng.integers(0, 7))}f}" for v in rng.uniform(-2000, 2000, len(header) - 1)]
                           for i in range(P)]
        for _ in range(int(rng.integers(0, 3)) if trial % 4 else 0):  # faults in random cells and lines
            i = int(rng.integers(0, len(rows)))
            kind = rng.random()
            if kind < 0.6:
                rows[i] = rows[i][:]
                rows[i][int(rng.integers(0, len(rows[i])))] = str(rng.choice(_FAULTS + ["4000", "P3", "-3599"]))
            elif kind < 0.8 and len(rows) > 1:
                rows.insert(i, rows[max(i, 1)][:])  # a pose twice
            else:
                rows[i] = rows[i][:-1]  # a field short
        path.write_text("\n".join(",".join(r) for r in rows) + "\n", encoding="utf-8")
        out = []
        for reader in (ref.read_poses_csv, read_poses_csv):
            try:
                names, xyz, abc = reader(path)
                out.append((names, xyz.tolist(), None if abc is None else abc.tolist(), xyz.flags.c_contiguous))
            except DataError as exc:
                out.append(f"DataError: {exc}")
        assert out[1] == out[0]


@pytest.mark.parametrize("nd", [None, 0, 4, 6])
def test_finite_list_equals_round_on_halves_and_huge_numbers(rng, nd):
    """Python's ``round`` (correctly rounded decimal) for every number, ties and near-ties included."""
    k = np.arange(-20000, 20000)
    a = np.concatenate([
        (k + 0.5) / 10.0 ** (nd or 0),                                   # halves of the last decimal
        np.nextafter((k + 0.5) / 10.0 ** (nd or 0), np.inf), np.nextafter((k + 0.5) / 10.0 ** (nd or 0), -np.inf),
        rng.normal(0.0, 1.0, 20000) * 10.0 ** rng.uniform(-12.0, 20.0, 20000),
        [0.0, -0.0, 1.0 / 128, -1.0 / 128, 2.0 ** 53, 1e300, -1e300, 5e-324, np.nan, np.inf, -np.inf],
    ])
    got = finite_list(a, nd)
    want = [finite_or_none(x, nd) for x in a.tolist()]
    assert json.dumps(got) == json.dumps(want)
    assert [type(x) for x in got] == [type(x) for x in want]


def test_the_json_written_in_pieces_is_the_whole_dump(rng):
    for _ in range(10):  # loop over random stop lists
        args = _random_list(rng)
        opts = _options(rng, list(dict.fromkeys(args["pose"])) if args["commanded_mm"] is None else args["names"])
        try:
            res = analyze_stop_list(args["pose"], args["cycle"], args["points_mm"], commanded_mm=args["commanded_mm"],
                                    names=args["names"] if args["commanded_mm"] is not None else None,
                                    approach=args["approach"], reflectors=args["reflectors"], **opts)
        except DataError:
            continue
        extra = {"input": {"file": "x\u00e9\"\n\x00"}, "exit": {"code": 3, "reasons": ["a", "b"]}}
        want = json.dumps({**res.to_dict(), **extra})
        d = res.to_dict(poses_per_piece=int(rng.integers(1, 50)))
        assert isinstance(d["poses"], Pieces) and len(d["poses"]) == len(res.poses)
        fh = io.StringIO()
        dump_json(fh, {**d, **extra})
        assert fh.getvalue() == want
        assert json.dumps(d["poses"].whole()) == json.dumps(json.loads(want)["poses"])
