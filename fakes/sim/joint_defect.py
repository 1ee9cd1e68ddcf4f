"""A localised joint defect of the simulated arm: a damaged gear tooth or a flaw on an encoder disc.

Over a few degrees around one angle of one joint the joint sits off its encoder reading by up to
``amplitude``; elsewhere it is exact:

``q_true_j += amplitude * exp(-(q_j - centre)^2 / (2 width^2))``

with ``q_j`` the encoder angle. A pose whose joint ``j`` stands in the flaw is off by the joint's lever
times the amplitude; every pose and sweep point a few widths away is untouched. That is the "one pose
out" robot of a plant's acceptance tests: one pose out of spec, the others in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import ConfigError


@dataclass(frozen=True)
class JointDefect:
    """``joint`` 1..6; ``centre_deg``, ``width_deg`` (> 0) and ``amplitude_deg`` of the flaw."""

    joint: int
    centre_deg: float
    width_deg: float
    amplitude_deg: float

    def __post_init__(self) -> None:
        if isinstance(self.joint, bool) or not isinstance(self.joint, int) or not 1 <= self.joint <= 6:
            raise ConfigError(f"joint_defect.joint must be 1..6, got {self.joint!r}")
        for name in ("centre_deg", "width_deg", "amplitude_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"joint_defect.{name} must be a finite number, got {v!r}")
        if self.width_deg <= 0:
            raise ConfigError(f"joint_defect.width_deg must be > 0, got {self.width_deg!r}")

    @classmethod
    def from_dict(cls, d) -> "JointDefect":
        if isinstance(d, JointDefect):
            return d
        if not isinstance(d, dict):
            raise ConfigError(f"joint_defect must be a table, got {type(d).__name__}")
        unknown = set(d) - {"joint", "centre_deg", "width_deg", "amplitude_deg"}
        if unknown:
            raise ConfigError(f"joint_defect: unknown key(s) {', '.join(sorted(unknown))}")
        try:
            return cls(int(d["joint"]), float(d["centre_deg"]), float(d["width_deg"]), float(d["amplitude_deg"]))
        except KeyError as exc:
            raise ConfigError(f"joint_defect needs {exc.args[0]}") from None

    def to_dict(self) -> dict:
        return {"joint": self.joint, "centre_deg": self.centre_deg, "width_deg": self.width_deg,
                "amplitude_deg": self.amplitude_deg}

    def offset_rad(self, q_rad) -> np.ndarray:
        """The joint's offset (rad) at encoder angles ``q_rad`` (N, 6) -> (N,)."""
        qj = np.asarray(q_rad, dtype=float)[..., self.joint - 1]
        x = (qj - math.radians(self.centre_deg)) / math.radians(self.width_deg)
        return math.radians(self.amplitude_deg) * np.exp(-0.5 * x * x)

    def apply(self, q_encoder_rad, q_true_rad) -> np.ndarray:
        """``q_true_rad`` with the flaw's offset added to its joint (at the encoder angles)."""
        out = np.array(q_true_rad, dtype=float, copy=True)
        out[..., self.joint - 1] += self.offset_rad(q_encoder_rad)
        return out
