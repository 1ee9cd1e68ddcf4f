"""Issue 43 items 3 and 4: the named effect's gain reaches unseen poses of lab-shaped sets, and encoder
eccentricity and joint compliance are told apart where the poses allow it (both named where they do not).
Every hidden effect, its joint, size and the poses are drawn at random; the seed is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fakes.sim.real_like_arms import LAB_EFFECTS, _link_mass_torques, lab_shaped, rokae_like
from station.analysis.diagnose import diagnose_arm
from station.models import kinematics as kin
from station.models.arm_extended import ExtendedArm, terms_from_json
from station.models.arm_model_file import model_from_json
from station.models.robots import get_robot
from tests.calibration.reference_fit import plain_fit
from tests.diagnosis.hidden import found, make_case

N_CASES = 8


def _unseen_rms(d, res) -> float:
    """3-D RMS error of the written model (as a model file holds it) on the unseen poses, mm."""
    return float(np.sqrt(np.mean(_unseen_sq(d, res))))


def _unseen_sq(d, res) -> np.ndarray:
    """Per unseen pose, the written model's squared 3-D error, mm^2."""
    doc = res.extended_model()
    dh_e, B_e, _ = model_from_json(doc)
    arm = ExtendedArm("x", dh_e, B_e, d.robot.joint_limits_rad, terms_from_json(doc["effects"], "m"),
                      gravity_model=d.robot)
    return np.sum((arm.predict(d.q_unseen_rad) - d.xyz_unseen_mm) ** 2, axis=1)


def _plain_sq(d) -> np.ndarray:
    """Per unseen pose, a plain geometric fit's squared 3-D error, mm^2."""
    dh, B = plain_fit(d.dh_nominal, d.q_rad, d.xyz_mm)
    return np.sum((kin.tool_position(dh, d.q_unseen_rad) @ B[:3, :3].T + B[:3, 3] - d.xyz_unseen_mm) ** 2, axis=1)


def _plain_rms(d) -> float:
    return float(np.sqrt(np.mean(_plain_sq(d))))


@pytest.mark.timeout(600)
def test_lab_shaped_effects_reach_unseen_poses(test_seed):
    """Eight 40-pose sets of an RB5-850 as built, 0.05 mm noise, one hidden effect drawn from compliance or
    eccentricity on J2 or J3 (tool-point RMS U(1.2, 2.0) x the noise), 120 unseen poses. The written model beats
    a plain geometric fit of the same 40 poses on the unseen ones in every case (within three standard errors of
the poses' paired differences) and by 10 % on average (issue 43's
    acceptance), and it reaches the noise: its mean squared unseen error exceeds the noise's ``3 s^2`` by no more
    than a least-squares fit of its p parameters to 3n coordinates does at new poses, ``3 s^2 p / 3n``, taken
    twice for the spread of the poses' leverage, plus four standard errors of the mean of 8 x 120 chi-square(3)
    draws. With the geometry held at the calibration (the effect fitted on the residual it left) the written
    model was 0.82x a plain fit on average, an oracle that knows the effect's form 0.63x, the written model now
    0.64x (10 draws, bench/bench_diagnosis_lab.py)."""
    rng = np.random.default_rng(test_seed)
    ratios, mse, bound, named = [], [], [], 0
    for _ in range(N_CASES):
        hidden = LAB_EFFECTS[int(rng.integers(len(LAB_EFFECTS)))]
        d = lab_shaped(rng, hidden)
        res = diagnose_arm(d.dh_nominal, d.q_rad, d.xyz_mm, robot=d.robot)
        sq_w, sq_p = _unseen_sq(d, res), _plain_sq(d)
        w, pl = float(np.sqrt(np.mean(sq_w))), float(np.sqrt(np.mean(sq_p)))
        ratios.append(w / pl)
        # not worse than the plain fit beyond the unseen poses' sampling of the difference (paired over the
        # 120 poses, 3 standard errors): a case 1 % worse (0.1326 against 0.1313 mm, CI seed 3546012294) was
        # within 0.3 of them
        diff = sq_w - sq_p
        assert diff.mean() <= 3.0 * diff.std(ddof=1) / math.sqrt(diff.size), (
            test_seed, hidden, w, pl, res.selected, res.written)
        s2 = d.noise_mm ** 2
        p = res.state_all.n_params
        mse.append(w ** 2)
        bound.append(3.0 * s2 * (1.0 + 2.0 * p / (3.0 * d.q_rad.shape[0])))
        named += found(res, *hidden)
    assert float(np.mean(ratios)) <= 0.9, (test_seed, ratios)
    se = 3.0 * d.noise_mm ** 2 * math.sqrt(6.0 / 9.0 / (N_CASES * d.q_unseen_rad.shape[0]))
    assert float(np.mean(mse)) <= float(np.mean(bound)) + 4.0 * se, (test_seed, np.mean(mse), np.mean(bound), ratios)
    assert named >= 6, (test_seed, named)


def test_lab_shaped_set_without_an_effect_names_none(test_seed):
    """The same sets with nothing hidden: geometry alone. Each round's test holds its family-wise false-discovery
    rate at alpha (0.05 by default: 1 effect-free set of 12 in the bench named one), so what is named there is
    marginal (its statistic within 2.5x its threshold, as tests/diagnosis/test_arm_diagnosis.py bounds a nominal
    arm's), at most one,
    and it costs the unseen poses nothing against a plain fit."""
    rng = np.random.default_rng(test_seed)
    for _ in range(2):
        d = lab_shaped(rng, None)
        res = diagnose_arm(d.dh_nominal, d.q_rad, d.xyz_mm, robot=d.robot)
        extra = [s for s in res.steps if s.term.kind != "geometric"]
        assert len(extra) <= 1, (test_seed, res.selected)
        for st in extra:
            assert st.statistic < 2.5 * st.threshold, (test_seed, st.term.key, st.statistic, st.threshold)
        assert _unseen_rms(d, res) <= 1.02 * _plain_rms(d), (test_seed, res.selected, res.written)


def _rokae_with(rng, effect: str, joints_moving=None, noise_mm=0.05):
    """240 ROKAE-like poses spread over the joint space (no mass model: the diagnosis's compliance basis is 1 kg
    at the elbow and at the tool), ``noise_mm`` (0.05 mm) of noise, J2 with 0.03-0.05 deg of eccentricity (a random
    phase) or of gravity sag of masses along the links (not the diagnosis's basis)."""
    d = rokae_like(rng, n=240, hidden=False, noise_mm=noise_mm)
    q = d.q_rad.copy()
    if joints_moving is not None:
        q[:, joints_moving:] = q[0, joints_moving:]
    size = math.radians(rng.uniform(0.03, 0.05))
    dq = np.zeros_like(q)
    if effect == "encoder_eccentricity":
        dq[:, 1] = size * np.sin(q[:, 1] + rng.uniform(0.0, 2.0 * np.pi))
    else:
        tau = _link_mass_torques(d.dh_true, q)[:, 1]
        dq[:, 1] = -size * tau / np.max(np.abs(tau))
    B = d.base_T
    xyz = kin.tool_position(d.dh_true, q + dq) @ B[:3, :3].T + B[:3, 3]
    xyz = xyz + rng.normal(0.0, d.noise_mm, xyz.shape)
    return diagnose_arm(d.dh_nominal, q, xyz, t_s=d.t_s)


@pytest.mark.parametrize("effect, rival", [("encoder_eccentricity", "joint_compliance"),
                                           ("joint_compliance", "encoder_eccentricity")])
def test_eccentricity_and_compliance_told_apart_on_spread_poses(test_seed, effect, rival):
    """On 240 spread poses the hidden one is chosen, with its joint, and the rival is not: neither on J2 nor on
    another joint (issue 43: 0.04 deg of eccentricity on J2 was named as compliance on J2 and J3). Where the
    poses cannot tell them apart (an eccentricity whose phase puts it within a few degrees of the once-per-turn
    torque of the elbow's mass: what compliance cannot produce of it is, after the geometry, within the noise,
    test seed 1422158423) either may go first, and the step names the other as a candidate with both
    statistics, neither significant beyond the other (issue 43 item 4): the hidden one is never left out."""
    rng = np.random.default_rng(test_seed)
    res = _rokae_with(rng, effect)
    pair = {(effect, 2), (rival, 2)}
    assert not pair <= set(res.selected), (test_seed, res.selected)
    step = next((s for s in res.steps if (s.term.effect, s.term.joint) in pair), None)
    assert step is not None, (test_seed, res.selected)
    named = (step.term.effect, step.term.joint)
    if named == (rival, 2):
        hidden = [a for a in step.ambiguous_with if (a["effect"], a["joint"]) == (effect, 2)]
        assert hidden and "cannot be told apart" in hidden[0]["note"], (test_seed, res.selected, step.ambiguous_with)
        assert not (hidden[0]["beyond_it"] or 0.0) > 1.0 and not (hidden[0]["it_beyond"] or 0.0) > 1.0, hidden
    # beyond the geometry and the pair's term, at most one chance discovery at the diagnosis's alpha: 2 of 100
    # draws named one (backlash on J3, J5), and once the rival on J3 at 1.04 times its threshold (test seed
    # 865806324), against the rival on J2 and J3 at once that issue 43 saw
    extra = [s for s in res.selected if s not in {("geometric", None), named}]
    assert len(extra) <= 1, (test_seed, res.selected)
    # the evidence is in the JSON: each rival told apart, or named as a candidate, with both statistics
    doc = next(s for s in res.to_json()["steps"] if (s["effect"], s["joint"]) == named)
    for a in doc["told_apart_from"]:
        assert a["it_beyond"] > 1.0 and not (a["beyond_it"] or 0.0) > 1.0, a
    for a in step.ambiguous_with:
        if (a["effect"], a["joint"]) in pair and "beyond_it" in a:
            assert not (a["beyond_it"] or 0.0) > 1.0 and not (a["it_beyond"] or 0.0) > 1.0, a


def test_eccentricity_and_compliance_both_named_where_the_poses_cannot_tell(test_seed):
    """Only J1 and J2 move: J2's gravity torque is then a once-per-turn function of q2, the two effects are the
    same columns, and the step names the other one as a candidate with the evidence (never 'told apart')."""
    rng = np.random.default_rng(test_seed)
    effect = ("encoder_eccentricity", "joint_compliance")[int(rng.integers(2))]
    # a tracker of half the noise (25 um): with J1 and J2 alone most of a once-per-turn term of q2 is J2's zero and
    # the link's geometry, and at 50 um the rest was under its threshold on some draws (statistic 3.5 against 4.7,
    # test seed 827479951, the same on the code before the effects were written once; a larger effect is refused
    # beyond a real joint's 5 arcmin). At 25 um it is still at the edge on a few draws (1 of 26): there nothing may
    # be named in its place, and the ambiguity is not tested
    res = _rokae_with(rng, effect, joints_moving=2, noise_mm=0.025)
    pair = {("encoder_eccentricity", 2), ("joint_compliance", 2)}
    step = next((s for s in res.steps if (s.term.effect, s.term.joint) in pair), None)
    if step is None:
        assert [s.term.kind for s in res.steps] == ["geometric"], (test_seed, res.selected)
        return
    other = (pair - {(step.term.effect, step.term.joint)}).pop()
    assert not any((a["effect"], a["joint"]) == other for a in step.told_apart), (test_seed, step.told_apart)
    tested = {ct.key: ct for ct in res.rounds[1]}
    if tested.get(f"{other[0]}[2]") is not None and tested[f"{other[0]}[2]"].significant:
        entry = next(a for a in step.ambiguous_with if (a["effect"], a["joint"]) == other)
        assert "cannot be told apart" in entry["note"] and "beyond_it" in entry, entry


ROBOT = get_robot("industrial-3100")


def _rival_goes_first(res, effect: str, joint: int | None) -> bool:
    """Issue 43 item 4: a hidden eccentricity whose rival, compliance on the same joint, was chosen, and the step
    names it as a candidate that cannot be told apart, with both statistics and neither significant beyond the
    other (as :func:`test_eccentricity_and_compliance_told_apart_on_spread_poses` accepts)."""
    if effect != "encoder_eccentricity":
        return False
    step = next((s for s in res.steps if (s.term.effect, s.term.joint) == ("joint_compliance", joint)), None)
    if step is None:
        return False
    return any((a["effect"], a["joint"]) == (effect, joint) and "cannot be told apart" in a["note"]
               and a.get("beyond_it") is not None and a.get("it_beyond") is not None
               and not a["beyond_it"] > 1.0 and not a["it_beyond"] > 1.0 for a in step.ambiguous_with)


@pytest.mark.parametrize("effect", ["backlash", "encoder_eccentricity", "joint_compliance", "thermal_drift"])
def test_hidden_effect_named_with_its_joint_on_240_spread_poses(rng, effect):
    """The earlier diagnosis tests' hidden effects on 240 spread poses: each named with its joint again. An
    eccentricity may go second to compliance on its joint only where the step says the poses cannot tell the two
    apart (:func:`_rival_goes_first`). Session seed 1049860001: eccentricity on J2, whose columns beyond the
    geometry the compliance's lie within at a cosine of 0.95; what the hidden one holds beyond the compliance had a
    noncentrality of 15 against the 15.5 its threshold needs (classical variance: told apart on about half such
    draws); on the draw its statistic beyond the compliance was 0.07 of its threshold and the compliance's beyond
    it 0.25, the compliance fitted as well, went first and names the eccentricity with it."""
    from tests.diagnosis.hidden import compliance_joints

    joint = None if effect == "thermal_drift" else int(
        rng.choice(compliance_joints(ROBOT) if effect == "joint_compliance" else np.arange(1, 6)))
    d = make_case(ROBOT, [(effect, joint)], rng, n=240, strength=(0.8, 1.2))
    res = diagnose_arm(ROBOT.dh_nominal, d.q_rad, d.xyz_mm, t_s=d.t_s, robot=ROBOT, alpha=0.01)
    assert found(res, effect, joint), (effect, joint, res.selected)
    assert (effect, joint) in res.selected or effect == "joint_compliance" or _rival_goes_first(res, effect, joint), (
        effect, joint, res.selected, [s.ambiguous_with for s in res.steps])
