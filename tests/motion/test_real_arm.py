"""Issue 42's acceptance on look-alikes of the lab's real UR arm (tests/motion/real_arm.py, not the diagnosis's
closed forms): the creep predicts the held-out moves at 0.7x the simulation's error or better, and a dry run with
its model (``simulate iso9283 --program ... --motion-model M``) gives MPT within 20 % of the recording's (PST:
no model can, see the test and bench/bench_pst_dry_run.py).
A cause is named on every draw, and the named model predicts the held-out moves at 0.7x the simulation's error
or better: on the lab's six moves a speed the held-out test is cross-fitted (every fold of moves held out once,
station/analysis/motion/diagnose.py ``_CrossFit``); with the two held-out moves alone it passed on 7 of 8 draws
at 100 % speed. bench/bench_real_arm_naming.py: the creep first on 8 of 8 draws at each speed; the harness of the
closing note, draws 200-211: a cause named on all 23 diagnosed (the creep first on all 12 at 100 %).

"Measured" and "dry run" figures come from one analysis: the diagnosis's windows and approach figures
(:mod:`station.analysis.motion.windows`, :mod:`station.analysis.motion.figures`: PST and MPT into a 0.02 mm band,
and the time from 0.1 to 0.02 mm) over every move of each recording, averaged per pose. Every parameter of the
look-alike is drawn from the test's ``rng`` (replay with ``--seed``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from station.analysis.motion.figures import approach_figures, mean_figures
from station.analysis.motion.windows import cut_windows

from .real_arm import draw, make, read_dry_run, write_export, write_poses, write_program

#: the issue's acceptance: held-out error of the extended model against the simulation's (baseline's)
HELDOUT_RATIO = 0.7
#: ... and the dry run's PST and MPT against the measured ones
FIGURE_REL = 0.2


def figures(t, xyz, poses, names) -> dict:
    """Per pose, the mean approach figures of every move of a recording."""
    w = cut_windows(t, xyz, poses, names)
    per: dict = {}
    for i in range(w.n):
        m = np.isfinite(w.x_mm[i])
        per.setdefault(w.to_pose[i], []).append(approach_figures(w.t_s[i][m], w.x_mm[i][m], w.t_leave_s[i]))
    return {k: mean_figures(v) for k, v in per.items()}


@pytest.mark.timeout(1500)  # a diagnosis and a simulation: slow on a shared machine
@pytest.mark.parametrize("speed", [1.0, 0.5])
def test_real_arm_lookalike(tmp_path, rng, test_seed, speed, capsys):
    from station.analysis.motion.diagnose import diagnose_motion

    ra = make(draw(rng, speed=speed))
    res = diagnose_motion(ra.t_s, ra.xyz_mm, ra.poses_mm, ["P1", "P2"])
    # the creep, tested first against the refitted baseline, predicts the held-out moves at 0.7x the
    # simulation's error or better, and passes the training moves' F test
    creep = next(ct for ct in res.rounds[0] if ct.effect == "creep")
    assert creep.significant, (ra.truth, creep.to_json())
    assert creep.heldout_rms_after <= HELDOUT_RATIO * res.simulation_heldout_rms, (
        creep.heldout_rms_after, res.simulation_heldout_rms)
    # a cause is named, and the named model predicts the held-out moves at 0.7x the simulation's error or better
    assert res.named and set(res.named) <= {"creep", "structural_mode", "tracker_drift"}, (
        ra.truth, [ct.to_json() for ct in res.rounds[0]])
    assert res.final_heldout_rms <= HELDOUT_RATIO * res.simulation_heldout_rms, (
        res.final_heldout_rms, res.simulation_heldout_rms)
    # ... judged cross-fitted: the held-out moves and the other folds' cover every move once, per pair a fold
    folds = [[m - 1 for m in f["heldout_moves"]] for f in res.cross_fit["folds"]]
    every = sorted(int(res.windows.move_index[i]) for i in res.heldout) + [m for f in folds for m in f]
    assert sorted(every) == sorted(int(k) for k in res.windows.move_index), res.cross_fit
    assert all(len(f) == 2 for f in folds) and creep.cross_fitted
    # the dry run: the lab's program replayed on the simulated UR5e with the model the training moves support
    # (the named effects and those significant on training alone: the creep alone left the ring to the loop,
    # which then overshot into the band)
    params = res.supported
    # ... which extends the named model by effects not named
    assert params.active == res.final.active + res.supported_only and not set(res.named) & set(res.supported_only)
    # written as the lab would: `diagnose motion` on the lab's export (its clock checked by the program's dwells)
    model = tmp_path / "m.json"
    capsys.readouterr()
    assert main(["diagnose", "motion", "--stream", str(write_export(tmp_path / "lab.txt", ra)),
                 "--poses", str(write_poses(tmp_path / "poses.csv", ra)),
                 "--program", str(write_program(tmp_path / "prog.toml", ra)),
                 "--model-out", str(model), "--model-basis", "supported"]) == 0
    doc = json.loads(model.read_text())
    # (the same samples through the lab's files, the clock inferred and the coordinates rounded to 1 nm: a
    # marginal F test need not fall the same way)
    assert doc["basis"] == "training_supported" and set(doc["not_confirmed"]) <= set(doc["effects"])
    print("the CLI's model:", json.dumps(doc["effects"]), "above:", res.supported_only, res.named)
    prog_rate = write_program(tmp_path / "prog_rate.toml", ra, rate_hz=1000.0 / 3.0)
    capsys.readouterr()
    assert main(["simulate", "iso9283", "--out", str(tmp_path / "sim"), "--program", str(prog_rate),
                 "--motion-model", str(model), "--seed", str(test_seed)]) == 0
    meas = figures(ra.t_s, ra.xyz_mm, ra.poses_mm, ["P1", "P2"])
    dry = figures(*read_dry_run(tmp_path / "sim"))
    for pose in ("P1", "P2"):
        m, s = meas[pose], dry[pose]
        assert m["MPT_s"] is not None and s["MPT_s"] is not None, (meas, dry)
        assert abs(s["MPT_s"] - m["MPT_s"]) <= FIGURE_REL * m["MPT_s"], (pose, meas, dry)
    # PST and the time from 0.1 to 0.02 mm are NOT asserted. With the creep's model alone, draw 23
    # (default_rng(23), 100 %) gave PST 0.25 s against 0.034 s measured at P1 (the loop, refitted at 12.8 Hz,
    # 0.57 for 15.3 Hz, 0.84, overshot into the band at once); with the supported model the PST is the tracker's
    # noise crossing the band's edge where the approach's staircase levels out within micrometres of it (noise
    # and wander off, the arm's PST and the dry run's are both 0): the arm's own expected PST rose 28-34 % for its
    # ring 10 % larger, and three moves a pose measure it to about +-50 % (bench/bench_pst_dry_run.py)


def test_the_export_is_the_labs_shape(tmp_path, rng):
    """The look-alike's export is the lab's shape: 1 s stamps of 66-444 samples, 1000/3 Hz found by the dwells."""
    from app.commands.analyze_inputs import load_stream

    ra = make(draw(rng), effects=())
    stream = write_export(tmp_path / "lab.txt", ra)
    assert ra.per_stamp[:-1].min() >= 66 and ra.per_stamp[:-1].max() <= 444  # the last: what is left
    si = load_stream(stream, rate_hz=None, command="test", wait_s=ra.wait_s)
    assert not si.refused and 1.0 / float(np.median(np.diff(si.t_s))) == pytest.approx(1000.0 / 3.0, rel=1e-3)
