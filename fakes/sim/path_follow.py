"""How the simulated controllers follow a path programme: runs of blended moves, the interpolator's ripple.

A programme with a corner zone or a circular move is a *path programme*:
the controller interpolates its Cartesian moves with the path interpolator
(:mod:`station.models.cartesian_path`): consecutive linear and circular moves
whose zones blend them form one *run*, rounded at its corners by the zones,
planned as one speed profile from rest to the run's fine target, with the
interpolator's speed ripple on it. The arm then follows the run's joint
knots through its servo (:meth:`fakes.sim.arm.SimArm.move_knots`), which
adds the speed-dependent lag and overshoot of a real arm. A programme with
fine stops only (the pose tests) keeps the pose planner.

The ripple is drawn per robot and seed (:func:`ripple_of`: amplitude and
frequency from the world's seed, the phase from each run's own key, so each
cycle ripples a little differently and a resumed run meets the same ripple).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.models import cartesian_path as cp
from station.models import kinematics as kin
from station.programs.program import Loop, Move, Program

__all__ = ["Run", "is_path_program", "group_runs", "ripple_of", "queue_run", "queue_segments"]

#: range of the interpolator's relative speed ripple (1 sigma of nothing: uniform), and of its frequency, Hz
RIPPLE_AMPLITUDE = (0.002, 0.01)
RIPPLE_FREQUENCY_HZ = (2.0, 9.0)


@dataclass
class Run:
    """Consecutive path moves that blend into one another (the last one ends fine, or the programme does)."""

    moves: list
    cycle: int


def _moves(program: Program):
    for s in program.statements:
        yield from (s.body if isinstance(s, Loop) else (s,))


def is_path_program(program: Program) -> bool:
    """A programme with a corner zone or a circular move."""
    return any(isinstance(m, Move) and (m.zone_mm > 0 or m.interpolation == "circular") for m in _moves(program))


def group_runs(items):
    """``(instruction, cycle)`` items with consecutive blended path moves joined into :class:`Run` items.

    A run grows while its last move has a zone and the next item is a linear or circular move; anything
    else (a dwell, a cycle mark, a joint move) ends it at a stop.
    """
    run: Run | None = None
    for ins, cycle in items:
        path_move = isinstance(ins, Move) and ins.interpolation != "joint"
        if run is not None and path_move and run.moves[-1].zone_mm > 0:
            run.moves.append(ins)
            continue
        if run is not None:
            yield run, run.cycle
            run = None
        if path_move:
            run = Run([ins], cycle)
        else:
            yield ins, cycle
    if run is not None:
        yield run, run.cycle


def ripple_of(seed: int, key=None) -> cp.Ripple:
    """The interpolator's ripple of a world's robot (``seed``), its phase drawn from a run's ``key``."""
    g = np.random.default_rng([int(seed), 9283])
    amp = float(g.uniform(*RIPPLE_AMPLITUDE))
    freq = float(g.uniform(*RIPPLE_FREQUENCY_HZ))
    phase_rng = np.random.default_rng([int(seed), 9284, *(int(k) for k in (key or ()))])
    return cp.Ripple(amp, freq, float(phase_rng.uniform(0.0, 2.0 * math.pi)))


def queue_run(arm, robot, run: Run, *, rated_tcp_speed_mm_s: float, accel_mm_s2: float, ripple: cp.Ripple,
              noise_key=None):
    """Plan ``run`` from where the arm's queue ends and queue it on ``arm``; returns the arm's Move."""
    segs = [cp.Segment(m.target.pose, m.speed_frac * rated_tcp_speed_mm_s, m.zone_mm,
                       None if m.via is None else np.asarray(m.via.xyz_mm, float)) for m in run.moves]
    return queue_segments(arm, robot, segs, accel_mm_s2=accel_mm_s2, ripple=ripple, noise_key=noise_key)


def queue_segments(arm, robot, segments: list, *, accel_mm_s2: float, ripple: cp.Ripple, noise_key=None):
    """Plan blended ``segments`` (:class:`~station.models.cartesian_path.Segment`) from where the arm's queue
    ends, to rest at the last one's target, and queue them on ``arm``; returns the arm's Move."""
    q0 = np.asarray(arm.moves[-1].q_target_rad if arm.moves else arm.commanded_q_rad(arm.clock.now()),
                    dtype=float).reshape(6)
    segs = list(segments)
    segs[-1] = cp.Segment(segs[-1].end_pose, segs[-1].speed_mm_s, 0.0, segs[-1].via_mm)  # the run ends at rest
    accel = float(accel_mm_s2)
    for _ in range(3):  # an axis that cannot follow the path acceleration lowers it (the cruise speed stays)
        plan = cp.plan_path(kin.fk(robot.dh_nominal, q0), segs, accel_mm_s2=accel,
                            ipo_period_s=arm.ipo_period_s, jerk_time_s=arm.jerk_time_s, ripple=ripple)
        t_k, q_k, a_ratio = cp.solve_knots(robot.dh_nominal, q0, plan, robot.joint_limits_rad,
                                           robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2)
        if a_ratio <= 1.0:
            break
        accel /= 1.02 * a_ratio
    return arm.move_knots(t_k, q_k, noise_key=noise_key)
