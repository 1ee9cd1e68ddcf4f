"""The ranges a real arm's model can have: the screen of model files and UR calibration deltas.

A model file is input like a measurement file: a value no arm has (a link of
1e200 mm, a backlash of 1e300 rad, a thermal expansion of 1e300 /K) is a unit
or export error and is refused naming the key, never carried into a tool
point of 6e199 mm. The bounds are generous (a hundred times and more what the
station's realistic arm draws, :func:`station.models.effects.realistic_effects`)
and absolute, so they hold for any arm the station can meet.
"""

from __future__ import annotations

import math

from station.errors import ConfigError
from station.numeric import short_repr as _short

__all__ = ["LIMITS", "number_in", "check_number", "MAX_EFFECTS"]

#: (lowest, highest, unit) of each kind of value a model file holds
LIMITS = {
    # kinematic table and tool: the largest industrial arms reach some 4 m
    "length_mm": (-5000.0, 5000.0, "mm"),
    "tool_mm": (-3000.0, 3000.0, "mm"),
    # the instrument <- base transform: within the range of any instrument (1 km, as measured coordinates)
    "base_mm": (-1.0e6, 1.0e6, "mm"),
    "joint_limit_deg": (-720.0, 720.0, "deg"),
    "rotation": (-1.5, 1.5, ""),  # an entry of a rotation matrix (orthonormality is checked on its own)
    # joint effects, rad: a realistic arm has 1e-4 rad; 0.05 rad is 2.9 deg
    "joint_offset_rad": (-0.05, 0.05, "rad"),
    # compliance, rad per N m (or per kg at a point): a realistic arm has 1e-6..1e-4
    "compliance": (-0.01, 0.01, "rad per unit"),
    # thermal drift: steel 1.2e-5 /K, aluminium 2.3e-5 /K
    "alpha_per_K": (-1.0e-4, 1.0e-4, "1/K"),
    "dT_max_K": (-100.0, 100.0, "K"),
    "tau_s": (1.0, 1.0e6, "s"),
    "t0_s": (-1.0e10, 1.0e10, "s"),
    "reference_temperature_c": (-50.0, 150.0, "degC"),
    # UR calibration deltas (standard DH): angles within a half turn, lengths within a metre
    "delta_angle_rad": (-math.pi, math.pi, "rad"),
    "delta_length_m": (-1.0, 1.0, "m"),
}

#: most effects of an extended model: one of each joint effect per joint (3 x 6) and one thermal drift
MAX_EFFECTS = 19


def number_in(value, where: str, kind: str) -> float:
    """``value`` as a float if it is a finite number (not a bool) within ``LIMITS[kind]``; ConfigError naming ``where``."""
    lo, hi, unit = LIMITS[kind]
    return check_number(value, where, lo, hi, unit)


def check_number(value, where: str, lo: float, hi: float, unit: str) -> float:
    """``value`` as a float if it is a finite number (not a bool) within ``[lo, hi]``; ConfigError naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where} must be a number, got {_short(value)}")
    try:
        v = float(value)
    except OverflowError:  # an integer of hundreds of digits
        v = math.inf
    if isinstance(value, float) and not math.isfinite(v):
        raise ConfigError(f"{where} must be a finite number, got {_short(value)}")
    if not lo <= v <= hi:
        raise ConfigError(f"{where} = {_short(value)} {unit} is beyond what an arm has ({lo:g} to {hi:g} {unit}; "
                          "units? export error?)")
    return v
