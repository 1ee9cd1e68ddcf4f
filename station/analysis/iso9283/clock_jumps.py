"""Steps of the stamps where the clock jumped, told from gaps where samples were lost.

A long step between two stamps is either a gap (the beam broke: samples were
lost, the stamps are right) or a jump of the clock (a daylight-saving change,
a date read in the wrong day/month order: no sample was lost, the stamps are
wrong across it). The samples tell which when the tool moves across the step:
after a gap of ``k`` lost samples the tool has moved about ``k + 1`` steps'
worth; after a jump it has moved one step, as on the samples either side. At
rest they cannot tell; a step of a whole number of hours (within two sample
steps) is then read as a jump, as clocks jump by hours and beams do not break
for exactly that long.

A time figure computed across a jump is not a measurement
(:mod:`station.analysis.iso9283.time_refusal` refuses it). Pure: arrays in,
results out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.analysis.iso9283.motion_clock import noise_3d_mm

#: a step longer than this many median steps is a gap or a jump
JUMP_GAP_FACTOR = 5.0
#: the tool moves at least this many times the noise per step on both sides: the motion can tell
MOVING_NOISE_FACTOR = 20.0
#: across a jump the tool moves no more than this many times its step on either side
CONTINUOUS_FACTOR = 2.5
#: a step within this many median steps of a whole number of hours is a jump of the clock
WHOLE_HOURS_STEPS = 2.0


@dataclass(frozen=True)
class ClockJump:
    """A jump of the clock between row ``row - 1`` and ``row`` (indices into the stream): ``step_s`` its size,
    ``evidence`` ``moving`` (the tool moves on across it as on the samples either side) or ``whole hours``."""

    row: int
    step_s: float
    evidence: str

    def to_dict(self) -> dict:
        return {"row": self.row, "step_s": self.step_s, "evidence": self.evidence}

    def text(self) -> str:
        h = self.step_s / 3600.0
        size = f"{self.step_s:+.6g} s" + (f" ({h:+.4g} h)" if abs(h) >= 0.99 else "")
        why = ("the tool moves on across it as on the samples either side, no sample was lost"
               if self.evidence == "moving" else "a whole number of hours while the tool is at rest")
        return f"the clock jumps {size} here ({why}): a daylight-saving change or the wrong --date-order?"


def clock_jumps(t_s, xyz_mm, valid=None) -> tuple[ClockJump, ...]:
    """The jumps of the clock in stamps ``t_s`` (N,) s in order, positions (N, 3) mm, ``valid`` (N,)."""
    t = np.asarray(t_s, dtype=float)
    xyz = np.asarray(xyz_mm, dtype=float)
    if t.size < 4:
        return ()
    ok = np.ones(t.size, bool) if valid is None else np.asarray(valid, bool)
    dt = np.diff(t)
    pos = dt[dt > 0]
    if not pos.size:
        return ()
    med = float(np.median(pos))
    sig = noise_3d_mm(xyz[ok])
    out = []
    for i in np.flatnonzero(dt > JUMP_GAP_FACTOR * med):  # a step between i and i+1
        if i < 1 or i + 2 >= t.size or not ok[i - 1: i + 3].all():
            evidence = None
        else:
            before = np.linalg.norm(xyz[i] - xyz[i - 1])
            after = np.linalg.norm(xyz[i + 2] - xyz[i + 1])
            across = np.linalg.norm(xyz[i + 1] - xyz[i])
            moving = min(before, after) > MOVING_NOISE_FACTOR * max(sig, 1e-12)
            evidence = "moving" if moving and across <= CONTINUOUS_FACTOR * max(before, after) else None
            if moving and evidence is None:
                continue  # the tool moved on by much more than a step: samples were lost
        if evidence is None:
            hours = float(dt[i]) / 3600.0
            if round(hours) >= 1 and abs(float(dt[i]) - 3600.0 * round(hours)) <= WHOLE_HOURS_STEPS * med:
                evidence = "whole hours"
        if evidence is not None:
            out.append(ClockJump(int(i + 1), float(dt[i]), evidence))
    return tuple(out)
