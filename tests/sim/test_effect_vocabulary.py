"""The effects' vocabulary: every effect names its parameters with a unit and the range any arm has."""

from __future__ import annotations

import numpy as np
import pytest

from station.errors import ConfigError
from station.models.effect_params import EffectSpec
from station.models.effects import EffectSet, realistic_effects
from station.models.robots import get_robot


def test_every_effect_declares_its_parameters_with_unit_and_range():
    es = EffectSet.none()
    for eff in es.effects:
        spec = eff.spec
        assert spec.name == eff.name
        assert spec.param_names == eff.param_names
        assert len(set(spec.param_names)) == len(spec.param_names)
        for p in spec.params:
            lo, hi = p.bounds
            assert lo < hi and np.isfinite([lo, hi]).all()
            assert p.unit, (eff.name, p)
            # the name carries the unit (house rule): b2_rad, c3_rad_per_Nm, k2_tcp_rad_per_kg, dT_max_K, a1_mm
            assert p.name.endswith("_" + p.unit.replace("/(N m)", "_per_Nm").replace("/", "_per_")), (eff.name, p)


@pytest.mark.parametrize("robot", ["industrial-3100", "rb5-850", "ur5e"])
def test_realistic_draws_lie_within_every_parameters_range(robot, rng):
    """No false alarm: what the station's realistic arm draws passes the screen of its own vocabulary."""
    es = realistic_effects(get_robot(robot), rng)
    for eff, params in zip(es.effects, es.params):
        for p, v in zip(eff.param_specs, params):
            assert p.check(float(v), f"{eff.name}.{p.name}") == float(v)


def test_a_value_beyond_the_range_is_refused_naming_parameter_and_unit():
    spec = EffectSet.none().effect("backlash").spec.param("b2_rad")
    with pytest.raises(ConfigError, match=r"m\.params\.b2_rad = 1.0 rad is beyond what an arm has"):
        spec.check(1.0, "m.params.b2_rad")
    with pytest.raises(ConfigError, match="must be a number"):
        spec.check(True, "m.params.b2_rad")


def test_an_effect_that_is_not_kinematic_has_the_same_shape():
    """A motion effect's ranges ((lowest, highest, unit) by key) make the same spec as a kinematic effect's."""
    creep = EffectSpec.from_table("creep", "approach", {"amplitude_mm": (-5.0, 5.0, "mm"), "tau_s": (1e-3, 60.0, "s")})
    assert creep.param_names == ("amplitude_mm", "tau_s")
    assert creep.param("tau_s").check(2.0, "creep.tau_s") == 2.0
    with pytest.raises(ConfigError, match="creep.tau_s = 120.0 s is beyond"):
        creep.param("tau_s").check(120.0, "creep.tau_s")
