"""ISO 9283 pose characteristics from a stop list: one averaged point per stop (and per reflector).

Many tracker measurements are not a stream but one point per stop, averaged by
the tracker software while the robot dwells. Each stop names its pose and
cycle; with several reflectors on the flange (three SMRs, the usual way to
get orientation) each stop carries one point per reflector.

* A stop's position is the reflectors' centroid. Position accuracy AP, eq. (1),
  needs the commanded pose; repeatability RP, eq. (2), does not.
* AD and RD, eqs. (8)-(9), between two poses over the cycles where both were
  attained (AD needs the commanded distance).
* With an ``approach`` label per stop: the stops of the pose's most frequent
  approach give AP and RP (ISO 9283: one approach direction), and vAP,
  eq. (7), is the largest distance between the approach groups' barycentres
  (three directions needed, as in the seed).
* With three or more reflectors: the reflector set of each stop is fitted
  rigidly (least squares, :func:`station.analysis.registration.fit_rigid`) to
  the mean reflector set of its pose; the rotation of each stop, as angles
  ``a, b, c`` about the frame's x, y, z (``R = Rz(c) Ry(b) Rx(a)``), gives the
  orientation repeatability ``RPa, RPb, RPc = 3 S`` per angle. Orientation
  accuracy needs the reflectors' nominal positions on the tool and is not
  computed.

POS, PST, MPT, drift and paths need a stream; limits for them are undecided.
The result has the JSON keys of the stream analysis
(:func:`station.analysis.iso9283.analyze_iso9283`); ``row`` numbers are
stops of the list (0-based).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from collections.abc import Iterator
from types import SimpleNamespace

import numpy as np

from station import characteristics as table
from station.analysis.iso9283.characteristics import (
    ISO_CYCLES,
    fold_warnings,
    listed,
    ApproachGroup,
    Judged,
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
    position_accuracy,
    position_repeatability,
)
from station.analysis.iso9283.pose_json import pose_texts
from station.analysis.registration import fit_rigid
from station.errors import ConfigError, DataError, InsufficientDataError
from station.json_pieces import Pieces
from station.numeric import finite_list, finite_or_none
from station.verdict import Outcome


#: poses whose JSON is made at a time (their numbers rounded together)
POSES_PER_BATCH = 4096


@dataclass(frozen=True)
class StopListResult(Judged):
    """Characteristics of a stop list; :meth:`to_dict` gives the JSON (keys of the stream analysis)."""

    poses: dict[str, PoseResult]
    distances: tuple[DistanceAR, ...]
    verdicts: tuple[LimitCheck, ...]
    limits: dict[str, float]
    warnings: tuple[str, ...]
    partial: bool
    iso_conformant: bool
    iso_reasons: tuple[str, ...]
    left_out: tuple[LeftOut, ...]
    #: per stop (K,): pose, cycle, approach label, centroid (K, 3), rms of the rigid fit of its reflectors (NaN
    #: with fewer than 3), distance to its commanded pose (NaN without poses), far from its pose
    stop_pose: tuple[str, ...] = ()
    stop_cycle: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    stop_approach: tuple[str, ...] | None = None
    stop_position_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    stop_fit_rms_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stop_distance_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stop_far: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    reflectors: tuple[str, ...] = ()
    assign_tol_mm: float = math.nan

    @property
    def n_far(self) -> int:
        return int(np.count_nonzero(self.stop_far))

    def to_dict(self, poses_per_piece: int | None = None) -> dict:
        """The JSON; with ``poses_per_piece`` its ``poses`` are :class:`~station.json_pieces.Pieces`, made that many
        at a time as :func:`~station.json_pieces.dump_json` writes them."""
        poses = Pieces(len(self.poses), lambda: self._pose_batches(poses_per_piece or POSES_PER_BATCH))
        if poses_per_piece is None:
            poses = poses.whole()
        return {
            **figures_dict(self, "0-based stop of the stop list", poses=poses, source="stop list"),
            "stops": {
                "n": len(self.stop_pose), "reflectors": list(self.reflectors), "assign_tol_mm": finite_or_none(self.assign_tol_mm, 6),
                "pose": list(self.stop_pose), "cycle": np.asarray(self.stop_cycle, dtype=np.int64).tolist(),
                "approach": None if self.stop_approach is None else list(self.stop_approach),
                "x_mm": finite_list(self.stop_position_mm[:, 0]), "y_mm": finite_list(self.stop_position_mm[:, 1]),
                "z_mm": finite_list(self.stop_position_mm[:, 2]), "fit_rms_mm": finite_list(self.stop_fit_rms_mm),
                "distance_to_pose_mm": finite_list(self.stop_distance_mm), "far": np.asarray(self.stop_far, dtype=bool).tolist(),
            },
        }


    def _pose_batches(self, n: int) -> Iterator[list[tuple[str, str]]]:
        """The poses' names and JSON texts (:func:`pose_texts`), ``n`` poses at a time."""
        names = list(self.poses)
        for a in range(0, len(names), n):  # loop over batches of poses
            part = names[a:a + n]
            yield list(zip(part, pose_texts([self.poses[k] for k in part])))


def rotation_abc(R) -> np.ndarray:
    """Angles ``(a, b, c)``, rad, of ``R = Rz(c) Ry(b) Rx(a)`` (rotations about x, y, z of the frame)."""
    R = np.asarray(R, dtype=float)
    a = math.atan2(R[2, 1], R[2, 2])
    b = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    c = math.atan2(R[1, 0], R[0, 0])
    return np.array([a, b, c])


def orientation_by_rigid_fit(points_mm) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angles of each stop's reflector set against the mean set, and the fit rms.

    Parameters
    ----------
    points_mm : array_like, shape (n, R, 3)
        The R >= 3 reflectors of n stops.

    Returns
    -------
    abc_rad : ndarray (n, 3)
        ``(a, b, c)`` of the rotation taking the mean set onto each stop's set.
    rms_mm : ndarray (n,)
        Rms residual of each rigid fit (a reflector that moved on the flange shows here).
    """
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 3 or pts.shape[1] < 3 or pts.shape[2] != 3:
        raise DataError(f"points_mm must have shape (n, R >= 3, 3), got {pts.shape}")
    ref = pts.mean(axis=0)
    out = np.zeros((pts.shape[0], 3))
    rms = np.zeros(pts.shape[0])
    for k in range(pts.shape[0]):  # loop over stops (one 3x3 SVD each)
        try:
            reg = fit_rigid(ref, pts[k])
        except InsufficientDataError:
            raise DataError("the reflectors lie on one line: their set gives no orientation") from None
        out[k] = rotation_abc(reg.R)
        rms[k] = reg.rms_mm
    return out, rms


def rows_by_label(labels) -> dict[str, np.ndarray]:
    """The rows of each label (ascending), labels in order of first appearance.

    One pass over the rows: a scan of every row per label took K x P steps (100,000 poses, over a minute).
    """
    rows: dict[str, list[int]] = {}
    for k, lab in enumerate(labels):
        rows.setdefault(lab, []).append(k)
    return {lab: np.array(ks, dtype=np.int64) for lab, ks in rows.items()}


@dataclass(frozen=True)
class PoseGroups:
    """The stops of each pose by approach (:func:`_pose_groups`)."""

    #: per pose: its groups ``[(label, stops)]`` (stops in cycle order) in order of first appearance, and the
    #: index of its main group (the largest; ties: the first to appear; -1 without a stop)
    per_pose: list[tuple[list[tuple[str, np.ndarray]], int]]
    #: the poses whose main group holds a cycle twice
    repeated: set[str]


def _pose_groups(order, pose, cyc, far, approach) -> PoseGroups:
    """Each pose's stops (of ``order``; those ``far`` left out) by approach label (``"-"`` without labels): one
    sort of all stops by pose, cycle and row, then by the first appearance of each pose's labels in that order.

    One pass over the stops: a scan of every stop per pose took K x P steps (100,000 poses, over a minute).
    """
    K, P = len(pose), len(order)
    number = {name: i for i, name in enumerate(order)}
    pidx = np.fromiter((number.get(p, P) for p in pose), np.int64, K)
    ids: dict[str, int] = {}
    lab = np.zeros(K, np.int64) if approach is None else \
        np.fromiter((ids.setdefault(a, len(ids)) for a in approach), np.int64, K)
    labels = ["-"] if approach is None else list(ids)
    kept = np.flatnonzero(~far & (pidx < P))
    s = kept[np.lexsort((cyc[kept], pidx[kept]))]  # by pose, cycle, row
    _, first, inv = np.unique(pidx[s] * len(labels) + lab[s], return_index=True, return_inverse=True)
    rank = np.empty(first.size, np.int64)
    rank[np.argsort(first)] = np.arange(first.size)  # groups in order of first appearance
    grank = rank[inv.ravel()]
    o = np.argsort(grank, kind="stable")
    s, grank = s[o], grank[o]
    starts = np.searchsorted(grank, np.arange(first.size + 1))
    g_pose = pidx[s[starts[:-1]]]
    g_lab = lab[s[starts[:-1]]].tolist()
    g_at = np.searchsorted(g_pose, np.arange(P + 1)).tolist()  # groups g_at[i]:g_at[i + 1] are pose i's
    sizes = np.diff(starts).tolist()
    st = starts.tolist()
    cs = cyc[s]
    twice = set(grank[1:][(grank[1:] == grank[:-1]) & (cs[1:] == cs[:-1])].tolist())
    per_pose, repeated = [], set()
    for i, name in enumerate(order):  # loop over poses: their groups
        ga, gb = g_at[i], g_at[i + 1]
        groups = [(labels[g_lab[g]], s[st[g]:st[g + 1]]) for g in range(ga, gb)]
        gp = -1
        if groups:
            n = sizes[ga:gb]
            gp = n.index(max(n))  # ties: the first to appear
            if ga + gp in twice:
                repeated.add(name)
        per_pose.append((groups, gp))
    return PoseGroups(per_pose, repeated)


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
        cmd_row = {str(n): i for i, n in enumerate(names)}  # a name given twice: its last row
        cmd = {n: cmd_arr[i] for n, i in cmd_row.items()}
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
        dist = np.linalg.norm(centroid - cmd_arr[np.fromiter((cmd_row[p] for p in pose), np.int64, K)], axis=1)
        far = dist > assign_tol_mm
        for k in np.flatnonzero(far):
            leave(k, "all", f"{dist[k]:.3f} mm from its commanded pose {pose[k]}, farther than the assignment "
                            f"tolerance {assign_tol_mm:g} mm")
    order = list(cmd) if cmd is not None else list(dict.fromkeys(pose))
    fit_rms = np.full(K, np.nan)
    poses: dict[str, PoseResult] = {}
    primary: dict[str, np.ndarray] = {}
    picked = []
    pg = _pose_groups(order, pose, cyc, far, approach)
    for name, (groups, gp) in zip(order, pg.per_pose):  # loop over poses: the stops of each and its main approach
        kp = groups[gp][1] if groups else np.zeros(0, np.int64)
        primary[name] = kp
        for g, (lab, kg) in enumerate(groups):
            if g != gp:
                for k in kg.tolist():
                    leave(k, "AP, RP, AD, RD, orientation",
                          f"approached from {lab} ({kg.size} stop(s)); {name}'s main direction is {groups[gp][0]} "
                          f"({kp.size} stops); vAP uses it")
        picked.append((name, groups, gp, kp))
    stats = _pose_statistics(centroid, [kp for _, _, _, kp in picked],
                             None if cmd is None else cmd_arr[np.fromiter(cmd_row.values(), np.int64, len(order))])
    # the main approach's stops of all poses, one after another: each pose's attained points are a view
    main = np.concatenate([kp for _, _, _, kp in picked]) if picked else np.zeros(0, np.int64)
    att, att_cyc, att_t = centroid[main], cyc[main], np.full(main.size, np.nan)
    at = 0
    for (name, groups, gp, kp), (acc, rep, mean) in zip(picked, stats):  # loop over poses: their results
        n = kp.size
        if n > 1 and name in pg.repeated:
            raise DataError(f"pose {name}: a cycle appears twice among the stops of one approach")
        if not n:
            warnings.append(f"{name}: no stop, AP and RP not computed")
            partial = True
        elif n == 1:
            warnings.append(f"{name}: RP needs at least 2 stops, got 1")
            partial = True
        if 0 < n < ISO_CYCLES:
            few.append((len(warnings), f"{name} {n}"))
            warnings.append(f"{name}: {n} cycles; ISO 9283 prescribes {ISO_CYCLES}")
        gl = tuple(ApproachGroup(lab, np.zeros(3), mean.copy() if kg is kp else centroid[kg].mean(axis=0),
                                 int(kg.size), kg) for lab, kg in groups)
        vap = vany = pair = None
        if len(gl) >= 2:
            vany, (h, k2) = multidirectional_accuracy(np.array([g.mean_mm for g in gl]))
            pair = (gl[h].label, gl[k2].label)
            if len(gl) >= 3:
                vap = vany
        oar = None
        if R >= 3 and n >= 2:
            try:
                abc, rms = orientation_by_rigid_fit(pts[kp])
            except DataError as exc:
                raise DataError(f"pose {name}: {exc}") from None
            fit_rms[kp] = rms
            S = abc.std(axis=0, ddof=1)
            oar = OrientationAR(None, 3.0 * S, abc.mean(axis=0), S, int(n), kp)
        poses[name] = PoseResult(
            name, None if cmd is None else cmd[name].copy(), att[at:at + n], att_t[at:at + n], kp,
            att_cyc[at:at + n], acc, rep, None, MultiDirectional(vap, vany, gl, pair), oar, None,
        )
        at += n
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
        dl = None if d is None else d.tolist()
        lbl, Sl = (lb.tolist(), S.tolist()) if n >= 2 else (None, None)
        for j, i in enumerate(idx):  # loop over those poses: their result records
            kp, m = kps[i], means[j]
            acc = rep = None
            if dl is not None:
                dj = d[j]
                # np.linalg.norm of a vector: the square root of its dot product with itself
                acc = PoseAccuracy(math.sqrt(dj.dot(dj)), *dl[j], m.copy(), n, kp)
            if n >= 2:
                lbj, Sj = lbl[j], Sl[j]
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
    kps = list(primary.values())
    main = np.concatenate(kps) if kps else np.zeros(0, np.int64)
    all_cycles = set(np.unique(cyc[main]).tolist())
    # the poses that may lack a cycle: those with fewer distinct cycles than there are
    sizes = np.array([kp.size for kp in kps], dtype=np.int64)
    owner = np.repeat(np.arange(len(kps)), sizes)
    pairs = np.unique(np.stack([owner, cyc[main]]), axis=1) if main.size else np.zeros((2, 0), np.int64)
    distinct = np.bincount(pairs[0], minlength=len(kps))
    gaps = []
    names = list(primary)
    for i in np.flatnonzero(distinct < len(all_cycles)).tolist():  # loop over the poses short of a cycle
        lack = sorted(all_cycles.difference(cyc[kps[i]].tolist()))
        gaps.append(f"{names[i]} in cycle(s) {', '.join(str(c) for c in lack)}")
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
