"""A plan's stored parameters (procedures.plan_params): JSON and back gives the same plan, for every
procedure's plan; a run stored before a field existed takes the field's default."""

import json

from app.acceptance import Station
from procedures.arm_calibration import ArmCalPlan
from procedures.arm_calibration import plan_from_config as arm_plan
from procedures.iso9283 import IsoPlan
from procedures.iso9283 import plan_from_config as iso_plan
from procedures.plan_params import plan_from_params, plan_params
from procedures.trailer import TrailerCalibrationPlan


def _json(p: dict) -> dict:
    return json.loads(json.dumps(p))


def test_every_plan_comes_back_from_its_json(rng, tmp_path):
    station = Station.fake(tmp_path, seed=int(rng.integers(2**31)))
    iso = iso_plan(station.config, "r1")
    arm = arm_plan(station.config, "r1", selection_seed=int(rng.integers(2**31)))
    trailer = TrailerCalibrationPlan(commands=(("H", float(rng.uniform(0.05, 0.3))), ("L", 0.1)),
                                     duration_s=float(rng.uniform(20, 80)), compare=("M17",))
    for plan, cls in ((iso, IsoPlan), (arm, ArmCalPlan), (trailer, TrailerCalibrationPlan)):
        stored = _json(plan_params(plan))
        back = plan_from_params(cls, stored)
        assert back == plan
        assert _json(plan_params(back)) == stored
    stored = _json(iso.params())
    assert stored["robot"] == iso.robot.name and isinstance(stored["poses_mm"]["P1"], list)
    assert isinstance(IsoPlan.from_params(stored).poses_mm["P1"], tuple)
    assert all(isinstance(q, tuple) for q in ArmCalPlan.from_params(_json(arm.params())).q_deg)


def test_a_run_stored_before_a_field_existed_takes_its_default(rng, tmp_path):
    station = Station.fake(tmp_path, seed=int(rng.integers(2**31)))
    plan = iso_plan(station.config, "r1")
    stored = _json(plan.params())
    for newer in ("registration", "axis_sweep_deg", "axis_sweep_points", "decision_rule", "uncertainty"):
        del stored[newer]
    back = IsoPlan.from_params(stored)
    assert back.decision_rule == "simple" and back.uncertainty is None
    assert back.axis_sweep_deg == (25.0, 30.0) and back.axis_sweep_points == 13
    del stored["cycles"], stored["robot"]
    try:
        IsoPlan.from_params(stored)
    except KeyError as exc:
        assert "robot" in str(exc)
    else:
        raise AssertionError("a plan without its robot was built")
