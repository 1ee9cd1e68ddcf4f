"""One physics of the arm's effects: the diagnosis's candidate terms are the simulated world's effects to first order.

Each effect is drawn at random (realistic size and shape), switched on in the
simulated world (:class:`station.models.effects.EffectSet` through
:class:`fakes.sim.diagnosis_data.ArmDataset`, the world of ``station simulate
arm``), and the world's displacement of the measured points is compared with
what the diagnosis's terms for that effect predict (their Jacobian columns at
the nominal model, :func:`station.analysis.diagnose.arm_fit.jacobian`, times the
drawn parameters).

If the terms are the effect's linearisation, the difference is of second
order in the effect's size ``s``: ``r(s) = a s^2 (1 + x)`` with ``x`` of the
order of the effect's angles (1e-4 rad here), so ``r(s) / r(s/4) = 16 (1 + x) /
(1 + x / 4)``, which is above 8 for any ``|x| < 0.57``. A term that differs
from the effect at first order (a wrong sign, scale or shape) leaves a
residual linear in ``s`` once that error exceeds ``a s``: the ratio falls to
4. The threshold 8 is the geometric mean of the two (the test checks that a
term 1 % off gives a ratio below it).

The thermal drift is a length scale, and the tool position is linear in the
lengths: its term is exact, and the residual is at the rounding of the
kinematics (checked as such).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fakes.sim.diagnosis_data import simulate_arm_data
from station.analysis.diagnose.arm_fit import ModelState, jacobian
from station.analysis.diagnose.terms import TAU_GRID_S, Term, compliance_effect, joint_terms, thermal_terms
from station.models.effects import EffectSet, Geometric, motion_directions, realistic_effects
from station.models.robots import get_robot

ROBOT = get_robot("industrial-3100")
#: r(s) / r(s/4) of a term right to first order is 16 (1 + x) / (1 + x / 4); of one wrong at first order 4
RATIO_THRESHOLD = 8.0
JOINT_EFFECTS = ("encoder_eccentricity", "backlash", "joint_compliance")


def _dataset(rng):
    """The world's poses in motion order, a random instrument frame and payload; the arm starts working at the
    first pose (so the warm-up's clock is the diagnosis's ``t - t_first``)."""
    d = simulate_arm_data(ROBOT, EffectSet.none(), rng, n=120, load_kg=float(rng.uniform(0.0, 20.0)))
    return replace(d, t_s=d.t_s - d.t_s.min())


def _state(d) -> ModelState:
    return ModelState(np.asarray(ROBOT.dh_nominal, dtype=float), d.base_T[:3, :3].copy(), d.base_T[:3, 3].copy())


#: the world's compliance has the diagnosis's basis (the mass model and 1 kg at the TCP)
OPTIONS = {"joint_compliance": {"basis": compliance_effect(ROBOT).basis}}


def _world(effect: str, params) -> EffectSet:
    """The world's arm with ``effect`` alone switched on."""
    return EffectSet.from_params({effect: params}, options=OPTIONS)


def _effect(effect: str):
    return EffectSet.from_params({}, options=OPTIONS).effect(effect)


def _draw(effect: str, d, rng):
    """``(terms, world parameters)``: the diagnosis's terms of ``effect`` on these poses and a realistic draw of
    the effect's parameters, zero where the diagnosis has no term (a joint it cannot test, a basis column it
    dropped)."""
    real = realistic_effects(ROBOT, rng)
    if effect == "geometric":
        geo = Geometric()
        term = Term("geometric", None, "geometric", geo.param_names, index=np.arange(len(geo.param_names)))
        return [term], real.get("geometric")
    if effect == "thermal_drift":
        tau = float(rng.choice(TAU_GRID_S))
        variants, why = thermal_terms(t_s=d.t_s)
        assert why is None, why
        terms = [t for t in variants if t.extra["tau_s"] == tau]
        return terms, np.array([rng.uniform(2.0, 6.0), tau])
    terms, _ = joint_terms(ROBOT.dh_nominal, d.q_rad, motion_directions(d.q_rad), robot=ROBOT, load_kg=d.load_kg)
    terms = [t for t in terms if t.effect == effect]
    eff = _effect(effect)
    names = eff.param_names
    m = len(eff.per_joint)
    if effect == "joint_compliance":
        # the mass model's column at the realistic compliance, the TCP column a realistic mass error (U(-2, 2) kg
        # at the tool point, in the same compliance)
        c = real.get("joint_compliance")
        P = np.column_stack([c, c * rng.uniform(-2.0, 2.0, 6)]).reshape(-1)
    else:
        P = real.get(effect)
    kept = np.zeros(6 * m)
    for t in terms:
        for nm in t.param_names:
            kept[names.index(nm)] = 1.0
    return terms, P * kept


def _theta(term: Term, effect: str, params) -> np.ndarray:
    if term.kind == "geometric":
        return params[term.index]
    if term.kind == "scale":
        return params[:1]
    names = _effect(effect).param_names
    return np.array([params[names.index(nm)] for nm in term.param_names])


def _residual_rms(effect: str, terms, params, d, scale: float, *, term_error: float = 0.0) -> tuple[float, float]:
    """RMS (mm) of the world's displacement at ``scale`` times the drawn parameters minus the terms' prediction,
    and of the displacement itself."""
    p = np.array(params, dtype=float)
    if effect == "thermal_drift":
        p[0] *= scale  # the size is dT_max; tau is the effect's shape
    else:
        p *= scale
    world = d.true_points(ROBOT, _world(effect, p)) - d.true_points(ROBOT, EffectSet.none())
    rows = np.arange(d.q_rad.shape[0])
    _, _, cols = jacobian(_state(d), d.q_rad, rows, extra_terms=terms)
    pred = sum(np.einsum("nik,k->ni", A, _theta(t, effect, p)) for t, A in cols)
    pred = pred * (1.0 + term_error)
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))  # noqa: E731
    return rms(world - pred), rms(world)


@pytest.mark.parametrize("effect", ["geometric", *JOINT_EFFECTS])
def test_each_term_is_the_worlds_effect_to_first_order(effect, rng):
    d = _dataset(rng)
    terms, params = _draw(effect, d, rng)
    assert terms, f"the diagnosis has no term of {effect} on 120 spread poses"
    r_full, disp = _residual_rms(effect, terms, params, d, 1.0)
    r_quarter, _ = _residual_rms(effect, terms, params, d, 0.25)
    # the displacement is far above the residual (first order right) and the residual shrinks with the square
    assert r_full < 0.05 * disp, (effect, r_full, disp)
    assert r_full / r_quarter > RATIO_THRESHOLD, (effect, r_full, r_quarter, disp)
    # and the test tells a term 1 % off at first order: its residual shrinks only linearly
    w_full, _ = _residual_rms(effect, terms, params, d, 1.0, term_error=0.01)
    w_quarter, _ = _residual_rms(effect, terms, params, d, 0.25, term_error=0.01)
    assert w_full / w_quarter < RATIO_THRESHOLD, (effect, w_full, w_quarter)


def test_thermal_term_is_the_worlds_drift_exactly(rng):
    """The warm-up term at the world's time constant predicts the drift to the rounding of the kinematics: the
    tool position is linear in the link lengths the drift scales."""
    d = _dataset(rng)
    terms, params = _draw("thermal_drift", d, rng)
    assert len(terms) == 1
    for scale in (1.0, 0.25):
        r, disp = _residual_rms("thermal_drift", terms, params, d, scale)
        assert disp > 1e-3, disp  # a drift the test can see (tens of micrometres)
        assert r < 1e-9 * max(disp, 1.0) + 1e-9, (scale, r, disp)
    # a term at another time constant is not the drift
    other = [t for t in thermal_terms(t_s=d.t_s)[0] if t.extra["tau_s"] != params[1]][0]
    r_other, disp = _residual_rms("thermal_drift", [other], params, d, 1.0)
    assert r_other > 1e-3 * disp, (r_other, disp)
