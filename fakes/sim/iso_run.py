"""An offline ISO 9283 run on the simulated cell (``station simulate iso9283``).

The world (:func:`fakes.sim.world.make_world`, on a ``ManualClock`` so it runs
as fast as the machine computes) drives its arm through the cycles of seed
000 sec. 3.1.3: the arm waits at P1 while the tracker starts measuring, then
visits P2, P3, P4, P5, P1 in every cycle with fine stops and a dwell at each
pose, at rated speed (synchronised joint moves at 100 % of the rated joint
speeds, or straight lines at the rated TCP speed with ``--move linear``).
Commanded poses are seed 000 Table 2 (the cube fitted to the arm's reach for other arms, e.g.
``--robot ur5e``) with one tool orientation (the one the
nominal inverse kinematics finds for P1 from the home pose).

Files written to DIR:

* ``stream.csv``: ``t,x,y,z,status``: the tracker stream (device time s,
  mm in the tracker frame); ``status`` 0 = valid, 1 = beam broken (then
  x, y, z are ``nan``). Every sample the tracker produced is there.
* ``poses.csv``: ``name,x,y,z``: the commanded positions in the tracker
  frame.
* ``truth.json``: the true attained positions per stop (base and tracker
  frames), the tracker's base transform, the error effects, servo and
  scatter parameters, and the stop timing, for people and tests.
"""

from __future__ import annotations

import json
import re

import numpy as np

from fakes.sim.sim_bounds import check_int, check_real, check_samples, check_seed
from station.errors import ConfigError
from station.tracker_rates import TRACKER_RATE_RANGE_HZ

__all__ = ["simulate_iso9283", "record_run", "commanded_joints", "CYCLE_ORDER", "STATUS_VALID", "STATUS_BEAM_BROKEN"]

STATUS_VALID = 0
STATUS_BEAM_BROKEN = 1

#: visiting order of one cycle after the initial wait at P1 (seed 000 sec. 3.1.3)
CYCLE_ORDER = ("P2", "P3", "P4", "P5", "P1")


#: most cycles of one simulated run (ISO 9283 asks for 30; more is a soak test, not one file)
MAX_CYCLES = 100
#: longest dwell at a pose, s (ISO 9283 test dwells are seconds)
MAX_DWELL_S = 60.0
#: longest initial wait at P1, s
MAX_WAIT_S = 600.0


def _check(cycles, dwell_s, rate_hz, seed, wait_s, move, effects, beam_breaks=()) -> None:
    check_int(cycles, "--cycles", 1, MAX_CYCLES)
    check_real(dwell_s, "--dwell", 0.0, MAX_DWELL_S, " s")
    check_real(rate_hz, "--rate", *TRACKER_RATE_RANGE_HZ, " Hz")
    check_seed(seed)
    check_real(wait_s, "--wait", 0.0, MAX_WAIT_S, " s")
    # the dwells and the wait alone (the moves come on top; counted while the stream is written)
    check_samples(float(rate_hz) * (float(wait_s) + 5 * int(cycles) * float(dwell_s)),
                  f"--rate {float(rate_hz):g} Hz over --wait {float(wait_s):g} s and {int(cycles)} --cycles of 5 "
                  f"--dwell {float(dwell_s):g} s")
    for _start, end in beam_breaks:
        check_real(end, "--beam-break END", 0.0, 1e6, " s")  # far beyond any run these bounds allow
    if move not in ("joint", "linear"):
        raise ConfigError(f"--move must be 'joint' or 'linear', got {move!r}")
    if effects not in ("realistic", "none"):
        raise ConfigError(f"--effects must be 'realistic' or 'none', got {effects!r}")


def commanded_joints(robot, positions_mm: np.ndarray):
    """Nominal IK of the five poses with the orientation IK picks for P1."""
    from station.models import kinematics as kin

    first = kin.ik(robot.dh_nominal, positions_mm[0], robot.home_q_rad, robot.joint_limits_rad)
    if not first.all_success:
        raise ConfigError(f"robot {robot.name!r} cannot reach P1 {positions_mm[0].tolist()} mm of seed 000 Table 2")
    T1 = kin.fk(robot.dh_nominal, first.q_rad[0])
    targets = np.repeat(T1[None], len(positions_mm), axis=0)
    targets[:, :3, 3] = positions_mm
    sol = kin.ik(robot.dh_nominal, targets, first.q_rad[0], robot.joint_limits_rad)
    if not sol.all_success:
        bad = int(np.nonzero(~sol.success)[0][0])
        raise ConfigError(
            f"robot {robot.name!r} cannot reach P{bad + 1} {positions_mm[bad].tolist()} mm "
            f"of seed 000 Table 2 with the tool orientation of P1"
        )
    return targets, sol.q_rad


def true_figures(names, commanded_tracker_mm, stops) -> dict:
    """The figures a run of these true stops states, for a person to hold the analysis against: per pose
    AP and RP (seed eqs. (1), (2)) of the true attained positions in the tracker frame (no tracker noise),
    with the number of stops; the measured figures differ from these by the tracker's noise and the
    extraction's window, which the analysis's uncertainty states."""
    from station.analysis.iso9283.characteristics import position_accuracy, position_repeatability

    out = {}
    for name, cmd in zip(names, commanded_tracker_mm):
        pts = np.array([s["true_tracker_mm"] for s in stops if s["pose"] == name], dtype=float).reshape(-1, 3)
        if len(pts) == 0:
            continue
        fig = {"n_stops": int(len(pts)), "AP_mm": round(position_accuracy(pts, cmd).AP_mm, 6)}
        if len(pts) >= 2:
            fig["RP_mm"] = round(position_repeatability(pts).RP_mm, 6)
        out[name] = fig
    return out


def simulate_iso9283(
    out_dir,
    *,
    cycles: int = 3,
    dwell_s: float = 0.5,
    rate_hz: float = 1000.0,
    seed: int = 0,
    robot: str = "industrial-3100",
    wait_s: float = 4.0,
    move: str = "joint",
    effects: str = "realistic",
    beam_breaks=(),
    chunk_s: float = 60.0,
    world_options: dict | None = None,
    motion_model=None,
) -> dict:
    """Run the ISO 9283 cycles offline and write ``stream.csv``, ``poses.csv``, ``truth.json``.

    Parameters
    ----------
    out_dir : str or Path
    cycles : int
        Cycles of P2, P3, P4, P5, P1 after the initial wait at P1.
    dwell_s : float
        Dwell at each pose, s.
    rate_hz : float
        Tracker rate (10-3000 Hz).
    seed : int
        Seed of the world.
    robot : str
        Robot model. The poses are seed 000 Table 2 for the arm Table 1 was laid out for, and the same
        cube fitted to any other arm's reach (:func:`station.analysis.iso_poses.fit_cube_to_reach`: a UR5e
        gets a 360 mm cube in front of its home pose).
    wait_s : float
        Time at P1 with the tracker measuring before the first move.
    move : {"joint", "linear"}
        PTP joint moves at 100 % rated joint speed, or linear moves at the
        rated TCP speed.
    effects : {"realistic", "none"}
    beam_breaks : iterable of (float, float)
        Beam breaks, seconds after the recording starts.
    chunk_s : float
        The stream is measured and written in chunks of this simulated time.
    world_options : dict, optional
        Further :func:`fakes.sim.world.make_world` keywords (e.g. ``tracker_noise``).
    motion_model : station.models.motion_effects.MotionModel, optional
        A diagnosed arm's motion: its loop (every axis) and profile (trapezoid when its jerk time is
        short), and its creep, structural mode and the tracker's drift added along each move
        (:func:`station.models.motion_effects.approach_offsets_mm`).

    Returns
    -------
    dict
        Paths, sample counts and the stop list.
    """
    _check(cycles, dwell_s, rate_hz, seed, wait_s, move, effects, beam_breaks)
    from fakes.sim.clock import ManualClock
    from fakes.sim.world import make_world
    from station.analysis.iso9283.poses import cube_test_poses, fit_cube_to_reach
    from station.models.robots import get_robot
    from station.programs.builders import TOOL_DOWN

    spec = get_robot(robot)
    cube = fit_cube_to_reach(spec.dh_nominal, spec.joint_limits_rad, spec.home_q_rad, TOOL_DOWN)
    tp = cube_test_poses(cube.corners_mm, inset_mm=cube.inset_mm)
    names = list(tp.names)
    positions = np.array(tp.positions_mm, dtype=float)
    world = make_world(robot=robot, seed=seed, clock=ManualClock(),
                       effects="realistic" if effects == "realistic" else None, tracker_rate_hz=rate_hz,
                       **{**(world_options or {}), "motion_model": motion_model})
    try:
        targets, q_cmd = commanded_joints(world.robot, positions)
        arm = world.arm

        def go(i: int, _cycle: int):
            if move == "joint":
                return arm.move_joint(q_cmd[i], speed_frac=1.0)
            return arm.move_linear(targets[i], speed_mm_s=world.robot.max_tcp_speed_mm_s,
                                   accel_mm_s2=world.robot.max_tcp_speed_mm_s / 0.5)

        sequence = [(names.index(n), go, {}) for n in CYCLE_ORDER]
        return record_run(out_dir, world, names=names, positions_base_mm=positions, q_cmd_rad=q_cmd,
                          start=names.index("P1"), sequence=sequence, cycles=cycles, dwell_s=dwell_s, wait_s=wait_s,
                          rate_hz=rate_hz, beam_breaks=beam_breaks, chunk_s=chunk_s,
                          truth_head={"description": "truth of a simulated ISO 9283 run (seed 000 sec. 3.1.3); "
                                                     "mm, s, deg", "move": move})
    finally:
        world.close()


def record_run(out_dir, world, *, names, positions_base_mm, q_cmd_rad, start: int, sequence, cycles: int,
               dwell_s: float, wait_s: float, rate_hz: float, beam_breaks=(), chunk_s: float = 60.0,
               truth_head: dict | None = None) -> dict:
    """Drive the world's arm through ``cycles`` of ``sequence`` and write ``stream.csv``, ``poses.csv`` and
    ``truth.json`` to ``out_dir`` (the files of the module docstring).

    The arm goes to pose ``start`` (unrecorded), settles, then the recording
    starts: ``wait_s`` at ``start``, then every cycle runs ``sequence``, a list
    of ``(pose index, go(pose index, cycle) -> Move, info)``, each move
    followed by a dwell of ``dwell_s``; ``info`` (JSON-able) is put on the
    stop's truth entry. A world built with a motion model (a diagnosed arm's) shows its creep, mode and
    drift in the readings (:mod:`fakes.sim.motion_offsets`).
    """
    from station.readers.out_files import output_dir, output_file, write_output

    clock = world.clock
    arm = world.arm
    source = world.tracker_source()
    tracker = world.tracker
    positions = np.asarray(positions_base_mm, dtype=float)
    q_cmd = np.asarray(q_cmd_rad, dtype=float)
    out = output_dir(out_dir, "--out")
    cmd_trk = tracker.to_tracker_frame(positions)
    # approach the start pose from home (not recorded), settle, then the recording starts
    arm.move_joint(q_cmd[start], speed_frac=0.5)
    arm.dwell(1.0)
    arm.wait_idle()
    t_rec = float(clock.now())
    for a, b in beam_breaks:
        tracker.add_beam_break(t_rec + a, t_rec + b)

    stream_path = out / "stream.csv"
    n_samples = n_invalid = 0
    t_written = t_rec
    stops = []
    with output_file(stream_path, "--out", newline="\n") as fh:
        fh.write("t,x,y,z,status\n")

        def flush(t_upto: float) -> None:
            nonlocal n_samples, n_invalid, t_written
            while t_written < t_upto:
                t1 = min(t_upto, t_written + chunk_s)
                t = source.sample_times(t_written, t1)
                t_written = t1
                if t.size == 0:
                    continue
                check_samples(n_samples + t.size, f"the run of {cycles} --cycles at --rate {float(rate_hz):g} Hz "
                              f"(the moves included)")
                xyz, valid = source.measure(t)
                status = np.where(valid, STATUS_VALID, STATUS_BEAM_BROKEN)
                rows = np.column_stack([source.device_time(t), xyz, status])
                np.savetxt(fh, rows, fmt=["%.6f", "%.4f", "%.4f", "%.4f", "%d"], delimiter=",")
                n_samples += t.size
                n_invalid += int(np.count_nonzero(~valid))

        arm.dwell(float(wait_s))
        for c in range(1, cycles + 1):
            for i, go, info in sequence:
                m = go(i, c)
                arm.dwell(float(dwell_s))
                stops.append({"cycle": c, "pose": names[i], "t_start_s": m.t_start, "t_end_s": m.t_end,
                              "t_leave_s": m.t_end + float(dwell_s), **info})
            arm.wait_idle()
            if c == 1:  # the first cycle's moves are simulated, nothing sampled yet: the whole run's size
                cycle_s = float(clock.now()) - t_rec - float(wait_s)
                check_samples(float(rate_hz) * (float(wait_s) + cycles * cycle_s),
                              f"--rate {float(rate_hz):g} Hz over {cycles} --cycles of {cycle_s:.1f} s "
                              f"(moves and dwells) after --wait {float(wait_s):g} s")
            flush(float(clock.now()))

    # true attained positions: the settled pose late in each dwell; what a noise-free reading of the tracker
    # shows of them (its session's systematic error applied)
    t_att = np.array([s["t_end_s"] + 0.9 * float(dwell_s) for s in stops])
    p_base = arm.tool_position_mm(t_att)
    p_trk = tracker.to_tracker_frame(p_base)
    p_read = tracker.reading(p_trk)
    for s, pb, pt, pr, ta in zip(stops, p_base, p_trk, p_read, t_att):
        s["t_attained_s"] = float(ta)
        s["t_attained_device_s"] = float(source.device_time(ta))
        s["true_base_mm"] = pb.tolist()
        s["true_tracker_mm"] = pt.tolist()
        s["reading_tracker_mm"] = pr.tolist()

    # The commanded poses in the tracker frame come from the world's true
    # base transform here; a real station gets that transform from a
    # registration (measuring known points), with its own uncertainty.
    poses_path = out / "poses.csv"
    with output_file(poses_path, "--out", newline="\n") as fh:
        fh.write("name,x,y,z\n")
        for name, p in zip(names, cmd_trk):
            fh.write(f"{name},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n")

    truth = {
        **(truth_head or {}),
        "robot": world.robot.name,
        "seed": world.seed,
        "cycles": cycles,
        "dwell_s": float(dwell_s),
        "rate_hz": float(rate_hz),
        "t_record_start_s": t_rec,
        "base_T_tracker": world.base_T_tracker.tolist(),
        "frames_note": "poses.csv uses the true base_T_tracker; a real station estimates it by registration. "
                       "true_tracker_mm: where the tool was; reading_tracker_mm: what the tracker reads of it "
                       "without its reading noise (its session's systematic error, world.tracker.systematic)",
        "commanded": {
            name: {
                "base_mm": positions[i].tolist(),
                "tracker_mm": cmd_trk[i].tolist(),
                "q_deg": np.rad2deg(q_cmd[i]).tolist(),
            }
            for i, name in enumerate(names)
        },
        "stops": stops,
        "figures": true_figures(names, cmd_trk, stops),
        "world": world.describe(),
    }
    truth_path = out / "truth.json"
    text = json.dumps(truth, indent=1)
    # one line per list of numbers, so a person can read the file
    text = re.sub(r"\[\s+([-+0-9.eE,\s]+?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text)
    write_output(truth_path, text, "--out")
    return {
        "stream_csv": str(stream_path),
        "poses_csv": str(poses_path),
        "truth_json": str(truth_path),
        "n_samples": n_samples,
        "n_invalid": n_invalid,
        "n_stops": len(stops),
        "cycles": cycles,
        "rate_hz": float(rate_hz),
        "duration_s": n_samples / float(rate_hz),
        "stops": stops,
    }
