"""URScript generator for :class:`~station.programs.program.Program` (a UR cobot's dialect).

Output: one ``def NAME(): ... end`` program, sent whole to the controller's
script port; loops are unrolled (URScript has ``while``, but a flat list is
what the station gated move by move)::

    def ST_P1():
      write_output_integer_register(12, 7)      # started: sequence number 7
      write_output_integer_register(14, 0)      # moves done
      write_output_integer_register(15, 0)      # cycles done
      movej([1.5708, -1.2, ...], a=13.96, v=3.1416)
      write_output_integer_register(14, 1)
      sleep(0.5)
      write_output_integer_register(13, 7)      # finished: sequence number 7
    end

Conventions the driver (:class:`drivers.ur.URDriver`) and the fake rely on:

* every move's joint target is the one the safety gate solved for it
  (``q_rad``, one per executed move, loop passes included), so the arm goes
  to the configuration that was checked; a linear move's pose is the target's
  own (``movel(p[x, y, z, rx, ry, rz])``, m and rotation vector);
* ``movej``'s ``v`` and ``a`` are ``speed_frac`` (``accel_frac``) x the
  slowest joint's limits (rad/s, rad/s^2), ``movel``'s the rated TCP speed and
  acceleration in m/s, m/s^2; a ``movel`` with an ``ori_speed_deg_s`` whose
  TCP stays where the move before left it only turns the tool: its ``v`` is
  that speed in rad/s and its ``a`` reaches it as soon as the line would
  (rad/s^2), the way UR's controller reads a pure rotation;
* a move ends in a stop (ISO 9283 measures poses at rest) unless it has a
  corner zone: then ``r`` is its blend radius in m (path tests); a circular
  move is ``movec(via, to, a, v, r, mode=0)`` (fixed orientation);
* output integer registers ``base`` .. ``base + 3``: the sequence number when
  the program starts, the same number when it ends, the moves done and the
  cycles done (``CycleMark``), which RTDE reports back to the driver.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from station.errors import ConfigError, SafetyError
from station.models import kinematics
from station.programs.program import CycleMark, Dwell, Loop, Move, Program, RenderedProgram

#: a linear move whose TCP moves less than this only turns the tool (its v and a in rad/s, rad/s^2), mm
TURN_ONLY_MM = 1e-3
#: registers after ``base``: started, finished, moves done, cycles done
REG_STARTED, REG_FINISHED, REG_MOVES, REG_CYCLES = 0, 1, 2, 3


def _num(x: float) -> str:
    if not math.isfinite(float(x)):
        raise SafetyError(f"non-finite number {x!r} in a URScript program")
    return repr(round(float(x), 9))


def _pose(T) -> str:
    """``p[x, y, z, rx, ry, rz]`` of a 4x4 pose in mm: metres and a rotation vector."""
    T = np.asarray(T, dtype=float)
    pose = list(T[:3, 3] / 1000.0) + list(Rotation.from_matrix(T[:3, :3]).as_rotvec())
    return f"p[{', '.join(_num(x) for x in pose)}]"


def executed(program: Program) -> list:
    """The program's instructions in execution order (loop bodies repeated ``count`` times)."""
    out = []
    for s in program.statements:
        if isinstance(s, Loop):
            for _ in range(s.count):
                out += list(s.body)
        else:
            out.append(s)
    return out


def render_urscript(program: Program, q_rad, *, robot, seq: int, register_base: int = 12,
                    rated_tcp_accel_mm_s2: float | None = None) -> RenderedProgram:
    """One URScript program for ``program``.

    Parameters
    ----------
    program : Program
    q_rad : array_like, shape (M, 6)
        The gated joint target of each executed move (:func:`executed` order).
    robot : RobotSpec
        Joint speed and acceleration limits.
    seq : int
        Sequence number written when the program starts and ends (1 .. 2**31 - 2).
    register_base : int
        First of the four output integer registers (0 .. 44).
    rated_tcp_accel_mm_s2 : float, optional
        Rated TCP acceleration of linear moves (default: rated speed / 0.5 s).
    """
    if not (isinstance(seq, int) and 0 < seq < 2**31 - 1):
        raise ConfigError(f"URScript sequence number must be in 1..2**31-2, got {seq!r}")
    if not (isinstance(register_base, int) and 0 <= register_base <= 44):
        raise ConfigError(f"register_base must be an integer 0..44, got {register_base!r}")
    steps = executed(program)
    moves = [s for s in steps if isinstance(s, Move)]
    q = np.asarray(q_rad, dtype=float).reshape(-1, 6)
    if len(q) != len(moves):
        raise ConfigError(f"program {program.name}: {len(moves)} moves but {len(q)} gated joint targets")
    v_joint = float(np.min(robot.joint_speed_limits_rad_s))
    a_joint = float(np.min(robot.joint_accel_limits_rad_s2))
    rated_accel = rated_tcp_accel_mm_s2 or program.rated_tcp_speed_mm_s / 0.5
    reg = {k: register_base + k for k in (REG_STARTED, REG_FINISHED, REG_MOVES, REG_CYCLES)}
    lines = [f"def {program.name.lower()}():",
             f"  write_output_integer_register({reg[REG_STARTED]}, {seq})",
             f"  write_output_integer_register({reg[REG_MOVES]}, 0)",
             f"  write_output_integer_register({reg[REG_CYCLES]}, 0)"]
    k = cycles = 0
    for s in steps:
        if isinstance(s, Move):
            if s.interpolation == "joint":
                args = ", ".join(_num(x) for x in q[k])
                lines.append(f"  movej([{args}], a={_num(program.accel_frac * a_joint)}, "
                             f"v={_num(s.speed_frac * v_joint)})")
            else:
                T = getattr(s.target, "pose", None)
                T = kinematics.fk(robot.dh_nominal, q[k]) if T is None else T
                a_m, v_m = program.accel_frac * rated_accel / 1000.0, s.speed_frac * program.rated_tcp_speed_mm_s / 1000.0
                if s.ori_speed_deg_s is not None and k > 0 and float(np.linalg.norm(
                        np.asarray(T)[:3, 3] - kinematics.tool_position(robot.dh_nominal, q[k - 1]))) < TURN_ONLY_MM:
                    w = math.radians(s.ori_speed_deg_s)  # only turns: rad/s, reaching it as soon as the line would
                    a_m, v_m = w * a_m / v_m, w
                av = f"a={_num(a_m)}, v={_num(v_m)}"
                blend = f", r={_num(s.zone_mm / 1000.0)}" if s.zone_mm > 0 else ""
                if s.interpolation == "circular":
                    lines.append(f"  movec({_pose(s.via.pose)}, {_pose(T)}, {av}{blend}, mode=0)")
                else:
                    lines.append(f"  movel({_pose(T)}, {av}{blend})")
            k += 1
            lines.append(f"  write_output_integer_register({reg[REG_MOVES]}, {k})")
        elif isinstance(s, Dwell):
            if s.seconds > 0:
                lines.append(f"  sleep({_num(s.seconds)})")
        elif isinstance(s, CycleMark):
            cycles += 1
            lines.append(f"  write_output_integer_register({reg[REG_CYCLES]}, {cycles})")
        else:
            raise ConfigError(f"program {program.name}: cannot render {type(s).__name__} in URScript")
    lines += [f"  write_output_integer_register({reg[REG_FINISHED]}, {seq})", "end", ""]
    name = f"{program.name.lower()}.script"
    return RenderedProgram(dialect="urscript", files={name: "\n".join(lines)}, main_file=name, program=program)


__all__ = ["render_urscript", "executed", "REG_STARTED", "REG_FINISHED", "REG_MOVES", "REG_CYCLES"]
