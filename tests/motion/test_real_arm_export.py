"""The lab's export through ``station diagnose motion`` gives the diagnosis of the recording itself.

A look-alike of issue 42's UR arm (tests/motion/real_arm.py) is diagnosed twice: in memory on its true clock
(``diagnose_motion(ra.t_s, ra.xyz_mm, ra.poses_mm, ...)``) and at the command line on what the lab hands over:
the SpatialAnalyzer export with 1 s PC stamps (the clock inferred from the program's dwells), the poses file
and the program. Both must refit the same baseline (the loop's frequency and damping, the profile's jerk
time), name the same effects and state the same held-out error: the file path adds nothing but the clock's
inference and the files' rounding (the export's 1 nm, the poses file's 0.1 um).

The two paths' inputs are the same samples on the same clock (the dwells give 1000/3 Hz to 1e-13; the export
rounds the coordinates to 1 nm). Their baselines still differed (draw 17 at 100 %: 27.8 Hz, damping 0.185 in
memory, 27.6 Hz, 0.054 through the export): the baseline's fit stalled, on one path and not the other, on the
jerk time's bound 0, where its gradient vanishes (:func:`station.analysis.motion.diagnose._baseline`). (The
figure of 14.9 Hz, 0.79 quoted for draw 23 in memory against the command line's 27.8 Hz, 0.048 is the
training-supported model's loop, ``res.supported``; the two paths' baselines were the same there.)
"""

from __future__ import annotations

import json

import pytest

from app.cli import main

from .real_arm import draw, make, write_export, write_poses, write_program

#: The two paths' baselines, measured on 10 draws at 100 % (default_rng 5, 11, 17, 23 and 101-106) with the
#: baseline refitted from its best starts: held-out RMS within 0.15 % (9 of 10 within 0.003 %); loop frequency
#: within 11 % (draw 105: 9.7 against 8.7 Hz; 8 of 10 within 0.5 %), damping within 11 % (draw 11: 0.035 against
#: 0.031, at the floor of 0.03), jerk time within 10 ms (draw 105); the same effects named on all 10. The
#: baseline's loop is not pinned down by these recordings (without the creep and the mode it lies in a flat
#: valley, 12-28 Hz at the damping's floor, within 0.5 % of RSS): its prediction is, so the held-out RMS has
#: the tight bound.
#: Before the fit left the jerk time's bound, draw 17 gave damping 0.185 against 0.054 and held-out RMS 33.7
#: against 32.7 um, draw 5 damping 0.057 against 0.043 (at 50 %, draw 23: held-out RMS 34.9 against 26.4 um).
#: So the prediction is compared tightly and the loop's damping only within a factor (a stalled fit differed by
#: 3.4x); its frequency and the jerk time, which the flat valley leaves free, are not compared.
HELDOUT_REL = 0.01
DAMPING_FACTOR = 2.0


@pytest.mark.timeout(900)  # two diagnoses: slow on a shared machine
def test_export_and_memory_give_the_same_baseline(tmp_path, rng):
    """One draw at 100 % speed: the command line on the lab's files and the in-memory diagnosis refit the same
    baseline and name the same effects (tolerances and their measured spread above).

    The extended model's held-out RMS is not compared: the candidates' refits start from the baseline's jerk
    time and can stall as the baseline's did (draw 11: 1.08 against 1.20 um, draw 5: 1.10 against 1.04 um).
    """
    from station.analysis.motion.diagnose import diagnose_motion

    ra = make(draw(rng, speed=1.0))
    res = diagnose_motion(ra.t_s, ra.xyz_mm, ra.poses_mm, ["P1", "P2"])
    out = tmp_path / "d.json"
    assert main(["diagnose", "motion", "--stream", str(write_export(tmp_path / "lab.txt", ra)),
                 "--poses", str(write_poses(tmp_path / "poses.csv", ra)),
                 "--program", str(write_program(tmp_path / "prog.toml", ra)), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["time_refused"] is None and doc["rate_hz"] == pytest.approx(1000.0 / 3.0, rel=1e-6), doc["time_base"]
    mem, cli = res.baseline.named("servo"), doc["baseline"]["servo"]
    assert doc["simulation_heldout_rms"] == pytest.approx(res.simulation_heldout_rms, rel=HELDOUT_REL), (mem, cli)
    assert 1.0 / DAMPING_FACTOR <= cli["damping"] / mem["damping"] <= DAMPING_FACTOR, (mem, cli, ra.truth)
    assert [s["effect"] for s in doc["steps"]] == res.named, (res.named, doc["steps"])
    assert [m["move"] for m in doc["heldout_moves"]] == [int(res.windows.move_index[i]) + 1 for i in res.heldout]
