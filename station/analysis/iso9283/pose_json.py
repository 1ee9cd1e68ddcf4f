"""The JSON text of many poses' results at once: :func:`pose_texts` gives ``json.dumps(pose_to_dict(pr))``,
character for character.

A stop list of 100,000 poses spent a third of its time on the JSON: some forty
calls per pose, each rounding an array of one to three numbers, then a dict of
some thirty keys per pose for the encoder. Here the numbers of a batch of poses
are gathered into a few arrays, rounded at once
(:func:`station.numeric.finite_list`) and written into each pose's text. A pose
with overshoot or drift figures (a stream's) takes :func:`pose_to_dict` itself.
"""

from __future__ import annotations

import json
from json.encoder import encode_basestring_ascii as _str  # json.dumps's own encoding of a string

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


def _texts(a, nd: int | None = 6) -> list[str]:
    """The JSON text of each number of ``a`` as :func:`finite_list` gives it (``null`` for NaN and infinity)."""
    out = list(map(repr, finite_list(a, nd)))
    if "None" in out:
        out = ["null" if t == "None" else t for t in out]
    return out


def _int_texts(arrays) -> list[str]:
    return list(map(repr, np.concatenate([np.asarray(a).ravel() for a in arrays]).astype(np.int64).tolist())) \
        if arrays else []


def _is_simple(pr: PoseResult) -> bool:
    """A pose of one attained point per cycle and no overshoot or drift figures (a stop list's)."""
    return (pr.overshoot is None and pr.drift is None and pr.attained_mm.ndim == 2
            and len(pr.attained_mm) == len(pr.attained_t_s) == len(pr.attained_cycle) == len(pr.attained_row))


def pose_texts(prs: list[PoseResult]) -> list[str]:
    """``[json.dumps(pose_to_dict(pr)) for pr in prs]``, the numbers of all poses rounded together."""
    simple = [_is_simple(pr) for pr in prs]
    batch = [pr for pr, s in zip(prs, simple) if s]
    # the numbers of every pose in a few arrays: commanded (3); AP and its axes, RP's three (7); vAP; mean (3)
    cmd = _texts(np.array([_NAN3 if pr.commanded_mm is None else pr.commanded_mm for pr in batch], dtype=float))
    rows7, means = [], []
    for pr in batch:  # loop over poses: their seven numbers and their barycentre, as pose_to_dict states them
        a, r = pr.accuracy, pr.repeatability
        rows7.append(((a.AP_mm, a.APx_mm, a.APy_mm, a.APz_mm) if a else _NAN4)
                     + ((r.RP_mm, r.l_bar_mm, r.S_l_mm) if r else _NAN3))
        means.append(a.mean_mm if a else (None if r is None else pr.attained_mm.mean(axis=0)))
    scal = _texts(np.array(rows7, dtype=float))
    mean = _texts(np.array([_NAN3 if m is None else m for m in means], dtype=float))
    vap = _texts(np.array([np.nan if pr.multidirectional.vAP_mm is None else pr.multidirectional.vAP_mm
                           for pr in batch], dtype=float))
    groups = [g for pr in batch for g in pr.multidirectional.groups]
    g_dir = _texts(np.array([g.direction for g in groups], dtype=float).reshape(-1, 3), 4)
    g_mean = _texts(np.array([g.mean_mm for g in groups], dtype=float).reshape(-1, 3))
    g_rows = [", ".join(map(repr, np.asarray(g.rows).astype(np.int64).tolist())) for g in groups]
    att = np.concatenate([pr.attained_mm.reshape(-1, 3) for pr in batch]) if batch else np.zeros((0, 3))
    ax, ay, az = _texts(att[:, 0]), _texts(att[:, 1]), _texts(att[:, 2])
    at = _texts(np.concatenate([np.asarray(pr.attained_t_s, dtype=float).ravel() for pr in batch])) if batch else []
    arow = _int_texts([pr.attained_row for pr in batch])
    acyc = _int_texts([pr.attained_cycle for pr in batch])
    extra, seen = [], set(KEYS)  # the table's other pose figures, the first of a key (as _with_figures adds them)
    for c in table.characteristics():
        if c.level == "pose" and c.in_json and c.key not in seen:
            extra.append(c)
            seen.add(c.key)
    join = ", ".join
    out: list[str] = []
    i = o = g0 = 0  # the pose, its first attained stop and first group in the batch's arrays
    for pr, s in zip(prs, simple):  # loop over poses: their text from the rounded numbers
        if not s:
            out.append(json.dumps(pose_to_dict(pr)))
            continue
        n, md, sc = pr.n_cycles, pr.multidirectional, scal[7 * i:7 * i + 7]
        if pr.accuracy is None:
            sc[:4] = ("null",) * 4
        if pr.repeatability is None:
            sc[4:] = ("null",) * 3
        ng = len(md.groups)
        dirs = join([f'{{"label": {_str(g.label)}, "direction": [{join(g_dir[3 * j:3 * j + 3])}], '
                     f'"mean_mm": [{join(g_mean[3 * j:3 * j + 3])}], "n": {int(g.n)!r}, "rows": [{g_rows[j]}]}}'
                     for j, g in enumerate(md.groups, g0)])
        text = (
            f'{{"commanded_mm": {"null" if pr.commanded_mm is None else "[" + join(cmd[3 * i:3 * i + 3]) + "]"}, '
            f'"n_cycles": {n!r}, "AP_mm": {sc[0]}, "APx_mm": {sc[1]}, "APy_mm": {sc[2]}, "APz_mm": {sc[3]}, '
            f'"mean_mm": {"null" if means[i] is None else "[" + join(mean[3 * i:3 * i + 3]) + "]"}, '
            f'"RP_mm": {sc[4]}, "l_bar_mm": {sc[5]}, "S_l_mm": {sc[6]}, "POS_mm": null, "PST_s": null, '
            f'"band_mm": null, "band_source": null, "approach": null, "overshoot_per_cycle": null, '
            f'"vAP_mm": {vap[i]}, "n_directions": {ng!r}, "directions": [{dirs}], '
            f'"attained": {{"x_mm": [{join(ax[o:o + n])}], "y_mm": [{join(ay[o:o + n])}], '
            f'"z_mm": [{join(az[o:o + n])}], "t_s": [{join(at[o:o + n])}], "row": [{join(arow[o:o + n])}], '
            f'"cycle": [{join(acyc[o:o + n])}]}}, '
            f'"orientation": {"null" if pr.orientation is None else json.dumps(orientation_to_dict(pr.orientation, md))}, '
            f'"drift": null'
        )
        for c in extra:  # loop over the table's other pose figures
            text += f", {_str(c.key)}: {json.dumps(finite_or_none(c.value(pr), 6))}"
        out.append(text + "}")
        i, o, g0 = i + 1, o + n, g0 + ng
    return out
