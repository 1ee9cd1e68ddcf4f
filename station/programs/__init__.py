"""Robot motion programs: a dialect-neutral model, its builders and generators.

* :mod:`.program` -- targets, moves, dwells, loops, :class:`Program`; all
  validation of names, numbers and text from configs.
* :mod:`.builders` -- ISO 9283 pose cycle, vAP approaches, calibration poses.
* :mod:`.rapid` -- ABB RAPID; :mod:`.krl` -- KUKA KRL.
* :mod:`.handshake` -- the controller's Modbus register map and codes.
"""

from station.programs.builders import calibration_program, iso_pose_program, vap_program
from station.programs.krl import render_krl
from station.programs.program import (
    CartesianTarget,
    CycleMark,
    Dwell,
    JointTarget,
    Loop,
    Move,
    Program,
    RenderedProgram,
    Stop,
    expected_stops,
)
from station.programs.rapid import render_rapid

RENDERERS = {"rapid": render_rapid, "krl": render_krl}

__all__ = [
    "CartesianTarget",
    "CycleMark",
    "Dwell",
    "JointTarget",
    "Loop",
    "Move",
    "Program",
    "RENDERERS",
    "RenderedProgram",
    "Stop",
    "calibration_program",
    "expected_stops",
    "iso_pose_program",
    "render_krl",
    "render_rapid",
    "vap_program",
]
