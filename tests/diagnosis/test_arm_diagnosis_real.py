"""Diagnosis on data that look like real lab sets (issue 22): 30-60 poses, mm-size nominal error, hidden
effects drawn at random; the seed of every draw is printed."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fakes.sim.real_like_arms import fanuc_like, rokae_like
from station.analysis.arm.calibration import split_poses
from station.analysis.diagnose import diagnose_arm
from app.cli import main
from station.models import kinematics as kin
from station.models.arm_extended import motion_directions
from station.models.arm_model_file import model_to_json, resolve_arm
from station.readers.arm_csv import write_arm_csv
from tests.calibration.reference_fit import plain_fit, position_error


def _extended_error(res, d, test) -> float:
    """Mean 3-D error of the diagnosis' extended model (as written to a file) on poses it never saw."""
    doc = res.extended_model(joint_limits_rad=d.joint_limits_rad)
    arm = _arm_from(doc)
    p = arm.predict(d.q_rad[test], last_dir=motion_directions(d.q_rad)[test], t_s=d.t_s[test])
    return float(np.linalg.norm(p - d.xyz_mm[test], axis=1).mean())


def _arm_from(doc):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "m.json"
        p.write_text(json.dumps(doc))
        return resolve_arm(str(p)).extended()


def _inside(q_train, q_test, tol_rad: float = 1e-6) -> np.ndarray:
    """Test poses whose every joint angle lies within the training poses' range of that joint."""
    lo, hi = q_train.min(axis=0) - tol_rad, q_train.max(axis=0) + tol_rad
    return np.all((q_test >= lo) & (q_test <= hi), axis=1)


def _issue_like_fanuc(rng, n, **kw):
    """The public FANUC set's shape as issue 43 measured it: one-joint sweeps, about 1.3 mm nominal error and
    0.15-0.25 mm noise per reflector (a plain fit predicts unseen poses at about 0.3 mm)."""
    return fanuc_like(rng, n=n, noise_mm=float(rng.uniform(0.15, 0.25)), nominal_mm=(1.1, 1.5), **kw)


#: poses of the same arm measured after each set, added to every split's unseen 30 % (see the test's docstring)
UNSEEN = 200


@pytest.mark.timeout(900)  # six diagnoses and plain fits: slow on a shared machine
@pytest.mark.parametrize("make, n", [(fanuc_like, 36), (_issue_like_fanuc, 36), (rokae_like, 30), (rokae_like, 50)])
def test_trained_on_70_percent_names_geometry_and_predicts_the_rest_as_a_plain_fit(test_seed, make, n):
    """Issue 43: geometry is named, judged by the calibration against the nominal model on poses the folds held
    out (interpolation folds on sweeps, said so), or by its F test alone where the nominal model predicts the
    folds' poses to the noise (the folds cannot tell, said so): on every split where the nominal model misses
    the unseen poses by more than 1.5x the plain fit (geometry is clearly the cause) and on at least five of
    six; the written model predicts the 30 % it never saw within 1.02x of a plain full DH + Hayati fit of the
    same 70 % (mean of six splits: a single split's sweep ends beyond the training range make either fit
    extrapolate luckily).
    The unseen poses are the split's 30 % and :data:`UNSEEN` more poses of the same arm measured after the set:
    the split's own 3-9 poses inside the training range scatter by more than the 2 % the bound allows (the
    ROKAE-like 30-pose case failed it on 11 of 150 test seeds, worst 1.111x, with geometry alone named and the
    calibration 0.978x the plain fit on average); with them, at most 1.007x in 100 seeds.
    bench/bench_diagnosis_geometry.py, 150 diagnoses per shape: geometry named in all but one (the issue's FANUC
    shape, where the nominal model missed the unseen poses by only 1.15x the plain fit); the six-split ratio
    at most 1.010 in 100 replicates."""
    from station.analysis.arm.identification import rigid_fit

    seed = test_seed
    rng = np.random.default_rng(seed)
    ext, ref, named = [], [], 0
    for k in range(6):
        if k % 3 == 0:
            d = make(rng, n=n, n_unseen=UNSEEN)
        sp = split_poses(n, 0.3, kind="random", seed=int(rng.integers(2 ** 31)))
        tr, te = sp.train, np.concatenate([sp.test, d.unseen])
        # the comparison is on the unseen poses inside the angles the training poses span (what the diagnosis
        # states for sweeps: interpolation only): a random split of 36 sweep poses can leave the end of a sweep
        # 70 deg beyond the training range, where either fit extrapolates by luck (test seed 811884676: the
        # written model 0.69 mm, the plain fit 0.26 mm on this host's BLAS and 0.56 mm on another's threads)
        te = te[_inside(d.q_rad[tr], d.q_rad[te])]
        res = diagnose_arm(d.dh_nominal, d.q_rad[tr], d.xyz_mm[tr], t_s=d.t_s[tr])
        assert res.converged, (seed, res.fits)
        dh, B = plain_fit(d.dh_nominal, d.q_rad[tr], d.xyz_mm[tr])
        if te.size:
            ref.append(float(position_error(dh, B, d.q_rad[te], d.xyz_mm[te]).mean()))
        B0 = rigid_fit(kin.tool_position(d.dh_nominal, d.q_rad[tr]), d.xyz_mm[tr])
        nominal = float(position_error(d.dh_nominal, B0, d.q_rad[te], d.xyz_mm[te]).mean()) if te.size else 0.0
        cv = res.geometry["cross_validation"]
        blind = not cv["nominal_beyond_noise"]["seen"]
        if res.selected[:1] == [("geometric", None)]:
            named += 1
            # the folds that judged it: the calibration alone against the nominal model, or both with the named
            # effects where their residual hid it (test seed 29: 0.272 mm alone against the nominal's 0.240);
            # or none, where the nominal model predicts the folds' poses to the noise (harness seed 47, split 3:
            # 8 interior sweep poses near home, the nominal model 0.212 mm there against a noise of 0.23 mm,
            # the calibration 0.218; on the unseen poses the nominal model missed by 1.79x a plain fit)
            judged = cv.get("with_effects", cv)
            if "judged_by" in res.geometry:
                assert blind and "partial F alone" in res.geometry["judged_by"], (seed, res.geometry)
                assert cv["nominal_beyond_noise"]["statistic"] <= cv["nominal_beyond_noise"]["threshold"]
            else:
                assert judged["rms_geometry_mm"] < judged["rms_nominal_mm"], (seed, cv)
        else:
            # not named: the folds saw geometry and found the calibration no better, or its F test failed
            assert not blind or res.geometry["statistic"] <= res.geometry["threshold"], (seed, res.geometry)
            assert nominal <= 1.5 * ref[-1], (seed, nominal, ref[-1], res.geometry)
        if d.name == "fanuc-like":
            assert cv["kind"] == "interpolation" and "interpolation only" in cv["statement"], (seed, cv)
            assert cv["extrapolation"]["held_out_poses"] > 0, (seed, cv)
        else:
            assert cv["kind"] == "random" and "extrapolation" not in cv, (seed, cv)
        # no step without gain: each chose itself by a lower cross-validated error, with a non-zero estimate
        for s in res.steps:
            assert any(v != 0.0 for v in s.params.values()), (seed, s.term.key)
            assert s.cv[1] < s.cv[0] or (s.term.effect == "geometric" and "judged_by" in res.geometry), (
                seed, s.term.key, s.cv)
        # the noise floor is the geometric fit's residual (no repeats), within 2x of it
        assert 0.5 < res.noise_floor / res.fit_residual_floor < 2.0
        if te.size:
            ext.append(_extended_error(res, d, te))
    assert named >= 5 and len(ext) >= 4, (seed, named)
    assert np.mean(ext) <= 1.02 * np.mean(ref), (seed, ext, ref)


@pytest.mark.parametrize("n", [30, 50])
def test_rokae_class_written_model_predicts_unseen_poses_below_0_15_mm(test_seed, n):
    """Issue 43: the ROKAE class's written model predicts the 30 % of a random split it never saw below 0.15 mm,
    as the issue measured it: the mean over three splits (here three sets of the class, one random split each),
    with 0.05 mm noise per coordinate (the noise alone leaves about 0.08 mm on the unseen poses).

    One split alone is no class figure: a plain full DH + Hayati fit of 21 poses leaves 0.16 mm on the unseen 9
    of some draws (test seed 797920951: the written model 0.168 mm, the plain fit 0.161, the noise alone 0.086;
    harness seed 75: 0.153 and 0.159), 2 of 200 single draws at 30 poses over 0.15 mm, 0 of 200 at 50. Over
    three sets (harness seeds 0-299 at 30 poses, 0-199 at 50): the mean at most 0.131 and 0.105 mm, at most
    1.75x and 1.28x what the true geometry leaves on the same poses."""
    seed = test_seed
    rng = np.random.default_rng(seed)
    errors, truths = [], []
    for _ in range(3):
        d = rokae_like(rng, n=n, noise_mm=0.05, hidden=False)
        sp = split_poses(n, 0.3, kind="random", seed=int(rng.integers(2 ** 31)))
        res = diagnose_arm(d.dh_nominal, d.q_rad[sp.train], d.xyz_mm[sp.train], t_s=d.t_s[sp.train])
        assert res.selected[:1] == [("geometric", None)], (seed, res.geometry)
        truths.append(float(np.linalg.norm(d.true_points(sp.test) - d.xyz_mm[sp.test], axis=1).mean()))
        errors.append(_extended_error(res, d, sp.test))
    e, truth = float(np.mean(errors)), float(np.mean(truths))
    assert e < 0.15 and e < 2.0 * truth, (seed, errors, truths)


def test_the_written_model_falls_back_to_the_calibration_when_its_effects_do_not_reach_unseen_poses(test_seed):
    """Issue 43 item 2: a backlash-like offset present in the training poses only is named, but the effect does
    not predict the held-out poses: the written model is the calibration of every pose alone, and says so."""
    from station.analysis.arm.identification import identify
    from station.analysis.arm.split import workspace_split

    seed = test_seed
    rng = np.random.default_rng(seed)
    # a draw whose held-out poses the offset does not move (the split, k-means on q and x,y,z, keeps them): about
    # half the draws do; five draws were too few for 1 test seed in 27 (CI seed 1149862016), thirty left none of 300
    for _ in range(30):
        d = rokae_like(rng, n=60, noise_mm=0.05, hidden=False)
        order = np.argsort(d.t_s)
        q, t = d.q_rad[order], d.t_s[order]
        _, heldout = workspace_split(q, d.xyz_mm[order], 0.25)
        dirs = motion_directions(q)
        b = float(rng.uniform(0.9e-3, 1.3e-3))
        dq = -b * dirs * np.eye(6)[1]
        dq[heldout] = 0.0
        meas = kin.tool_position(d.dh_true, q + dq) @ d.base_T[:3, :3].T + d.base_T[:3, 3]
        meas = meas + rng.normal(0, d.noise_mm, meas.shape)
        if np.array_equal(workspace_split(q, meas, 0.25)[1], heldout):
            break
    else:
        pytest.fail(f"seed {seed}: the offset moved the held-out split in thirty draws")
    res = diagnose_arm(d.dh_nominal, q, meas, t_s=t)
    assert ("backlash", 2) in res.selected, (seed, res.selected)
    w = res.to_json()["written_model"]
    assert w["effects_written"] is False, (seed, w)
    assert w["heldout_rms_with_effects_mm"] > w["heldout_rms_calibration_mm"], (seed, w)
    assert "calibration alone" in w["note"], (seed, w)
    doc = res.extended_model(joint_limits_rad=d.joint_limits_rad)
    assert doc["effects"] == [], (seed, doc["effects"])
    # the written model is the calibration of every pose, to the solvers' tolerance
    cal = identify(d.dh_nominal, q, meas, method="absolute")
    p_cal = kin.tool_position(cal.dh, q) @ cal.base_T[:3, :3].T + cal.base_T[:3, 3]
    assert np.max(np.linalg.norm(_arm_from(doc).predict(q) - p_cal, axis=1)) < 1e-3, seed


def test_rokae_like_from_the_nominal_model_names_geometry_and_reaches_the_noise(test_seed):
    """2.2-2.5 mm nominal error, ~0.1 mm after calibration: the fit from the nominal does not diverge."""
    seed = test_seed
    d = rokae_like(np.random.default_rng(seed), n=50, noise_mm=0.05, hidden=False)
    res = diagnose_arm(d.dh_nominal, d.q_rad, d.xyz_mm)
    assert res.selected == [("geometric", None)] or res.selected[0] == ("geometric", None), (seed, res.selected)
    geo = res.steps[0]
    assert any(abs(v) > 1e-6 for v in geo.params.values())
    assert res.simulation_heldout_rms > 1.5 and res.final_heldout_rms < 0.15, (seed, res.final_heldout_rms)
    assert res.noise_floor < 0.15 and "geometric fit" in res.noise_floor_source
    assert res.converged


def test_geometry_untestable_names_nothing_else_and_says_why(test_seed):
    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=14, hidden=False)
    q = d.q_rad.copy()
    # a strong backlash on joint 2 that would be found if anything else were allowed
    dirs = motion_directions(q)
    meas = kin.tool_position(d.dh_true, q - 2e-3 * dirs * np.eye(6)[1]) @ d.base_T[:3, :3].T + d.base_T[:3, 3]
    res = diagnose_arm(d.dh_nominal, q, meas, t_s=d.t_s)
    assert res.steps == [], (seed, res.selected)
    assert "geometry cannot be tested" in res.stop_reason
    assert "geometric" in res.to_json()["not_testable"]


def test_row_order_does_not_change_the_answer_without_a_motion_order(test_seed):
    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=50)
    a = diagnose_arm(d.dh_nominal, d.q_rad, d.xyz_mm)
    perm = rng.permutation(50)
    b = diagnose_arm(d.dh_nominal, d.q_rad[perm], d.xyz_mm[perm])
    assert a.selected == b.selected, seed
    assert b.final_heldout_rms == pytest.approx(a.final_heldout_rms, rel=1e-6)
    assert np.array_equal(np.sort(perm[b.heldout]), a.heldout)
    assert all("order of motion" in a.not_testable[f"backlash[{j}]"] for j in (1, 2, 3))
    # with a t column the rows are sorted by it: shuffling them changes nothing either
    c = diagnose_arm(d.dh_nominal, d.q_rad, d.xyz_mm, t_s=d.t_s)
    e = diagnose_arm(d.dh_nominal, d.q_rad[perm], d.xyz_mm[perm], t_s=d.t_s[perm])
    assert c.selected == e.selected and e.final_heldout_rms == pytest.approx(c.final_heldout_rms, rel=1e-6)


def test_noise_floor_from_repeated_measurements(test_seed):
    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=40, noise_mm=0.08, hidden=False)
    rep = rng.choice(40, 10, replace=False)
    q = np.concatenate([d.q_rad, d.q_rad[rep], d.q_rad[rep]])
    true = kin.tool_position(d.dh_true, q) @ d.base_T[:3, :3].T + d.base_T[:3, 3]
    meas = true + rng.normal(0, 0.08, true.shape)
    res = diagnose_arm(d.dh_nominal, q, meas)
    assert "repeated measurements" in res.noise_floor_source
    # 3-D scatter of the noise: 0.08 sqrt(3); 20 degrees of freedom x 3 coordinates
    assert 0.7 < res.noise_floor / (0.08 * np.sqrt(3)) < 1.3, (seed, res.noise_floor)


def test_implausible_joint_effect_is_not_named(test_seed):
    """A 'joint error' of 20 arcmin that a sweep cannot tell from an offset is refused, with the reason."""
    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=60, noise_mm=0.05, hidden=False)
    q = d.q_rad
    dq = np.zeros_like(q)
    dq[:, 1] = np.radians(20 / 60) * np.sin(q[:, 1])
    meas = kin.tool_position(d.dh_true, q + dq) @ d.base_T[:3, :3].T + d.base_T[:3, 3] + rng.normal(0, 0.05, q.shape[:1] + (3,))
    res = diagnose_arm(d.dh_nominal, q, meas)
    assert ("encoder_eccentricity", 2) not in res.selected, (seed, res.selected)
    assert "arcmin" in res.rejected.get("encoder_eccentricity[2]", ""), (seed, res.rejected)


def test_cli_model_out_predict_and_compensate(test_seed, tmp_path, capsys):
    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=50)
    (tmp_path / "nom.json").write_text(json.dumps(model_to_json(d.dh_nominal, name="rokae-like",
                                                                joint_limits_rad=d.joint_limits_rad)))
    write_arm_csv(tmp_path / "a.csv", np.degrees(d.q_rad), d.xyz_mm, t=d.t_s)
    m = tmp_path / "m.json"
    assert main(["diagnose", "arm", "--robot", str(tmp_path / "nom.json"), "--data", str(tmp_path / "a.csv"),
                 "--model-out", str(m)]) == 0
    model = json.loads(m.read_text())
    assert set(model) >= {"joints", "tool", "base", "effects"}
    arm = resolve_arm(str(m)).extended()
    q_deg = np.degrees(d.q_rad)
    dirs = motion_directions(d.q_rad)
    head = "q1,q2,q3,q4,q5,q6,t,dir1,dir2,dir3,dir4,dir5,dir6\n"
    rows = [",".join(repr(float(v)) for v in [*q, t, *dd]) for q, t, dd in zip(q_deg, d.t_s, dirs)]
    (tmp_path / "q.csv").write_text(head + "\n".join(rows) + "\n")
    assert main(["predict", "arm", "--model", str(m), "--joints", str(tmp_path / "q.csv"),
                 "--out", str(tmp_path / "p.csv")]) == 0
    p = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)
    want = arm.predict(d.q_rad, last_dir=dirs, t_s=d.t_s)
    np.testing.assert_allclose(p[:, 6:9], want, atol=1e-9)
    # the prediction is what the measured points are, to the noise (the model was fitted to them)
    assert np.sqrt(np.mean(np.sum((p[:, 6:9] - d.xyz_mm) ** 2, axis=1))) < 3 * d.noise_mm * np.sqrt(3) + 0.1
    # compensate: joint commands whose predicted points are the targets
    tgt = want[:10] + rng.normal(0, 0.5, (10, 3))
    t_rows = [",".join(repr(float(v)) for v in [*x, *q, *dd]) for x, q, dd in zip(tgt, q_deg[:10], dirs[:10])]
    (tmp_path / "t.csv").write_text("x,y,z,q1,q2,q3,q4,q5,q6,dir1,dir2,dir3,dir4,dir5,dir6\n" + "\n".join(t_rows))
    model_no_t = dict(model)
    model_no_t["effects"] = [e for e in model["effects"] if e["effect"] != "thermal_drift"]
    m2 = tmp_path / "m2.json"
    m2.write_text(json.dumps(model_no_t))
    assert main(["compensate", "arm", "--model", str(m2), "--targets", str(tmp_path / "t.csv"),
                 "--out", str(tmp_path / "qc.csv")]) == 0
    qc = np.loadtxt(tmp_path / "qc.csv", delimiter=",", skiprows=1)
    arm2 = resolve_arm(str(m2)).extended()
    np.testing.assert_allclose(arm2.predict(np.radians(qc[:, :6]), last_dir=dirs[:10]), tgt, atol=2e-3)
    assert np.all(qc[:, 9] < 1e-3)
    # a target out of reach: written, and exit 3
    (tmp_path / "far.csv").write_text("x,y,z,dir1,dir2,dir3,dir4,dir5,dir6\n1e5,0,0,1,1,1,1,1,1\n")
    assert main(["compensate", "arm", "--model", str(m2), "--targets", str(tmp_path / "far.csv"),
                 "--out", str(tmp_path / "far_q.csv")]) == 3
    assert "missed" in capsys.readouterr().err
    # refusals name the file, line and what is missing
    (tmp_path / "q_bad.csv").write_text("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,x\n")
    assert main(["predict", "arm", "--model", str(m), "--joints", str(tmp_path / "q_bad.csv"),
                 "--out", str(tmp_path / "pb.csv")]) == 2
    assert "q_bad.csv:2:6 (q6): not a number" in capsys.readouterr().err
    if any(e["effect"] == "backlash" for e in model["effects"]):
        (tmp_path / "q_nodir.csv").write_text("q1,q2,q3,q4,q5,q6,t\n" + "\n".join(
            ",".join(repr(float(v)) for v in [*q, t]) for q, t in zip(q_deg, d.t_s)))
        assert main(["predict", "arm", "--model", str(m), "--joints", str(tmp_path / "q_nodir.csv"),
                     "--out", str(tmp_path / "pn.csv")]) == 2
        assert "dir1..dir6" in capsys.readouterr().err
    assert not (tmp_path / "pb.csv").exists()


def test_cli_says_when_the_poses_allow_only_interpolation(test_seed, tmp_path, capsys):
    """One-joint sweeps: the geometry's cross-validation is interpolation only, said in the output and the JSON,
    with the sweep ends' extrapolation figure beside it; spread poses say neither."""
    seed = test_seed
    rng = np.random.default_rng(seed)
    for make, sweeps in ((fanuc_like, True), (rokae_like, False)):
        d = make(rng, n=36)
        (tmp_path / "nom.json").write_text(json.dumps(model_to_json(d.dh_nominal, name=d.name)))
        write_arm_csv(tmp_path / "a.csv", np.degrees(d.q_rad), d.xyz_mm, t=d.t_s)
        assert main(["diagnose", "arm", "--robot", str(tmp_path / "nom.json"), "--data", str(tmp_path / "a.csv"),
                     "--json", str(tmp_path / "d.json")]) == 0, seed
        out = capsys.readouterr().out
        cv = json.loads((tmp_path / "d.json").read_text())["geometry"]["cross_validation"]
        assert "geometry cross-validated on" in out and cv["folds"] >= 2, (seed, out)
        assert ("interpolation only" in out) == sweeps and ("extrapolation (the sweeps' ends" in out) == sweeps, out
        assert cv["kind"] == ("interpolation" if sweeps else "random"), (seed, cv)
        assert ("one-joint sweeps" in cv["poses"]) == sweeps, (seed, cv)


def test_extended_model_file_is_checked():
    from station.errors import ConfigError
    from station.models.arm_extended import terms_from_json

    with pytest.raises(ConfigError, match=r"effects\[0\]: 'joint' must be 1..6"):
        terms_from_json([{"effect": "backlash", "joint": 7, "params": {"b7_rad": 1e-4}}], "m.json")
    with pytest.raises(ConfigError, match="has the param b2_rad"):
        terms_from_json([{"effect": "backlash", "joint": 2, "params": {"b3_rad": 1e-4}}], "m.json")
    with pytest.raises(ConfigError, match="needs params.alpha_per_K"):
        terms_from_json([{"effect": "thermal_drift", "params": {"dT_max_K": 2.0}}], "m.json")


def _written_geometry(res, d):
    """Positions the written model's table and base give (the effects left out), and its effects."""
    doc = res.extended_model(joint_limits_rad=d.joint_limits_rad)
    arm = _arm_from({k: v for k, v in doc.items() if k != "effects"})
    return arm.predict(d.q_rad), doc.get("effects", [])


def test_the_written_model_starts_from_the_calibration_and_adds_the_effects(test_seed):
    """The model written out starts from the calibration of every pose the diagnosis was given; on spread poses
    the geometry is re-identified with the named effects (issue 43 item 3: an effect fitted on the residual the
    calibration left explains only its part no geometric error mimics), and the model fits the poses it was
    given better than the calibration and predicts poses it never saw better than the calibration alone."""
    from station.analysis.arm.identification import identify

    seed = test_seed
    rng = np.random.default_rng(seed)
    d = rokae_like(rng, n=120, hidden=False)
    # a backlash on joint 2 of 3-4.5 arcmin (0.7-1 mm at the flange); 60 poses to diagnose, 60 never seen
    b = float(rng.uniform(0.9e-3, 1.3e-3))
    dirs = motion_directions(d.q_rad)
    q = d.q_rad
    meas = kin.tool_position(d.dh_true, q - b * dirs * np.eye(6)[1]) @ d.base_T[:3, :3].T + d.base_T[:3, 3]
    meas = meas + rng.normal(0, d.noise_mm, meas.shape)
    tr, te = np.arange(60), np.arange(60, 120)
    res = diagnose_arm(d.dh_nominal, q[tr], meas[tr], t_s=d.t_s[tr])
    assert ("backlash", 2) in res.selected, (seed, res.selected)
    cal = identify(d.dh_nominal, q[tr], meas[tr], method="absolute")

    def at(dh, B, rows):
        return kin.tool_position(dh, q[rows]) @ B[:3, :3].T + B[:3, 3]

    doc = res.extended_model(joint_limits_rad=d.joint_limits_rad)
    assert "backlash" in [e["effect"] for e in doc["effects"]]
    assert res.written["effects_written"] is True and "are written" in res.written["note"], (seed, res.written)
    assert res.written["geometry"].startswith("re-identified"), res.written
    # on the poses it was given: closer than the calibration (it has the backlash's parameter more)
    fit = _arm_from(doc).predict(q[tr], last_dir=dirs[tr], t_s=d.t_s[tr])
    assert (np.linalg.norm(fit - meas[tr], axis=1).mean()
            < np.linalg.norm(at(cal.dh, cal.base_T, tr) - meas[tr], axis=1).mean()), seed
    # with the effects, the poses never seen are predicted better than by the calibration alone
    ext = _arm_from(doc).predict(q[te], last_dir=dirs[te], t_s=d.t_s[te])
    e_ext = np.linalg.norm(ext - meas[te], axis=1).mean()
    e_geo = np.linalg.norm(at(cal.dh, cal.base_T, te) - meas[te], axis=1).mean()
    assert e_ext < e_geo, (seed, e_ext, e_geo)
