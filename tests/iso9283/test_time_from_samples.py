"""Time from the samples: stamps coarser than the samples are checked against the motion (issue 42, item 1).

The lab look-alike (:mod:`tests.iso9283.ur_lookalike`, not the station's simulator): a UR5e joint move
P1 <-> P2 at 1000/3 Hz with micrometre noise, 2 s waits, 3 cycles, stamped by a PC clock of 1 s resolution
with 66-444 samples a stamp. Its stamps give a rate near 100-150 Hz; the station must either infer 333.3 Hz
from the motion, within the uncertainty it states, or refuse every time figure with the reason.
"""

from __future__ import annotations

import json
from datetime import datetime, timedelta

import numpy as np
import pytest

from app.cli import main
from station.analysis.iso9283.motion_clock import (
    CLOCK_REL_U,
    REST_RADIUS_MM,
    find_moves,
    identical_moves,
    rate_from_dwells,
)

from .labfiles import write_poses, write_sa
from .ur_lookalike import RATE_HZ, lab_lookalike, write_lab_export


def run(capsys, *argv):
    if argv[0] == "iso9283":  # the lab's program starts at rest at P1: its first move is the third P1->P2
        argv = (*argv, "--initial-rest", "count")
    rc = main(["analyze", *map(str, argv)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.fixture(params=[1.0, 0.5], ids=["100pct", "50pct"])
def lab(tmp_path, rng, request):
    la = lab_lookalike(rng, speed=request.param)
    f = write_lab_export(tmp_path / f"ur_{request.param:.0%}.txt", la)
    P = write_poses(tmp_path / "P.csv", ["P1", "P2"], la.poses_mm)
    return la, f, P


def test_the_lookalike_is_what_the_lab_exported(lab):
    la, f, _ = lab
    whole = la.per_stamp[1:-1]
    assert whole.min() == 66 and whole.max() == 444  # 66-444 samples a stamp
    stamp_rate = whole.sum() / whole.size
    assert stamp_rate < 0.9 * RATE_HZ  # the stamps' rate is off the tracker's


def test_without_the_rate_every_time_figure_is_refused_with_the_reason(tmp_path, lab, capsys):
    la, f, P = lab
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--json", tmp_path / "r.json",
                       "--limit", "MPT_s=20")
    assert rc == 3, err
    assert "time figures refused (PST, MPT): the clock failed its check against the motion" in err
    assert "the stamps disagree with the motion" in err and "--dwell-s W" in err and "--rate-hz R" in err
    d = json.loads((tmp_path / "r.json").read_text())
    assert all(p["PST_s"] is None for p in d["poses"].values())
    assert [m["MPT_s"] for m in d["MPT"]] == [None, None]
    assert all(all(x is None for x in m["times_s"]) for m in d["MPT"])
    assert {v["passed"] for v in d["verdicts"] if v["characteristic"] == "MPT_s"} == {None}
    tb = d["time_base"]
    assert tb["source"] == "refused" and tb["rate_hz"] is None
    assert sorted(tb["refused_figures"]) == ["MPT_s P1->P2", "MPT_s P2->P1", "PST_s P1", "PST_s P2"]
    # the evidence: identical moves take the same samples, the stamps give them other durations
    groups = tb["motion_check"]["identical_moves"]
    assert len(groups) == 2 and all(g["n"] == 3 and g["steady"] for g in groups)
    truth = la.samples_outside(REST_RADIUS_MM)  # the micrometre noise leaves the radius at 0.5 mm
    for g in groups:
        assert g["spread_samples"] <= 3
        assert abs(np.median(g["samples"]) - np.median(truth)) <= 3 and np.median(g["samples"]) < la.move_s * RATE_HZ
    ev = tb["motion_check"]["stamps_against_moves"]
    assert ev["n_disagreeing"] >= 1 and ev["n_events"] == 2 * la.n_moves - 1
    # nothing on the console states a time on this clock
    assert "MPT P1->P2: - s" in out and "unknown rate" in out.splitlines()[0]
    assert " s*" not in out and "PST_s*" not in out


def test_the_programs_wait_gives_the_rate_within_its_stated_uncertainty_and_mpt_as_on_the_true_rate(
        tmp_path, lab, capsys):
    la, f, P = lab
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--dwell-s", 2, "--json", tmp_path / "r.json")
    assert rc == 0, err
    d = json.loads((tmp_path / "r.json").read_text())
    tb = d["time_base"]
    assert tb["source"] == "motion_rate"
    assert abs(tb["rate_hz"] - RATE_HZ) <= 2.0 * tb["u_rate_hz"]
    assert tb["u_rate_hz"] == pytest.approx(CLOCK_REL_U * RATE_HZ)
    assert tb["dwell_rate"]["emscon_candidates_hz"] == pytest.approx([RATE_HZ])
    lo, hi = tb["dwell_rate"]["interval_hz"]
    assert lo <= RATE_HZ <= hi and hi < 500.0 and lo > 250.0  # the neighbouring emScon rates are excluded
    assert "the rate INFERRED from the motion: emScon rate 1000/3 Hz" in out and "+/- 0.033 Hz" in out
    assert "identical moves" in out and "The stamps were not used" in out
    # the same MPT as on the true rate; the move takes its profile's time plus settling into the own-RP band
    rc, _, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--rate-hz", repr(RATE_HZ), "--json",
                     tmp_path / "true.json")
    assert rc == 0, err
    ref = json.loads((tmp_path / "true.json").read_text())
    mpt = [m["MPT_s"] for m in d["MPT"]]
    assert mpt == pytest.approx([m["MPT_s"] for m in ref["MPT"]], rel=3 * CLOCK_REL_U)
    for m in mpt:  # never the 14 s of the stamps' clock: the move (less its ends inside the bands), then settling
        assert 0.95 * la.move_s < m < la.move_s + la.dwell_s.max()
    assert all(m["on_estimated_rate"] for m in d["MPT"])


def test_a_wait_that_fits_no_rate_is_refused_not_used(tmp_path, lab, capsys):
    la, f, P = lab
    # 1.5 s: the dwells (about 2.05 s at 1000/3 Hz) fit 354-470 Hz with it, no emScon rate and too wide a range
    rc, _, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--dwell-s", 1.5, "--json", tmp_path / "r.json")
    assert rc == 3
    assert "the dwells give no rate" in err and "too wide to use" in err
    d = json.loads((tmp_path / "r.json").read_text())
    assert d["time_base"]["source"] == "refused" and all(m["MPT_s"] is None for m in d["MPT"])


def test_the_rate_given_overrides_the_check(tmp_path, lab, capsys):
    la, f, P = lab
    rc, out, err = run(capsys, "iso9283", "--stream", f, "--poses", P, "--rate-hz", 250, "--dwell-s", 2,
                       "--json", tmp_path / "r.json")
    assert rc == 0, err
    tb = json.loads((tmp_path / "r.json").read_text())["time_base"]
    assert tb == {"source": "sample_index", "rate_hz": 250.0}


def test_moves_and_dwells_are_found_in_samples(rng):
    la = lab_lookalike(rng)
    mv = find_moves(la.xyz_mm)
    assert mv.leave_row.size == la.n_moves and mv.centres_mm.shape == (2, 3)
    groups = identical_moves(mv)
    assert [g.samples.size for g in groups] == [3, 3]
    # a move from leaving one rest radius to entering the other: under the profile's samples by the slow ends of
    # its ramps inside the radii (up to a tenth at half speed where the flange starts near an axis)
    assert mv.radius_mm == REST_RADIUS_MM
    truth = la.samples_outside(mv.radius_mm)
    for g in groups:
        assert g.spread <= 3
        assert np.all(np.abs(g.samples - np.median(truth)) <= 3) and g.samples.max() <= la.move_s * RATE_HZ
    # a dwell is the wait and overhead the tool stands still, give or take the ends of the ramps
    assert mv.dwell_rows.size == la.n_moves - 1
    assert np.all(np.abs(mv.dwell_rows - la.dwell_s * RATE_HZ) <= 0.1 * RATE_HZ)


def test_dwells_that_fit_several_emscon_rates_give_no_rate(rng):
    # 2 s waits at 100 Hz: 90.9 Hz (1000/11) reads them as 2.2-2.3 s, which the overhead allows too
    D = 200 + rng.integers(0, 10, 6)
    dr = rate_from_dwells(D, 2.0)
    assert dr.rate_hz is None and 100.0 in dr.candidates_hz and 1000.0 / 11 in dr.candidates_hz
    assert "alike" in dr.reason
    # a longer wait tells them apart
    dr = rate_from_dwells(10 * 100 + rng.integers(5, 15, 6), 10.0)
    assert dr.rate_hz == pytest.approx(100.0) and dr.candidates_hz == (100.0,)


def test_dwells_off_every_emscon_rate_give_the_middle_when_narrow(rng):
    rate = float(rng.uniform(1100.0, 1300.0))  # a tracker above every emScon rate
    wait = 10.0  # long enough for the overhead's allowance to leave a narrow interval
    D = np.floor(rate * (wait + rng.uniform(0.0, 0.05, 5)))
    dr = rate_from_dwells(D, wait)
    lo, hi = dr.interval_hz
    assert lo > 1000.0 and dr.candidates_hz == ()
    assert dr.rate_hz is not None and abs(dr.rate_hz - rate) <= np.sqrt(3.0) * dr.u_rate_hz + 1e-9
    assert "no emScon rate" in dr.basis


def _hold_stamps(rng, n, rate, bursty):
    """1 s stamps of a held pose: steady (the rate's samples each second) or a logger's bursts of 66-444."""
    if not bursty:
        return np.floor(np.arange(n) / rate + rng.uniform(0, 1)).astype(int)
    per = []
    while sum(per) < n:
        per.append(int(rng.integers(66, 445)))
    return np.repeat(np.arange(len(per)), per)[:n]


@pytest.mark.parametrize("bursty", [False, True])
def test_a_held_pose_on_coarse_stamps_states_drift_only_when_its_stamps_agree(tmp_path, rng, capsys, bursty):
    rate = RATE_HZ
    n = int(rate * rng.uniform(60, 90))
    drift_mm_s = rng.uniform(0.5e-3, 2e-3)  # along x
    t = np.arange(n) / rate
    xyz = np.array([1500.0, -200.0, 300.0]) + rng.normal(0, 1e-3, (n, 3))
    xyz[:, 0] += drift_mm_s * t
    sec = _hold_stamps(rng, n, rate, bursty)
    t0 = datetime(2025, 3, 11, 14, 0, 0)
    f = write_sa(tmp_path / "hold.txt", xyz, stamps=[(t0 + timedelta(seconds=int(s))).strftime("%m/%d/%y %H:%M:%S")
                                                    for s in sec])
    rc, out, err = run(capsys, "hold", "--stream", f, "--json", tmp_path / "h.json")
    d = json.loads((tmp_path / "h.json").read_text())
    if bursty:
        assert rc == 3 and "drift per minute and the windows refused" in err
        assert "stamp intervals hold another rate" in err and "no move in the stream can check the stamps" in err
        assert d["drift_mm_per_min"] is None and d["windows"] is None and "drift" in d["time_base"]["refused_figures"]
        assert "drift       REFUSED" in out and "mm/min" not in out
    else:
        assert rc == 0, err
        sd = d["drift_sd_mm_per_min"][0]
        assert abs(d["drift_mm_per_min"][0] - 60.0 * drift_mm_s) < 5 * sd + 60.0 * drift_mm_s * 1e-2
