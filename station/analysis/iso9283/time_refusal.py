"""Time figures refused where the clock cannot be trusted: all of them, or those across a jump.

PST (eq. (6)) and MPT (eq. (10)) are durations; on a clock that failed its
check (:mod:`station.analysis.iso9283.motion_clock`) or across a jump of the
clock (:mod:`station.analysis.iso9283.clock_jumps`) they are not measurements.
:func:`refuse_time_figures` takes them out of a result (None, per-stop values
NaN), makes their verdicts "not decided" with the reason, and says which it
refused. A pose's PST is refused when the jump lies in any of its stops (not a
mean over the others, which would change the figure silently); an MPT when the
jump lies in the stop the move leaves or reaches. Pure: a result in, a result
out.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from station.verdict import Outcome


def _touched(res, jump_rows) -> tuple[set, set]:
    """(poses whose PST, moves whose MPT) a jump at ``jump_rows`` (stream rows) lies in."""
    ex = res.extraction
    st = ex.stops
    if not st.n:
        return set(), set()
    start = ex.to_rows(st.i_phase_start)
    order = np.argsort(st.row, kind="stable")
    start_o = start[order]
    poses, moves = set(), set()
    names = ex.names
    for r in jump_rows:
        j = int(np.searchsorted(start_o, r, side="right")) - 1  # the stop whose phase holds the jump
        j = max(j, 0)
        for a, b in ((j - 1, j), (j, j + 1)):
            if a < 0 or b >= order.size:
                continue
            pa, pb = int(st.pose[order[a]]), int(st.pose[order[b]])
            if pa >= 0 and pb >= 0:
                moves.add((names[pa], names[pb]))
        p = int(st.pose[order[j]])
        if p >= 0:
            poses.add(names[p])
    return poses, moves


def refuse_time_figures(res, reason: str, jump_rows=None, *, short: str = ""):
    """The result with PST and MPT refused (every one, or those ``jump_rows`` lie in) and the list refused.

    ``reason`` goes into the warnings, ``short`` (default ``reason``) into the
    verdicts' notes. Returns ``(result, refused)``: ``refused`` names each
    figure taken out, e.g. ``PST_s P1``, ``MPT_s P1->P2``.
    """
    if jump_rows is None:
        poses = set(res.poses)
        moves = {(m.from_pose, m.to_pose) for m in res.posing_times}
    else:
        poses, moves = _touched(res, list(jump_rows))
    refused = []
    new_poses = {}
    for name, pr in res.poses.items():
        ovs = pr.overshoot
        if name in poses and ovs is not None and ovs.PST_s is not None:
            ovs = dataclasses.replace(ovs, PST_s=None, PST_j_s=np.full(ovs.PST_j_s.shape, np.nan))
            pr = dataclasses.replace(pr, overshoot=ovs)
            refused.append(f"PST_s {name}")
        new_poses[name] = pr
    mts = []
    for m in res.posing_times:
        if (m.from_pose, m.to_pose) in moves and (m.MPT_s is not None or np.isfinite(m.times_s).any()):
            m = dataclasses.replace(m, MPT_s=None, times_s=np.full(m.times_s.shape, np.nan))
            refused.append(f"MPT_s {m.from_pose}->{m.to_pose}")
        mts.append(m)
    subjects = {("PST_s", p) for p in poses} | {("MPT_s", f"{a}->{b}") for a, b in moves}
    verdicts = tuple(dataclasses.replace(v, value=None, outcome=Outcome.NOT_DECIDED, note=f"refused: {short or reason}",
                                         uncertainty=None, guard_band=None)
                     if (v.characteristic, v.subject) in subjects else v for v in res.verdicts)
    res = dataclasses.replace(res, poses=new_poses, posing_times=tuple(mts), verdicts=verdicts)
    if not refused:  # nothing (more) to refuse: the verdicts only (decided again by a later stage)
        return res, []
    return dataclasses.replace(res, warnings=tuple(res.warnings) + (f"{', '.join(refused)} refused: {reason}",),
                               partial=True, iso_conformant=False,
                               iso_reasons=tuple(res.iso_reasons) + (f"{', '.join(refused)} refused",)), refused
