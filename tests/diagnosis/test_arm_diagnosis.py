"""Hidden-effect tests of the arm diagnosis: effect, joint, strength and seed drawn at random each run."""

from __future__ import annotations

import json

import numpy as np
import pytest

from station.analysis.diagnose import diagnose_arm
from station.analysis.diagnose.arm import canonical_order
from station.analysis.diagnose.arm_fit import jacobian
from app.cli import main
from station.models import kinematics as kin
from station.models.effects import EffectSet
from station.models.robots import get_robot
from station.readers.arm_csv import write_arm_csv
from fakes.sim.diagnosis_data import simulate_arm_data
from tests.diagnosis.hidden import compliance_joints, found, make_case

ROBOT = get_robot("industrial-3100")
ALPHA = 0.01  # family-wise per round; the tests must not be flaky


def _diagnose(d, **kw):
    return diagnose_arm(ROBOT.dh_nominal, d.q_rad, d.xyz_mm, t_s=d.t_s, robot=ROBOT, alpha=ALPHA, **kw)


def _oracle_rms(d, res, rows=None) -> float:
    """3-D RMS of the truth's residual (the noise) on ``rows`` (default: the held-out poses)."""
    e = (d.xyz_mm - d.true_points(ROBOT))[res.heldout if rows is None else rows]
    return float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))


def _predicts_like_the_truth(d, res) -> None:
    """The extended model's held-out mean-square error exceeds the truth's by no more than its own estimation
    error explains. For a least-squares fit of the final model's parameters to the training poses, with the
    noise variance the data has (the truth's residual), the excess at the held-out poses is
    ``|A_ho dtheta|^2 / n + 2 e.A_ho dtheta / n``: its mean and spread follow from the Jacobians of the two
    pose sets, and the excess stays within 5 of its standard deviations of its mean (over 60 draws of thermal
    drift and encoder eccentricity: z mean 0.1, sd 1.0, max 2.6). A ratio to the truth's held-out RMS is no
    bound: the held-out region is a part of the workspace whose noise can be smaller than the rest's (seed
    925812743: 0.067 mm there against 0.096 mm on the training poses; the ratio 1.20, z = 3.0)."""
    perm = canonical_order(d.q_rad, d.xyz_mm, d.t_s, False)[0]  # the diagnosis's working order
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    q = d.q_rad[perm]
    _, a_tr, _ = jacobian(res.state, q, inv[res.train])
    _, a_ho, _ = jacobian(res.state, q, inv[res.heldout])
    p = a_tr.shape[2]
    a_tr, a_ho = a_tr.reshape(-1, p), a_ho.reshape(-1, p)
    e2 = np.sum((d.xyz_mm - d.true_points(ROBOT)) ** 2, axis=1)
    s2 = float(e2.mean()) / 3.0  # per coordinate
    n_ho = res.heldout.size
    lam = np.linalg.eigvals(s2 * np.linalg.pinv(a_tr.T @ a_tr) @ (a_ho.T @ a_ho) / n_ho).real
    mean = float(lam.sum())
    sd = float(np.sqrt(2.0 * np.sum(lam ** 2) + 4.0 * s2 * mean / n_ho))
    excess = res.final_heldout_rms ** 2 - float(e2[res.heldout].mean())
    assert excess < mean + 5.0 * sd, ((excess - mean) / sd, excess, mean, sd, res.final_heldout_rms, res.selected)


def _joint(effect, rng):
    if effect == "thermal_drift":
        return None
    # joint 6 turns only the short tool offset, half of whose eccentricity is a tool offset: the bench covers it
    return int(rng.choice(compliance_joints(ROBOT) if effect == "joint_compliance" else np.arange(1, 6)))


@pytest.mark.parametrize("effect", ["backlash", "encoder_eccentricity", "joint_compliance", "thermal_drift"])
def test_hidden_effect_is_named_with_its_joint(rng, effect):
    joint = _joint(effect, rng)
    d = make_case(ROBOT, [(effect, joint)], rng, strength=(0.8, 1.2))
    res = _diagnose(d)
    assert found(res, effect, joint), (effect, joint, res.selected)
    others = [s for s in res.selected if s not in (("geometric", None), (effect, joint))]
    assert len(others) <= 1, res.selected  # at most one chance discovery (alpha per round)
    # the extended model predicts held-out poses about as well as the truth does
    _predicts_like_the_truth(d, res)
    # the step that named it: by its own term, or by a term that explains the same residual
    step = next(s for s in res.steps if (s.term.effect, s.term.joint) == (effect, joint)
                or any((a["effect"], a["joint"]) == (effect, joint) for a in s.ambiguous_with))
    assert step.heldout_rms_after < step.heldout_rms_before
    lo_hi = list(step.ci.values())[0]
    assert lo_hi[0] < lo_hi[1]


def test_two_hidden_effects_are_both_named(rng):
    e1, e2 = rng.choice(["backlash", "encoder_eccentricity", "joint_compliance"], 2, replace=False)
    j1, j2 = _joint(str(e1), rng), _joint(str(e2), rng)
    d = make_case(ROBOT, [(str(e1), j1), (str(e2), j2)], rng, strength=(1.0, 1.5))
    res = _diagnose(d)
    assert found(res, str(e1), j1) and found(res, str(e2), j2), (e1, j1, e2, j2, res.selected)
    _predicts_like_the_truth(d, res)


def test_geometric_errors_only_give_the_geometric_step_only(rng):
    d = make_case(ROBOT, [], rng)
    res = _diagnose(d)
    assert res.selected[0] == ("geometric", None)
    assert len(res.selected) <= 2, res.selected
    assert res.gain > 0.5
    # the noise floor is the noise the generator put in (3-D RMS), within the scatter of its estimate
    # the floor comes from the training residual: compared with the truth's on the same poses
    assert 0.7 < res.noise_floor / _oracle_rms(d, res, rows=res.train) < 1.35


def test_nominal_arm_gives_nothing(rng):
    d = simulate_arm_data(ROBOT, EffectSet.none(), rng, n=120)
    res = _diagnose(d)
    # a test at level ALPHA names a false effect ALPHA of the time (1 draw in 41 was seen): what it names then is
    # marginal, its statistic near the threshold (2.5x is a tail below 1e-6 under no effect) and its gain small
    for st in res.steps:
        assert st.statistic < 2.5 * st.threshold and st.cv[1] > 0.95 * st.cv[0], (st.term.key, st.statistic,
                                                                                  st.threshold, st.cv)
    assert len(res.steps) <= 1
    # the geometric calibration it starts from is not named, and costs the held-out poses little: fitting p ~ 30
    # parameters to the noise of N ~ 270 training coordinates raises the held-out rms by about sqrt(1 + p/N) ~ 1.05;
    # the draw of the 30 held-out poses spreads that ratio by a few percent (1.10 was seen), so 1.2 bounds it
    assert res.final_heldout_rms < 1.2 * res.simulation_heldout_rms


def test_not_testable_candidates_are_named_with_the_reason(rng):
    d = make_case(ROBOT, [], rng, n=40)
    q = d.q_rad.copy()
    q[:, 5] = 0.3  # joint 6 never moves
    meas = kin.tool_position(ROBOT.dh_nominal, q) + rng.normal(0, 0.02, (40, 3))
    res = diagnose_arm(ROBOT.dh_nominal, q, meas, robot=ROBOT, alpha=ALPHA)
    nt = res.to_json()["not_testable"]
    assert "no time or temperature column" in nt["thermal_drift"]
    assert "constant" in nt["backlash[6]"] and "constant" in nt["encoder_eccentricity[6]"]
    # no t column and no --rows-in-motion-order: the order of motion is unknown, backlash is not tested
    assert "order of motion" in nt["backlash[2]"]


def test_eccentricity_needs_a_joint_swept_a_quarter_turn(rng):
    """Over a short arc a once-per-turn error is an offset and a slope: it is not tested, and the reason names
    the arc."""
    d = make_case(ROBOT, [], rng, n=40)
    q = d.q_rad.copy()
    arc_deg = float(rng.uniform(20.0, 80.0))
    q[:, 2] = np.radians(rng.uniform(-arc_deg / 2, arc_deg / 2, q.shape[0]))  # joint 3 swept less than 90 deg
    meas = kin.tool_position(ROBOT.dh_nominal, q) + rng.normal(0, 0.02, (q.shape[0], 3))
    res = diagnose_arm(ROBOT.dh_nominal, q, meas, robot=ROBOT, alpha=ALPHA)
    nt = res.to_json()["not_testable"]
    assert "spans" in nt["encoder_eccentricity[3]"] and "90 deg" in nt["encoder_eccentricity[3]"], nt
    assert "encoder_eccentricity[1]" not in nt  # the other joints move over the whole range
    assert ("encoder_eccentricity", 3) not in res.selected


def test_compliance_needs_its_torque_spread_over_half_its_range(rng):
    """Shoulder and elbow held within a few degrees: joint 2's gravity torque spans a sliver of what it takes over
    the joint space, so its compliance is not tested (it would be told from geometry over that sliver)."""
    d = make_case(ROBOT, [], rng, n=40)
    q = d.q_rad.copy()
    for j in (1, 2):
        c = float(rng.uniform(-0.3, 0.3))
        q[:, j] = c + np.radians(rng.uniform(-5.0, 5.0, q.shape[0]))
    meas = kin.tool_position(ROBOT.dh_nominal, q) + rng.normal(0, 0.02, (q.shape[0], 3))
    res = diagnose_arm(ROBOT.dh_nominal, q, meas, robot=ROBOT, alpha=ALPHA)
    nt = res.to_json()["not_testable"]
    assert "of its range over the joint space" in nt["joint_compliance[2]"], nt
    assert ("joint_compliance", 2) not in res.selected


def test_other_generator_anisotropic_noise_backlash_found(rng):
    """Data made without the station's effects code: backlash by hand, tracker noise larger along the line of sight."""
    n = 160
    lim = ROBOT.joint_limits_rad
    q = rng.uniform(np.maximum(lim[:, 0], -2.5), np.minimum(lim[:, 1], 2.5), (n, 6))
    joint = int(rng.integers(1, 6))  # joints with a lever of a metre or so
    dirs = np.zeros(n)
    for k in range(1, n):
        dirs[k] = np.sign(q[k, joint - 1] - q[k - 1, joint - 1])
    b = rng.uniform(1.5, 2.5) * 0.03 / 1000.0 * 3  # rad: ~0.1 mm at a metre's lever
    q_true = q.copy()
    q_true[:, joint - 1] -= b * dirs
    dh_true = ROBOT.dh_nominal.copy()
    dh_true[:, [0, 2]] += rng.normal(0, 0.2, (7, 2))
    p = kin.tool_position(dh_true, q_true)
    los = p - np.array([3000.0, 0.0, 500.0])
    los /= np.linalg.norm(los, axis=1)[:, None]
    noise = rng.normal(0, 0.01, (n, 3)) + los * rng.normal(0, 0.02, (n, 1))
    res = diagnose_arm(ROBOT.dh_nominal, q, p + noise, robot=ROBOT, alpha=ALPHA, rows_in_motion_order=True)
    assert found(res, "backlash", joint), (joint, res.selected)
    assert len(res.selected) <= 3


def test_cli_json_keys_and_bad_input(rng, tmp_path, capsys):
    d = make_case(ROBOT, [("backlash", int(rng.integers(1, 7)))], rng, n=100, strength=(1.5, 2.0))
    csv_path = tmp_path / "a.csv"
    write_arm_csv(csv_path, np.degrees(d.q_rad), d.xyz_mm, t=d.t_s)
    out, rep, model = tmp_path / "d.json", tmp_path / "d.html", tmp_path / "m.json"
    assert main(["diagnose", "arm", "--robot", "industrial-3100", "--data", str(csv_path),
                 "--json", str(out), "--report", str(rep), "--model-out", str(model)]) == 0
    doc = json.loads(out.read_text())
    for key in ("steps", "final_heldout_rms", "noise_floor"):
        assert key in doc
    for key in ("effect", "joint", "params", "ci", "heldout_rms_before", "heldout_rms_after", "gain",
                "statistic", "threshold"):
        assert key in doc["steps"][0]
    assert rep.read_text().count("<svg") == len(doc["steps"])
    # the model file is the JSON's extended model, and it carries the named effects
    assert json.loads(model.read_text()) == doc["extended_model"]
    named = {(s["effect"], s["joint"]) for s in doc["steps"] if s["effect"] != "geometric"}
    assert {(e["effect"], e.get("joint")) for e in doc["extended_model"]["effects"]} == named
    assert doc["noise_floor_source"] and doc["selection"].startswith("nested")
    bad = tmp_path / "bad.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6,x,y\n1,2,3,4,5,6,7,8\n")
    out2 = tmp_path / "bad.json"
    assert main(["diagnose", "arm", "--robot", "industrial-3100", "--data", str(bad), "--json", str(out2)]) == 2
    assert not out2.exists()
    assert "missing column" in capsys.readouterr().err
