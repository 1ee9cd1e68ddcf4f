"""The JSON of many poses' results at once: :func:`pose_dicts` gives the dicts of :func:`pose_to_dict`, to the last digit.

A stop list of 100,000 poses spent a third of its time on the JSON: some forty
calls per pose, each rounding an array of one to three numbers. Here the
numbers of a batch of poses are gathered into a few arrays, rounded at once
(:func:`station.numeric.finite_list`) and handed out per pose. A pose with
overshoot or drift figures (a stream's) takes :func:`pose_to_dict` itself.
"""

from __future__ import annotations

import numpy as np

from station import characteristics as table
from station.analysis.iso9283.characteristics import PoseResult, orientation_to_dict, pose_to_dict
from station.numeric import finite_list, finite_or_none

_NAN3 = (np.nan, np.nan, np.nan)
_NAN4 = (np.nan,) * 4

#: the keys of :func:`pose_to_dict`'s own, in its order (the table's other pose figures follow them)
KEYS = ("commanded_mm", "n_cycles", "AP_mm", "APx_mm", "APy_mm", "APz_mm", "mean_mm", "RP_mm", "l_bar_mm", "S_l_mm",
        "POS_mm", "PST_s", "band_mm", "band_source", "approach", "overshoot_per_cycle", "vAP_mm", "n_directions",
        "directions", "attained", "orientation", "drift")


def _ints(arrays) -> list:
    return np.concatenate([np.asarray(a).ravel() for a in arrays]).astype(np.int64).tolist() if arrays else []


def pose_dicts(prs: list[PoseResult]) -> list[dict]:
    """``[pose_to_dict(pr) for pr in prs]``, the numbers of all poses rounded together."""
    simple = [pr.overshoot is None and pr.drift is None
              and pr.attained_mm.shape[0] == np.size(pr.attained_t_s) == np.size(pr.attained_cycle) == pr.n_cycles
              for pr in prs]
    batch = [pr for pr, s in zip(prs, simple) if s]
    if not batch:
        return [pose_to_dict(pr) for pr in prs]
    # the numbers of every pose in a few arrays: commanded (3); AP and its axes, RP's three (7); vAP; mean (3)
    cmd = finite_list(np.array([_NAN3 if pr.commanded_mm is None else pr.commanded_mm for pr in batch], dtype=float))
    rows7 = []
    for pr in batch:  # loop over poses: their seven numbers
        a, r = pr.accuracy, pr.repeatability
        rows7.append(((a.AP_mm, a.APx_mm, a.APy_mm, a.APz_mm) if a else _NAN4)
                     + ((r.RP_mm, r.l_bar_mm, r.S_l_mm) if r else _NAN3))
    scal = finite_list(np.array(rows7, dtype=float))
    vap = finite_list(np.array([np.nan if pr.multidirectional.vAP_mm is None else pr.multidirectional.vAP_mm
                                for pr in batch], dtype=float))
    means = []  # (3,) or None per pose, as pose_to_dict states it
    for pr in batch:  # loop over poses: the barycentre AP's or RP's
        means.append(pr.accuracy.mean_mm if pr.accuracy else
                     (None if pr.repeatability is None else pr.attained_mm.mean(axis=0)))
    mean = finite_list(np.array([_NAN3 if m is None else m for m in means], dtype=float))
    groups = [g for pr in batch for g in pr.multidirectional.groups]
    g_dir = finite_list(np.array([g.direction for g in groups], dtype=float).reshape(-1, 3), 4)
    g_mean = finite_list(np.array([g.mean_mm for g in groups], dtype=float).reshape(-1, 3))
    g_rows = [np.asarray(g.rows).astype(np.int64).tolist() for g in groups]
    att = np.concatenate([pr.attained_mm.reshape(-1, 3) for pr in batch]) if batch else np.zeros((0, 3))
    ax, ay, az = finite_list(att[:, 0]), finite_list(att[:, 1]), finite_list(att[:, 2])
    at = finite_list(np.concatenate([np.asarray(pr.attained_t_s, dtype=float).ravel() for pr in batch]))
    arow = _ints([pr.attained_row for pr in batch])
    acyc = _ints([pr.attained_cycle for pr in batch])
    extra, seen = [], set(KEYS)  # the table's other pose figures, the first of a key (as _with_figures adds them)
    for c in table.characteristics():
        if c.level == "pose" and c.in_json and c.key not in seen:
            extra.append(c)
            seen.add(c.key)
    out: list[dict] = []
    i = o = g0 = 0  # the pose, its first attained stop and first group in the batch's arrays
    for pr, s in zip(prs, simple):  # loop over poses: their dicts from the rounded numbers
        if not s:
            out.append(pose_to_dict(pr))
            continue
        n, md, sc = pr.n_cycles, pr.multidirectional, scal[7 * i:7 * i + 7]
        acc, rep, ng = pr.accuracy is not None, pr.repeatability is not None, len(md.groups)
        d = {
            "commanded_mm": None if pr.commanded_mm is None else cmd[3 * i:3 * i + 3],
            "n_cycles": n,
            "AP_mm": sc[0] if acc else None, "APx_mm": sc[1] if acc else None,
            "APy_mm": sc[2] if acc else None, "APz_mm": sc[3] if acc else None,
            "mean_mm": None if means[i] is None else mean[3 * i:3 * i + 3],
            "RP_mm": sc[4] if rep else None, "l_bar_mm": sc[5] if rep else None, "S_l_mm": sc[6] if rep else None,
            "POS_mm": None, "PST_s": None, "band_mm": None, "band_source": None, "approach": None,
            "overshoot_per_cycle": None,
            "vAP_mm": vap[i],
            "n_directions": ng,
            "directions": [
                {"label": g.label, "direction": g_dir[3 * j:3 * j + 3], "mean_mm": g_mean[3 * j:3 * j + 3], "n": g.n,
                 "rows": g_rows[j]} for j, g in zip(range(g0, g0 + ng), md.groups)
            ],
            "attained": {"x_mm": ax[o:o + n], "y_mm": ay[o:o + n], "z_mm": az[o:o + n], "t_s": at[o:o + n],
                         "row": arow[o:o + n], "cycle": acyc[o:o + n]},
            "orientation": None if pr.orientation is None else orientation_to_dict(pr.orientation, md),
            "drift": None,
        }
        for c in extra:  # loop over the table's other pose figures (as _with_figures adds them)
            d[c.key] = finite_or_none(c.value(pr), 6)
        out.append(d)
        i, o, g0 = i + 1, o + n, g0 + ng
    return out
