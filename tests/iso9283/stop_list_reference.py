"""The stop list's and the poses file's readers and the analysis as they were before issue 47 item 10's batching: the per-pose reference.

Kept for the tests only (:mod:`tests.iso9283.test_stop_list_reference`): the reader, the
analysis and the JSON built one row, one pose at a time, as they stood at commit 29ae52d. The
station's batched forms must give the same JSON to the last digit and the same refusals.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from station import characteristics as table
from station.analysis.iso9283.characteristics import (
    ISO_CYCLES,
    fold_warnings,
    listed,
    ApproachGroup,
    DistanceAR,
    LeftOut,
    LimitCheck,
    MultiDirectional,
    OrientationAR,
    PoseAccuracy,
    PoseRepeatability,
    PoseResult,
    _verdicts,
    check_limits,
    figures_dict,
    multidirectional_accuracy,
)
from station.analysis.iso9283.stop_list import StopListResult, orientation_by_rigid_fit, rows_by_label
from station.errors import ConfigError, DataError, InsufficientDataError
from station.numeric import finite_list, finite_or_none
from station.readers import stop_list as reader
from station.readers.stop_list import MAX_CYCLE, OPTIONAL, REQUIRED
from station.readers.stream_csv import ORIENTATION
from station.readers.text import MAX_ABS_MM, MAX_ROWS, csv_records, parse_number
from station.verdict import Outcome
from pathlib import Path


def result_to_dict(self) -> dict:
    """The JSON of a :class:`StopListResult`, one pose at a time (:func:`figures_dict`)."""
    return {
        **figures_dict(self, "0-based stop of the stop list", source="stop list"),
        "stops": {
            "n": len(self.stop_pose), "reflectors": list(self.reflectors), "assign_tol_mm": finite_or_none(self.assign_tol_mm, 6),
            "pose": list(self.stop_pose), "cycle": np.asarray(self.stop_cycle, dtype=np.int64).tolist(),
            "approach": None if self.stop_approach is None else list(self.stop_approach),
            "x_mm": finite_list(self.stop_position_mm[:, 0]), "y_mm": finite_list(self.stop_position_mm[:, 1]),
            "z_mm": finite_list(self.stop_position_mm[:, 2]), "fit_rms_mm": finite_list(self.stop_fit_rms_mm),
            "distance_to_pose_mm": finite_list(self.stop_distance_mm), "far": np.asarray(self.stop_far, dtype=bool).tolist(),
        },
    }



def _groups(k_pose: np.ndarray, approach) -> list[tuple[str, np.ndarray]]:
    """(label, stops) per approach label, in order of first appearance."""
    if approach is None:
        return [("-", k_pose)] if k_pose.size else []
    labels: dict[str, list[int]] = {}
    for k in k_pose:
        labels.setdefault(approach[k], []).append(int(k))
    return [(lab, np.array(ks, dtype=np.int64)) for lab, ks in labels.items()]


def analyze_stop_list(
    pose,
    cycle,
    points_mm,
    *,
    commanded_mm=None,
    names=None,
    approach=None,
    reflectors=None,
    limits=None,
    distance_pairs="auto",
    assign_tol_mm: float = 25.0,
) -> StopListResult:
    """ISO 9283 pose characteristics of a stop list, with verdicts.

    Parameters
    ----------
    pose : sequence of str, length K
        Commanded pose of each stop.
    cycle : array_like of int, shape (K,)
    points_mm : array_like, shape (K, R, 3)
        Each stop's R reflector positions (R = 1 without reflectors), mm, in the
        frame of ``commanded_mm``.
    commanded_mm : array_like, shape (P, 3), optional
        Commanded positions of the poses ``names`` (AP and AD need them).
    names : sequence of str, length P
        Pose names of ``commanded_mm`` (required with it).
    approach : sequence of str, length K, optional
        Approach label of each stop (vAP; AP and RP take the most frequent).
    reflectors : sequence of str, length R, optional
    limits : dict, optional
        ``{key: limit}`` as in :func:`station.analysis.iso9283.analyze_iso9283`.
    distance_pairs : "auto", None or sequence of (name, name)
    assign_tol_mm : float
        A stop farther than this from its commanded pose is left out of every
        statistic (a wrong frame or a wrong pose name).

    Returns
    -------
    StopListResult
    """
    lim = check_limits(limits)
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[1] < 1:
        raise DataError(f"points_mm must have shape (K, R, 3), got {pts.shape}")
    K = pts.shape[0]
    if K == 0:
        raise InsufficientDataError("the stop list has no stops")
    if not np.all(np.isfinite(pts)):
        raise DataError("points_mm contains NaN or inf")
    pose = tuple(str(p) for p in pose)
    cyc = np.asarray(cycle, dtype=np.int64)
    if len(pose) != K or cyc.shape != (K,):
        raise DataError(f"pose and cycle need {K} entries like points_mm, got {len(pose)} and {cyc.shape}")
    if approach is not None:
        approach = tuple(str(a) for a in approach)
        if len(approach) != K:
            raise DataError(f"approach needs {K} entries, got {len(approach)}")
    if not (math.isfinite(assign_tol_mm) and assign_tol_mm > 0):
        raise ConfigError(f"assign_tol_mm must be finite and > 0, got {assign_tol_mm!r}")
    cmd = None
    if commanded_mm is not None:
        cmd_arr = np.asarray(commanded_mm, dtype=float)
        if names is None or cmd_arr.shape != (len(names), 3) or not np.all(np.isfinite(cmd_arr)):
            raise DataError("commanded_mm must be finite with shape (P, 3) and come with P names")
        cmd = {str(n): cmd_arr[i] for i, n in enumerate(names)}
        unknown = sorted({p for p in pose if p not in cmd})
        if unknown:
            raise DataError(f"the stop list names pose(s) {', '.join(unknown)} that the commanded poses lack "
                            f"(have {', '.join(cmd)})")
    R = pts.shape[1]
    refl = tuple(reflectors) if reflectors is not None else tuple(str(k) for k in range(R))
    centroid = pts.mean(axis=1)
    warnings: list[str] = []
    few: list[tuple[int, str]] = []  # (index in warnings, "pose n") of the poses of fewer than ISO_CYCLES cycles
    partial = False
    left: list[LeftOut] = []

    def leave(k, stats, reason):
        left.append(LeftOut(int(k), math.nan, pose[k], int(cyc[k]), stats, reason))

    dist = np.full(K, np.nan)
    far = np.zeros(K, bool)
    if cmd is not None:
        dist = np.linalg.norm(centroid - np.array([cmd[p] for p in pose]), axis=1)
        far = dist > assign_tol_mm
        for k in np.flatnonzero(far):
            leave(k, "all", f"{dist[k]:.3f} mm from its commanded pose {pose[k]}, farther than the assignment "
                            f"tolerance {assign_tol_mm:g} mm")
    order = list(cmd) if cmd is not None else list(dict.fromkeys(pose))
    by_pose = rows_by_label(pose)
    fit_rms = np.full(K, np.nan)
    poses: dict[str, PoseResult] = {}
    primary: dict[str, np.ndarray] = {}
    picked = []
    for name in order:  # loop over poses: the stops of each and its main approach
        k_pose = by_pose.get(name, np.zeros(0, np.int64))
        k_pose = k_pose[~far[k_pose]]
        k_pose = k_pose[np.argsort(cyc[k_pose], kind="stable")]
        groups = _groups(k_pose, approach)
        if groups:
            gp = int(np.argmax([kg.size for _, kg in groups]))  # ties: the first to appear
            kp = groups[gp][1]
        else:
            gp, kp = -1, np.zeros(0, np.int64)
        primary[name] = kp
        for g, (lab, kg) in enumerate(groups):
            if g != gp:
                for k in kg:
                    leave(k, "AP, RP, AD, RD, orientation",
                          f"approached from {lab} ({kg.size} stop(s)); {name}'s main direction is {groups[gp][0]} "
                          f"({kp.size} stops); vAP uses it")
        picked.append((name, groups, gp, kp))
    stats = _pose_statistics(centroid, [kp for _, _, _, kp in picked],
                             None if cmd is None else np.array([cmd[name] for name in order]))
    for (name, groups, gp, kp), (acc, rep, mean) in zip(picked, stats):  # loop over poses: their results
        ck = cyc[kp]  # in cycle order (sorted above): a repeated cycle is next to itself
        if kp.size > 1 and bool(np.any(ck[1:] == ck[:-1])):
            raise DataError(f"pose {name}: a cycle appears twice among the stops of one approach")
        a = centroid[kp]
        if not kp.size:
            warnings.append(f"{name}: no stop, AP and RP not computed")
            partial = True
        elif kp.size == 1:
            warnings.append(f"{name}: RP needs at least 2 stops, got 1")
            partial = True
        if 0 < kp.size < ISO_CYCLES:
            few.append((len(warnings), f"{name} {kp.size}"))
            warnings.append(f"{name}: {kp.size} cycles; ISO 9283 prescribes {ISO_CYCLES}")
        gl = tuple(ApproachGroup(lab, np.zeros(3), mean.copy() if kg is kp else centroid[kg].mean(axis=0),
                                 int(kg.size), kg) for lab, kg in groups)
        vap = vany = pair = None
        if len(gl) >= 2:
            vany, (h, k2) = multidirectional_accuracy(np.array([g.mean_mm for g in gl]))
            pair = (gl[h].label, gl[k2].label)
            if len(gl) >= 3:
                vap = vany
        oar = None
        if R >= 3 and kp.size >= 2:
            try:
                abc, rms = orientation_by_rigid_fit(pts[kp])
            except DataError as exc:
                raise DataError(f"pose {name}: {exc}") from None
            fit_rms[kp] = rms
            S = abc.std(axis=0, ddof=1)
            oar = OrientationAR(None, 3.0 * S, abc.mean(axis=0), S, int(kp.size), kp)
        poses[name] = PoseResult(
            name, None if cmd is None else cmd[name].copy(), a, np.full(kp.size, np.nan), kp, cyc[kp],
            acc, rep, None, MultiDirectional(vap, vany, gl, pair), oar, None,
        )
    warnings[:] = fold_warnings(warnings, [i for i, _ in few],
                                f"{len(few)} poses of fewer than {ISO_CYCLES} cycles ({listed(f for _, f in few)}); "
                                f"ISO 9283 prescribes {ISO_CYCLES}")
    dists = _distances(poses, primary, cyc, centroid, cmd, distance_pairs, warnings, leave)
    if any(d.RD_mm is None for d in dists):
        partial = True
    verdicts = []
    stream_only = {c.key for c in table.characteristics() if c.needs_stream}
    for v in _verdicts(lim, SimpleNamespace(poses=poses, distances=dists)):
        if v.outcome is Outcome.NOT_DECIDED and v.characteristic in stream_only:
            v = LimitCheck(v.characteristic, v.subject, None, v.limit, Outcome.NOT_DECIDED,
                           "needs a stream: a stop list has one "
                           "point per stop" if not v.characteristic.startswith("AP") else
                           "needs the reflectors' nominal positions on the tool")
        elif v.outcome is Outcome.NOT_DECIDED and v.characteristic in ("AP_mm", "AD_mm") and cmd is None:
            v = LimitCheck(v.characteristic, v.subject, None, v.limit, Outcome.NOT_DECIDED,
                           "needs the commanded poses (--poses)")
        verdicts.append(v)
    if any(v.outcome is Outcome.NOT_DECIDED for v in verdicts):
        partial = True
    reasons = _conformance(poses, primary, cyc, far, verdicts, lim)
    left.sort(key=lambda x: (x.row, x.statistics))
    return StopListResult(
        poses=poses, distances=tuple(dists), verdicts=tuple(verdicts), limits=lim, warnings=tuple(warnings),
        partial=bool(partial or far.any()), iso_conformant=not reasons, iso_reasons=tuple(reasons),
        left_out=tuple(left), stop_pose=pose, stop_cycle=cyc, stop_approach=approach, stop_position_mm=centroid,
        stop_fit_rms_mm=fit_rms, stop_distance_mm=dist, stop_far=far, reflectors=refl,
        assign_tol_mm=float(assign_tol_mm),
    )


def _pose_statistics(centroid, kps, cmd) -> list[tuple]:
    """``(accuracy, repeatability, mean)`` of every pose from its stops ``kps[i]``: AP, eq. (1) (with the commanded
    positions ``cmd`` (P, 3), else None), RP, eq. (2) (None below 2 stops), the barycentre (None without a stop).

    The figures of :func:`position_accuracy` and :func:`position_repeatability` to the bit, for the poses of
    one number of stops at once: a stop list of 100,000 poses spent most of its time in their per-pose calls.
    """
    out: list[tuple] = [(None, None, None)] * len(kps)
    by_n: dict[int, list[int]] = {}
    for i, kp in enumerate(kps):
        if kp.size:
            by_n.setdefault(int(kp.size), []).append(i)
    for n, idx in by_n.items():  # loop over the numbers of stops: the poses with n stops at once
        X = centroid[np.array([kps[i] for i in idx])]                      # (G, n, 3)
        means = X.mean(axis=1)
        d = None if cmd is None else means - cmd[idx]
        if n >= 2:
            L = np.linalg.norm(X - means[:, None, :], axis=2)
            lb = L.mean(axis=1)
            S = np.sqrt(np.sum((L - lb[:, None]) ** 2, axis=1) / (n - 1))
        for j, i in enumerate(idx):  # loop over those poses: their result records
            kp, m = kps[i], means[j]
            acc = rep = None
            if d is not None:
                acc = PoseAccuracy(float(np.linalg.norm(d[j])), float(d[j, 0]), float(d[j, 1]), float(d[j, 2]),
                                   m.copy(), n, kp)
            if n >= 2:
                lbj, Sj = float(lb[j]), float(S[j])
                rep = PoseRepeatability(lbj + 3.0 * Sj, lbj, Sj, L[j].copy(), n, kp)
            out[i] = (acc, rep, m)
    return out


def _distances(poses, primary, cyc, centroid, cmd, distance_pairs, warnings, leave) -> list[DistanceAR]:
    """AD and RD, eqs. (8)-(9), over the cycles where both poses were attained (main approach)."""
    names = list(poses)
    if distance_pairs == "auto":
        distance_pairs = [("P2", "P4")] if {"P2", "P4"} <= set(names) else []
    out = []
    for pa, pb in distance_pairs or []:
        for q in (pa, pb):
            if q not in names:
                raise ConfigError(f"distance pair names unknown pose {q!r}")
        ka, kb = primary[pa], primary[pb]
        common, ja, jb = np.intersect1d(cyc[ka], cyc[kb], return_indices=True)
        for k in np.concatenate([np.delete(ka, ja), np.delete(kb, jb)]):
            other = pb if k in ka else pa
            leave(k, f"AD, RD {pa}-{pb}", f"{other} has no stop in cycle {int(cyc[k])}")
        if common.size < 1:
            warnings.append(f"AD/RD {pa}-{pb}: no cycle with both poses")
            continue
        D = np.linalg.norm(centroid[ka[ja]] - centroid[kb[jb]], axis=1)
        Dc = float(np.linalg.norm(cmd[pa] - cmd[pb])) if cmd is not None else None
        AD = float(D.mean() - Dc) if Dc is not None else None
        RD = float(3.0 * np.std(D, ddof=1)) if D.size >= 2 else None
        if RD is None:
            warnings.append(f"RD {pa}-{pb}: needs at least 2 cycles with both poses, got 1")
        out.append(DistanceAR(pa, pb, Dc, AD, RD, D, common, ka[ja], kb[jb], int(D.size)))
    return out


def _conformance(poses, primary, cyc, far, verdicts, limits) -> list[str]:
    """Why the stop list is not ISO 9283 conformant, one sentence each (as for a stream)."""
    reasons = []
    short = [f"{n} {pr.n_cycles}" for n, pr in poses.items() if pr.n_cycles < ISO_CYCLES]
    if short:
        reasons.append(f"fewer than {ISO_CYCLES} cycles at {listed(short)}")
    all_cycles = set()
    for kp in primary.values():
        all_cycles.update(cyc[kp].tolist())
    gaps = []
    for n, kp in primary.items():
        lack = sorted(all_cycles.difference(cyc[kp].tolist()))
        if lack:
            gaps.append(f"{n} in cycle(s) {', '.join(str(c) for c in lack)}")
    if gaps:
        reasons.append("missing stops: " + "; ".join(gaps))
    if far.any():
        reasons.append(f"{int(far.sum())} stop(s) far from their commanded pose")
    undecided = [f"{v.characteristic} {v.subject}" + (f" ({v.note})" if v.note else "")
                 for v in verdicts if v.outcome is Outcome.NOT_DECIDED]
    if undecided:
        reasons.append("limit(s) not decided: " + "; ".join(undecided))
    unevaluated = sorted(set(limits) - {v.characteristic for v in verdicts})
    if unevaluated:
        reasons.append("limit(s) given for characteristics this analysis did not compute: " + ", ".join(unevaluated))
    return reasons


def _stop_name(pose: str, cycle: int, approach: str | None) -> str:
    return f"pose {pose} cycle {cycle}" + ("" if approach is None else f" approach {approach}")


def read_stop_list(path) -> StopList:
    """Read a stop list CSV; DataError naming file, line and column for anything malformed."""
    p = Path(path)
    rows = []
    for ln, c in csv_records(p, REQUIRED, what="a stop list", optional=OPTIONAL):
        if not c["pose"]:
            raise DataError(f"{p}: line {ln}, column 'pose': empty")
        try:
            cyc = int(c["cycle"][:40])
        except ValueError:
            raise DataError(f"{p}: line {ln}, column 'cycle': {c['cycle'][:40]!r} is not an integer") from None
        if not 0 <= cyc <= MAX_CYCLE:
            raise DataError(f"{p}: line {ln}, column 'cycle': {cyc} is not a cycle number (0 to {MAX_CYCLE})")
        xyz = [parse_number(c[k], p, ln, k) for k in ("x", "y", "z")]
        for k in OPTIONAL:
            if k in c and not c[k]:
                raise DataError(f"{p}: line {ln}, column {k!r}: empty")
        rows.append((c["pose"], cyc, c.get("reflector", ""), c.get("approach"), xyz, ln))
        if len(rows) > MAX_ROWS:
            raise DataError(f"{p}: more than {MAX_ROWS} rows")
    if not rows:
        raise DataError(f"{p}: no stops after the header")
    stops: dict[tuple[str, int, str | None], dict] = {}
    for pose, cyc, refl, app, xyz, ln in rows:
        s = stops.setdefault((pose, cyc, app), {"refl": {}, "line0": ln})
        if refl in s["refl"]:
            raise DataError(f"{p}: line {ln}: {_stop_name(pose, cyc, app)}"
                            + (f" reflector {refl}" if refl else "")
                            + f" appears twice (first on line {s['refl'][refl][1]})")
        s["refl"][refl] = (xyz, ln)
    all_refl = sorted({r for s in stops.values() for r in s["refl"]})
    for (pose, cyc, app), s in stops.items():
        lack = [r for r in all_refl if r not in s["refl"]]
        if lack:
            lines = ", ".join(str(v[1]) for v in s["refl"].values())
            raise DataError(f"{p}: {_stop_name(pose, cyc, app)} (line(s) {lines}) has no row for reflector(s) "
                            f"{', '.join(lack)}; every stop must carry every reflector ({', '.join(all_refl)})")
    keys = list(stops)
    pts = np.array([[stops[k]["refl"][r][0] for r in all_refl] for k in keys], dtype=float)
    lines = np.array([[stops[k]["refl"][r][1] for r in all_refl] for k in keys], dtype=np.int64)
    has_app = rows[0][3] is not None  # the approach column is there (its cells are never empty)
    return reader.StopList(pose=tuple(k[0] for k in keys), cycle=np.array([k[1] for k in keys], dtype=np.int64),
                    points_mm=pts, reflectors=tuple(all_refl),
                    approach=tuple(k[2] for k in keys) if has_app else None,
                    lines=lines, source=str(p))


def read_poses_csv(path) -> tuple[list[str], np.ndarray, np.ndarray | None]:
    """Read ``name,x,y,z[,a,b,c]``; returns names, positions (P,3) mm, orientation (P,3) deg or None.

    Every line bounded and decoded on its own (:func:`~station.readers.text.numbered_lines`).
    """
    path = Path(path)
    need = ("name", "x", "y", "z")
    names, rows, seen = [], [], set()
    cols = None
    for ln, c in csv_records(path, need, what="a poses file"):
        if cols is None:
            abc = [k for k in ORIENTATION if k in c]
            if abc and len(abc) != 3:
                raise DataError(f"{path}: orientation needs all of a,b,c, got {','.join(abc)}")
            cols = ["x", "y", "z"] + abc
        name = c["name"]
        if not name:
            raise DataError(f"{path}: line {ln}, column 'name': empty")
        if name in seen:
            raise DataError(f"{path}: line {ln}, column 'name': duplicate pose {name[:40]!r}")
        seen.add(name)
        names.append(name)
        rows.append([parse_number(c[k], path, ln, k, MAX_ABS_MM if k in "xyz" else 3600.0) for k in cols])
        if len(rows) > MAX_ROWS:
            raise DataError(f"{path}: more than {MAX_ROWS} poses")
    if not rows:
        raise DataError(f"{path}: no poses after the header")
    arr = np.array(rows)
    return names, arr[:, :3], (arr[:, 3:] if len(cols) > 3 else None)
