"""The vocabulary of an effect: its name and its parameters, each with a unit and the range any arm has.

One shape for every effect the station models, kinematic or not:

* the kinematic effects of :mod:`station.models.effects` (geometry, thermal
  drift, encoder eccentricity, backlash, joint compliance) declare their
  parameters as :class:`ParamSpec` rows (:attr:`param_specs`), and the arm
  model file is screened with them (:mod:`station.models.arm_extended`);
* an effect that is not kinematic (a servo loop, creep, a structural mode:
  :mod:`station.models.motion_effects`) has the same three facts per
  parameter (``(lowest, highest, unit)`` by key) and fits the same row.

A parameter's range is the screen of model files (:mod:`station.models.arm_ranges`):
a value outside it is a unit or export error, refused naming the parameter.
Pure, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ParamSpec", "EffectSpec"]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    Attributes
    ----------
    name : str
        As files and results name it, with its unit (``b3_rad``, ``dT_max_K``).
    unit : str
        ``mm``, ``rad``, ``rad/(N m)``, ``rad/kg``, ``K``, ``1/K``, ``s``, ``Hz``, ... ("" for a pure number).
    bounds : (float, float)
        Lowest and highest value any arm has.
    """

    name: str
    unit: str
    bounds: tuple

    @classmethod
    def of_kind(cls, name: str, kind: str, unit: str | None = None) -> "ParamSpec":
        """A parameter screened by the model-file range ``kind`` (:data:`station.models.arm_ranges.LIMITS`)."""
        from station.models.arm_ranges import LIMITS

        lo, hi, u = LIMITS[kind]
        return cls(name, u if unit is None else unit, (lo, hi))

    def check(self, value, where: str) -> float:
        """``value`` as a float within :attr:`bounds`; ConfigError naming ``where`` and the unit otherwise."""
        from station.models.arm_ranges import check_number

        return check_number(value, where, self.bounds[0], self.bounds[1], self.unit)


@dataclass(frozen=True)
class EffectSpec:
    """An effect's name, what it acts on and its parameters.

    ``acts_on``: ``"table"`` (the kinematic table), ``"joint"`` (the joint
    angles), or a quantity of a motion (``"approach"``: the travel of a stop).
    """

    name: str
    acts_on: str
    params: tuple

    @classmethod
    def from_table(cls, name: str, acts_on: str, table: dict) -> "EffectSpec":
        """From ``{parameter: (lowest, highest, unit)}``, the form the motion model's ranges have
        (:data:`station.models.motion_effects.LIMITS`)."""
        return cls(name, acts_on, tuple(ParamSpec(k, unit, (lo, hi)) for k, (lo, hi, unit) in table.items()))

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def param(self, name: str) -> ParamSpec:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(name)
