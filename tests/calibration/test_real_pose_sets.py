"""Calibration on pose sets that look like real lab data (issue 22): sweeps, few poses, mm-size nominal errors.

Every set is drawn from a seed printed on failure. The yardstick is a plain
full DH + Hayati least-squares fit by scipy's MINPACK (tests/calibration/reference_fit.py).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fakes.sim.real_like_arms import fanuc_like, rokae_like
from station.analysis.arm.calibration import calibrate_arm, cross_validate, split_poses
from station.analysis.arm.identification import identify, parameter_warnings
from app.cli import main
from station.errors import DataError, InsufficientDataError
from station.models import kinematics as kin
from station.models.arm_model_file import model_to_json
from station.readers.arm_csv import write_arm_csv
from tests.calibration.reference_fit import plain_fit, position_error


def _files(tmp_path, d, name="nom.json", dh=None):
    write_arm_csv(tmp_path / "a.csv", np.degrees(d.q_rad), d.xyz_mm)
    (tmp_path / name).write_text(json.dumps(model_to_json(d.dh_nominal if dh is None else dh, name=d.name,
                                                          joint_limits_rad=d.joint_limits_rad)))
    return str(tmp_path / name), str(tmp_path / "a.csv")


#: random splits of the acceptance's mean (four sets, four splits each). A random split of sweeps holds out
#: sweep ends beyond the training range, where either fit may extrapolate the hidden effects luckily: a single
#: split's ratio reached 1.46. With 8 splits the mean ratio of the FANUC-like set exceeded 1.05 for 1 of 300
#: seeds (and for soak seed 1014864616: one split at 1.46, the seven others 0.97-1.01); median 0.94. With 16
#: it did for none of 300 other seeds (largest 1.032, median 0.934). bench/bench_calibration_split_ratio.py.
SPLITS = 16


@pytest.mark.timeout(600)  # sixteen reference fits: slow on a shared machine
@pytest.mark.parametrize("make, n", [(fanuc_like, 36), (rokae_like, 30), (rokae_like, 50)])
def test_random_splits_hold_out_as_well_as_a_plain_full_fit(test_seed, make, n):
    """Absolute method, random 70/30 splits, no preparation of the file: within 1.05x of the full fit."""
    seed = test_seed
    rng = np.random.default_rng(seed)
    ours, ref, before, truth = [], [], [], []
    for k in range(SPLITS):  # a set every four random splits: the acceptance is a mean over random splits
        if k % 4 == 0:
            d = make(rng, n=n)
        sp = split_poses(n, 0.3, kind="random", seed=int(rng.integers(2 ** 31)))
        cal = calibrate_arm(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", split=sp)
        assert cal.identification.converged, (seed, cal.identification.message)
        dh, B = plain_fit(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train])
        ours.append(cal.test.after_mm.mean())
        ref.append(position_error(dh, B, d.q_rad[sp.test], d.xyz_mm[sp.test]).mean())
        before.append(cal.test.before_mm.mean())
        # what the true geometry leaves on the same poses: the hidden effects and the noise
        truth.append(position_error(d.dh_true, d.base_T, d.q_rad[sp.test], d.xyz_mm[sp.test]).mean())
    assert np.mean(ours) <= 1.05 * np.mean(ref), (seed, ours, ref)
    # and the calibration removes the mm-size nominal error: at least 80 % of what the true geometry removes
    # (the rest, the hidden effects, is not geometry; on some draws it is 0.4 mm)
    removed, removable = np.mean(before) - np.mean(ours), np.mean(before) - np.mean(truth)
    assert np.mean(before) > 0.3 and removed >= 0.8 * removable, (seed, before, ours, truth)


def test_fanuc_tail_is_the_j6_sweep_calibrated_without_preparation_and_named(test_seed, tmp_path, capsys):
    seed = test_seed
    d = fanuc_like(np.random.default_rng(seed), n=36)
    robot, data = _files(tmp_path, d)
    out = tmp_path / "c.json"
    # the J6 sweep is the tail: the default calibrates what the training poses see and says what the prior held
    assert main(["calibrate", "arm", "--robot", robot, "--data", data, "--method", "absolute", "--test-fraction",
                 "0.17", "--json", str(out)]) == 0, seed
    doc = json.loads(out.read_text())
    text = capsys.readouterr().out
    unseen = [k for k, why in doc["held"].items() if "cannot see" in why]
    assert unseen and "held:" in text, (seed, doc["held"])
    assert any(note.startswith("q6:") and "never move" in note for note in doc["heldout_coverage"]), seed
    assert "held-out poses: q6" in text
    # --strict refuses the same poses, naming what they cannot see
    assert main(["calibrate", "arm", "--robot", robot, "--data", data, "--method", "absolute", "--test-fraction",
                 "0.17", "--strict"]) == 2
    assert "these poses cannot see" in capsys.readouterr().err
    with pytest.raises(InsufficientDataError, match="these poses cannot see"):
        calibrate_arm(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", test_fraction=0.17, strict=True)


def test_splits_and_folds(test_seed, tmp_path, capsys):
    seed = test_seed
    d = rokae_like(np.random.default_rng(seed), n=40)
    a = split_poses(40, 0.3, kind="random", seed=7)
    b = split_poses(40, 0.3, kind="random", seed=7)
    assert np.array_equal(a.test, b.test) and a.test.size == 12 and not np.array_equal(a.test, np.arange(28, 40))
    s = split_poses(40, 0.3, kind="spread", q_rad=d.q_rad, measured_mm=d.xyz_mm)
    assert s.test.size == 12 and np.intersect1d(s.train, s.test).size == 0
    with pytest.raises(DataError, match="--split"):
        split_poses(40, 0.3, kind="head")
    cv = cross_validate(d.dh_nominal, d.q_rad, d.xyz_mm, folds=4, seed=3, method="absolute")
    assert len(cv["folds"]) == 4 and sum(f["n_test"] for f in cv["folds"]) == 40
    means = [f["test_mean_after_mm"] for f in cv["folds"]]
    assert cv["mean_mm"] == pytest.approx(np.mean(means)) and cv["sd_mm"] == pytest.approx(np.std(means, ddof=1))
    with pytest.raises(DataError, match="--folds"):
        cross_validate(d.dh_nominal, d.q_rad, d.xyz_mm, folds=1)
    robot, data = _files(tmp_path, d)
    assert main(["calibrate", "arm", "--robot", robot, "--data", data, "--split", "random", "--seed", "5",
                 "--folds", "3", "--method", "absolute", "--test-fraction", "0.3"]) == 0
    text = capsys.readouterr().out
    assert "split random, seed 5" in text and "cross-validation (3 folds, seed 5)" in text


def test_redundant_pair_keeps_one_free_and_free_fix_by_name(test_seed):
    """d6 and the tool's z move the point alike (alpha6 = 0): one of them is identified, --free chooses which."""
    seed = test_seed
    d = rokae_like(np.random.default_rng(seed), n=40, hidden=False)
    res = identify(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute")
    names = set(res.identifiability.names)
    assert ("d6" in names) != ("dTCP" in names), (seed, names)
    assert "redundant" in res.identifiability.fixed["dTCP"]
    res2 = identify(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", free_extra=("dTCP",))
    assert "dTCP" in res2.identifiability.names and "d6" in res2.identifiability.fixed
    # the same fit either way: the pair carries one number
    assert res.residual_rms_mm == pytest.approx(res2.residual_rms_mm, rel=0.05)
    res3 = identify(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", fixed_extra={"a2": "fixed as asked (--fix)"})
    assert res3.identifiability.fixed["a2"] == "fixed as asked (--fix)" and res3.dh[1, 0] == d.dh_nominal[1, 0]
    with pytest.raises(DataError, match="unknown parameter 'a9'"):
        identify(d.dh_nominal, d.q_rad, d.xyz_mm, method="absolute", fixed_extra={"a9": "x"})
    with pytest.raises(DataError, match="both fixed and free"):
        identify(d.dh_nominal, d.q_rad, d.xyz_mm, fixed_extra={"a2": "x"}, free_extra=("a2",))


def test_a_calibrated_start_does_not_unlock_near_redundant_pairs(test_seed):
    """A model file that is itself a calibration has tenths of a mm where the design has 0: the fit must not
    trade a5 against theta5 by tens of mm and degrees, and the distance method converges."""
    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=50, hidden=False)
    start = d.dh_true.copy()
    start[:, [0, 2]] += rng.normal(0, 0.3, (7, 2))
    for method in ("distance", "absolute"):
        res = identify(start, d.q_rad, d.xyz_mm, method=method)
        assert res.converged, (seed, method, res.message)
        assert not [w for w in res.extra["warnings"] if w["kind"] == "implausible"], (seed, res.extra["warnings"])
        assert "a5" not in res.identifiability.names and "a5" in res.identifiability.fixed


def test_implausible_change_is_warned_with_a_fixed_alternative(test_seed, tmp_path, capsys):
    seed = test_seed
    d = rokae_like(np.random.default_rng(seed), n=40, hidden=False)
    start = d.dh_nominal.copy()
    start[1, 0] += 12.0  # a2 written 12 mm wrong: the fit moves it back, beyond what tolerances make plausible
    cal = calibrate_arm(start, d.q_rad, d.xyz_mm, method="absolute", split_kind="random", seed=1, test_fraction=0.3)
    warns = [w for w in cal.identification.extra["warnings"] if w["kind"] == "implausible"]
    assert [w["parameters"] for w in warns] == [["a2"]], (seed, warns)
    # the fit moves a2 back to the true arm's value, which itself lies a few mm from nominal (drawn)
    assert warns[0]["change"] == pytest.approx(d.dh_true[1, 0] - start[1, 0], abs=1.0), seed
    alt = cal.identification.extra["alternative"]
    assert alt["fix"] == ["a2"] and alt["test_mean_after_mm"] > cal.test.after_mm.mean()
    robot, data = _files(tmp_path, d, dh=start)
    assert main(["calibrate", "arm", "--robot", robot, "--data", data, "--method", "absolute"]) == 0
    text = capsys.readouterr().out
    assert "warning: a2 changes by" in text and "rerun with --fix a2" in text


def test_correlation_warning_names_the_pair(test_seed):
    rng = np.random.default_rng(test_seed)
    J = rng.normal(size=(60, 3))
    J[:, 1] = J[:, 0] + 1e-4 * rng.normal(size=60)   # a1 and alpha1 (columns 0 and 1) nearly the same
    w = parameter_warnings(kin.dh_from_degrees(np.zeros((7, 5))), kin.dh_from_degrees(np.zeros((7, 5))),
                           np.array([0, 1, 2]), J, {})
    assert [x["parameters"] for x in w if x["kind"] == "correlated"] == [["a1", "alpha1"]]
    assert "estimated together" in w[0]["message"]


def test_not_converged_exits_3_and_says_so(test_seed, tmp_path, capsys):
    seed = test_seed
    d = rokae_like(np.random.default_rng(seed), n=40)
    robot, data = _files(tmp_path, d)
    out = tmp_path / "c.json"
    assert main(["calibrate", "arm", "--robot", robot, "--data", data, "--method", "absolute", "--max-iter", "1",
                 "--json", str(out)]) == 3
    assert "did not converge" in capsys.readouterr().err
    doc = json.loads(out.read_text())
    assert doc["converged"] is False and doc["message"].startswith("not converged")
    assert math.isfinite(doc["test"]["mean_abs_after_mm"])
