"""A lab's program replayed on the simulated cell (``station simulate iso9283 --program FILE``).

The program (:mod:`station.readers.motion_program`) names poses (joint
angles, or base-frame positions with the orientation nominal IK finds for the
first of them from the home pose), a cycle's order of moves (joint or linear,
speed, acceleration, profile), the dwell after each move, the cycles, the
payload, the tracker rate and the controller's speed override. The arm goes to
the start pose unrecorded, the tracker records a wait there, then the cycles
(:func:`fakes.sim.iso_run.record_run`: the same ``stream.csv``, ``poses.csv``
and ``truth.json`` as the ISO run, every pose of the program in ``poses.csv``).

A joint move's speed and acceleration are those of its leading joint (the one
that travels farthest), as a UR controller's ``movej`` takes them: every
joint's profile is that one scaled, so all finish together. The speed
override ``f`` scales speeds by ``f`` and accelerations by ``f^2`` (the move
keeps its shape and takes ``1 / f`` the time). Without a speed, acceleration
or profile a move takes the controller's defaults (:func:`move_defaults`).
"""

from __future__ import annotations

import math

import numpy as np

from station.errors import ConfigError

__all__ = ["simulate_program", "move_defaults", "UR_MOVEJ", "UR_MOVEL"]

#: URScript's defaults: movej v = 1.05 rad/s, a = 1.4 rad/s^2 (60 and 80 deg/s, deg/s^2); movel v = 0.25 m/s,
#: a = 1.2 m/s^2; UR controllers plan both with a trapezoidal velocity profile
UR_MOVEJ = {"speed": math.degrees(1.05), "acceleration": math.degrees(1.4), "profile": "trapezoid"}
UR_MOVEL = {"speed": 250.0, "acceleration": 1200.0, "profile": "trapezoid"}


def move_defaults(robot, move_type: str) -> dict:
    """Speed (deg/s or mm/s), acceleration (deg/s^2 or mm/s^2) and profile of a move the program leaves open:
    a UR controller's ``movej``/``movel`` defaults; another arm's rated joint speed and acceleration (its
    slowest joint's), or its rated tool speed reached in 0.5 s, with an S-curve."""
    if robot.controller == "ur":
        return dict(UR_MOVEJ if move_type == "joint" else UR_MOVEL)
    if move_type == "joint":
        return {"speed": math.degrees(float(np.min(robot.joint_speed_limits_rad_s))),
                "acceleration": math.degrees(float(np.min(robot.joint_accel_limits_rad_s2))), "profile": "scurve"}
    return {"speed": float(robot.max_tcp_speed_mm_s), "acceleration": float(robot.max_tcp_speed_mm_s) / 0.5,
            "profile": "scurve"}


def _resolve(program, robot) -> list[dict]:
    """Every move of the order with its speed, acceleration and profile settled and checked against the robot."""
    f = program.speed_pct / 100.0
    v_joint = math.degrees(float(np.min(robot.joint_speed_limits_rad_s)))
    a_joint = math.degrees(float(np.min(robot.joint_accel_limits_rad_s2)))
    out = []
    for i, m in enumerate(program.order):
        d = move_defaults(robot, m.type)
        speed = d["speed"] if m.speed is None else m.speed
        accel = d["acceleration"] if m.acceleration is None else m.acceleration
        key = f"order[{i}]"
        if m.type == "joint" and speed > v_joint + 1e-9:
            raise ConfigError(f"program {program.source}: `{key}.speed` {speed:g} deg/s is above the rated "
                              f"{v_joint:g} deg/s of {robot.name}'s slowest joint")
        if m.type == "joint" and accel > a_joint + 1e-9:
            raise ConfigError(f"program {program.source}: `{key}.acceleration` {accel:g} deg/s^2 is above the "
                              f"rated {a_joint:g} deg/s^2 of {robot.name}'s slowest joint")
        if m.type == "linear" and speed > robot.max_tcp_speed_mm_s + 1e-9:
            raise ConfigError(f"program {program.source}: `{key}.speed` {speed:g} mm/s is above {robot.name}'s "
                              f"rated tool speed {robot.max_tcp_speed_mm_s:g} mm/s")
        out.append({"to": m.to, "type": m.type, "speed": speed * f, "acceleration": accel * f * f,
                    "profile": d["profile"] if m.profile is None else m.profile})
    return out


def _pose_joints(program, robot):
    """``(names, base positions (P, 3) mm, joints (P, 6) rad, targets (P, 4, 4))`` of the program's poses."""
    from station.models import kinematics as kin

    names = program.pose_names
    lim = robot.joint_limits_rad
    q = np.zeros((len(names), 6))
    T = np.zeros((len(names), 4, 4))
    R_cart = None
    for k, name in enumerate(names):
        kind, vals = program.poses[name]
        if kind == "joints_deg":
            q[k] = np.radians(vals)
            bad = np.nonzero((q[k] < lim[:, 0]) | (q[k] > lim[:, 1]))[0]
            if bad.size:
                j = int(bad[0])
                raise ConfigError(f"program {program.source}: `poses.{name}.joints_deg[{j}]` {vals[j]:g} deg is "
                                  f"outside {robot.name}'s joint {j + 1} limits")
            T[k] = kin.fk(robot.dh_nominal, q[k])
            continue
        target = np.eye(4)
        target[:3, 3] = vals
        if R_cart is None:  # the orientation nominal IK finds for the first Cartesian pose from home
            first = kin.ik(robot.dh_nominal, np.asarray(vals, dtype=float), robot.home_q_rad, lim)
            if not first.all_success:
                raise ConfigError(f"program {program.source}: `poses.{name}.xyz_mm` {list(vals)} mm is out of "
                                  f"{robot.name}'s reach")
            R_cart = kin.fk(robot.dh_nominal, first.q_rad[0])[:3, :3]
        target[:3, :3] = R_cart
        seed = q[k - 1] if k else robot.home_q_rad
        sol = kin.ik(robot.dh_nominal, target, seed, lim)
        if not sol.all_success:
            raise ConfigError(f"program {program.source}: `poses.{name}.xyz_mm` {list(vals)} mm cannot be reached "
                              f"by {robot.name} with the tool orientation of the first Cartesian pose")
        q[k] = sol.q_rad[0]
        T[k] = target
    return names, T[:, :3, 3].copy(), q, T


def joint_fractions(q_from, q_to, robot, speed_deg_s: float, accel_deg_s2: float) -> tuple[float, float]:
    """Fractions of the rated limits (:meth:`fakes.sim.arm.SimArm.move_joint`) that move the leading joint
    (the one travelling farthest) at ``speed_deg_s`` and ``accel_deg_s2``: all joints share one profile of
    the path parameter, whose speed is then the leading joint's over its travel."""
    dq = np.abs(np.asarray(q_to, dtype=float) - np.asarray(q_from, dtype=float))
    moving = dq > 1e-12
    if not moving.any():
        return 1.0, 1.0
    lead = float(dq.max())
    rated_v = float(np.min(robot.joint_speed_limits_rad_s[moving] / dq[moving]))
    rated_a = float(np.min(robot.joint_accel_limits_rad_s2[moving] / dq[moving]))
    fv = math.radians(speed_deg_s) / lead / rated_v
    fa = math.radians(accel_deg_s2) / lead / rated_a
    return min(1.0, fv), min(1.0, fa)


def simulate_program(out_dir, program, *, seed: int = 0, robot: str | None = None, effects: str = "realistic",
                     beam_breaks=(), world_options: dict | None = None, chunk_s: float = 60.0,
                     motion_model=None) -> dict:
    """Replay ``program`` (a :class:`~station.readers.motion_program.MotionProgram`) on the simulated cell and
    write ``stream.csv``, ``poses.csv``, ``truth.json`` to ``out_dir`` (see the module docstring).

    ``robot``: the model when the program names none (a program's own ``robot`` wins only when ``robot`` is
    None; the two must agree otherwise). ``motion_model`` (a
    :class:`~station.models.motion_effects.MotionModel`, ``station diagnose motion --model-out``): the arm moves
    with its loop and its creep, mode and drift show in the readings (a dry run of a diagnosed arm); the
    program's profiles stand. Returns the summary of :func:`fakes.sim.iso_run.record_run`.
    """
    from fakes.sim.clock import ManualClock
    from fakes.sim.iso_run import record_run
    from fakes.sim.sim_bounds import check_samples, check_seed
    from fakes.sim.world import make_world
    from station.models.robots import get_robot

    check_seed(seed)
    if effects not in ("realistic", "none"):
        raise ConfigError(f"--effects must be 'realistic' or 'none', got {effects!r}")
    if program.robot is not None and robot is not None and program.robot != robot:
        raise ConfigError(f"program {program.source}: `robot` is {program.robot!r} but --robot says {robot!r}")
    name = program.robot or robot or "industrial-3100"
    try:
        spec = get_robot(name)
    except ConfigError as exc:
        raise ConfigError(f"program {program.source}: `robot`: {exc}") from None
    if program.payload_kg > spec.rated_payload_kg:
        raise ConfigError(f"program {program.source}: `payload_kg` {program.payload_kg:g} kg is above "
                          f"{spec.name}'s rated payload {spec.rated_payload_kg:g} kg")
    moves = _resolve(program, spec)
    names, positions, q_cmd, targets = _pose_joints(program, spec)
    check_samples(program.rate_hz * (program.wait_s + program.cycles * len(moves) * program.dwell_s),
                  f"the program's rate_hz {program.rate_hz:g} Hz over its wait_s and {program.cycles} cycles of "
                  f"{len(moves)} dwells of {program.dwell_s:g} s")
    world = make_world(robot=spec, seed=int(seed), clock=ManualClock(),
                       effects="realistic" if effects == "realistic" else None,
                       tracker_rate_hz=program.rate_hz, payload_kg=program.payload_kg,
                       **{**(world_options or {}), "motion_model": motion_model})
    try:
        arm = world.arm
        last = {"q": q_cmd[names.index(program.start)]}

        def mover(m: dict):
            def go(i: int, _cycle: int):
                if m["type"] == "joint":
                    fv, fa = joint_fractions(last["q"], q_cmd[i], spec, m["speed"], m["acceleration"])
                    mv = arm.move_joint(q_cmd[i], speed_frac=fv, accel_frac=fa, profile=m["profile"])
                else:
                    mv = arm.move_linear(targets[i], speed_mm_s=m["speed"], accel_mm_s2=m["acceleration"],
                                         profile=m["profile"])
                last["q"] = q_cmd[i]
                return mv
            return go

        sequence = [(names.index(m["to"]), mover(m),
                     {"move": m["type"], "profile": m["profile"], "speed": m["speed"],
                      "acceleration": m["acceleration"]}) for m in moves]
        head = {"description": f"truth of a lab program replayed on the simulated cell ({program.source}); "
                               "mm, s, deg",
                "program": {"source": program.source, "speed_pct": program.speed_pct, "start": program.start,
                            "order": [m["to"] for m in moves], "wait_s": program.wait_s,
                            "payload_kg": program.payload_kg,
                            "units": "speed deg/s (joint) or mm/s (linear) after the speed override; acceleration "
                                     "deg/s^2 or mm/s^2"}}
        return record_run(out_dir, world, names=names, positions_base_mm=positions, q_cmd_rad=q_cmd,
                          start=names.index(program.start), sequence=sequence, cycles=program.cycles,
                          dwell_s=program.dwell_s, wait_s=program.wait_s, rate_hz=program.rate_hz,
                          beam_breaks=beam_breaks, chunk_s=chunk_s, truth_head=head)
    finally:
        world.close()
