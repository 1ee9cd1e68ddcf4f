"""ISO 9283 acceptance procedure (seed 000), as a readable list of steps.

The tests of seed 000 Table 3 on one robot with one laser tracker:

1. ``check programs`` — test poses from the cube (seed 000 sec. 2.1-2.2), every
   program generated (ABB RAPID) and passed through the safety gate before
   anything connects;
2. ``mount reflector`` / ``clear the cell`` — operator prompts (``--yes``
   answers them from a script), asked once per run: a resume does not ask
   again what was confirmed (an armed run's own confirmation is asked in
   every session by the front door);
3. ``connect devices`` — tracker (emScon/GeoCOM) and controller (FTP+Modbus);
4. ``home`` — the robot goes to P1, a known pose (again after a resume);
5. ``register base frame`` — stationary tracker points at the inset cube
   corners, rigid best fit tracker <- base
   (:mod:`station.analysis.registration`);
6. ``pose cycle k`` (k = 1..n) — one P1-P2-P3-P4-P5-P1 cycle at rated speed
   with 0.5 s fine-stop dwells while the tracker streams (sec. 3.1.3): AP,
   RP (eq. (1)-(2)), POS/PST (5)-(6), AD/RD (8)-(9) between P2 and P4,
   MPT (10);
7. ``vAP cycle k`` — P1, P2, P4 approached along x, y and z (sec. 3.3, eq. (7));
   the tracker streams continuously from the first cycle to ``stop stream``,
   each step committing what arrived while it ran (with a 6-DoF tracker,
   ``devices.tracker.six_dof``, a T-Mac on the tool in the emScon 6D
   continuous time mode: every sample carries the tool's orientation too);
8. ``analyse`` — attained-pose extraction and every characteristic, with
   verdicts against the configured limits (with a 6-DoF tracker the
   orientation accuracy and repeatability AP_a,b,c and RP_a,b,c at each
   pose too, :mod:`station.analysis.iso9283.orientation`);
9. ``report`` — one HTML file with the plots of Figs. 3-8, and the registered
   frame beside it (``<run>.frame.json``, the form ``analyze iso9283 --frame`` reads).

Samples go to the run store in committed batches while the robot moves, so
a run killed at any moment keeps every acknowledged sample and resumes at
the cycle it was in. The interrupted cycle is redone whole (its partial
samples stay in the store under their attempt, outside the analysis), and
entered as an uninterrupted run enters it: the program of the step before
runs again, unmeasured, first (:func:`predecessor`). A resume with only the
analysis left opens no device.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from procedures.plan_params import plan_from_params, plan_params
from station import characteristics as table
from station.analysis.iso9283.characteristics import ISO_CYCLES, analyze_iso9283, conformance_text
from station.analysis.iso9283.orientation import abc_in_base, abc_of_matrices
from station.analysis.iso9283.poses import cube_test_poses, fit_cube_to_reach
from station.analysis.registration import Registration, fit_rigid, register_by_axes
from station.errors import ConfigError, DeviceError, InsufficientDataError, StationError
from station.models.robots import RobotSpec, get_robot
from station.programs.builders import TOOL_DOWN, iso_pose_program, rated_tcp_accel_mm_s2, vap_program
from station.programs.program import CartesianTarget, Dwell, JointTarget, Move, Program, quat_from_matrix
from station.programs.rapid import render_rapid
from station.runner import Procedure, Step, StepContext
from station.safety import SafetyGate, SafetyLimits
from station.verdict import Outcome
from procedures.decision import Checks, decide, record_measurements
from procedures.cell import CellSession, connect_cell, record_robot_readings, robot_subject, prompt_step, stop_cell
from procedures.preflight import report_dir_problems, tracker_rate_problems
from procedures.registry import ProcedureSpec

#: seed 000 Table 1, corners C1..C8 (mm, robot base frame)
SEED_CUBE_MM = (
    (600, 2300, 2000), (600, 1100, 2000), (-600, 1100, 2000), (-600, 2300, 2000),
    (600, 2300, 800), (600, 1100, 800), (-600, 1100, 800), (-600, 2300, 800),
)
#: the poses approached from three directions in seed 000 Fig. 7 / Table 3
VAP_POSES = ("P1", "P2", "P4")
STREAM = "tracker"


@dataclass(frozen=True)
class IsoPlan:
    """Everything the procedure needs to know before it starts (JSON-able via :meth:`params`)."""

    robot: RobotSpec
    workspace_min_mm: tuple[float, float, float]
    workspace_max_mm: tuple[float, float, float]
    max_tcp_speed_mm_s: float
    poses_mm: dict[str, tuple[float, float, float]]
    registration_mm: dict[str, tuple[float, float, float]]
    cycles: int = 30
    vap_cycles: int = 10
    dwell_s: float = 0.5
    speed_frac: float = 1.0
    vap_offset_mm: float = 100.0
    tracker_rate_hz: float = 100.0
    limits: dict[str, float] = field(default_factory=dict)
    band_mm: float | None = None
    payload_kg: float = 0.0
    report_dir: str = "reports"
    max_speed_frac: float = 1.0
    max_accel_frac: float = 1.0
    registration: str = "axes"
    axis_sweep_deg: tuple[float, float] = (25.0, 30.0)
    axis_sweep_points: int = 13
    #: "simple" or "guarded" (ISO 14253-1); the budget's keyword arguments (None: no uncertainty stated)
    decision_rule: str = "simple"
    uncertainty: dict | None = None
    #: the tracker measures a 6-DoF target on the tool: orientation at every stop (devices.tracker.six_dof)
    orientation: bool = False
    #: sd of each 6-DoF angle reading, deg (the instrument term of the orientation figures' uncertainty)
    angle_sd_deg: float = 0.0
    #: the mounting the robot stands on (robots.<r>.mounting): ``{"name", "frame_file", "R", "t_mm"}``, the frame
    #: p_tracker = R p_mounting + t_mm (None: this run's registered frame is the mounting's); None: not recorded
    mounting: dict | None = None

    def gate(self) -> SafetyGate:
        return SafetyGate(
            self.robot,
            SafetyLimits(workspace_min_mm=self.workspace_min_mm, workspace_max_mm=self.workspace_max_mm,
                         max_tcp_speed_mm_s=self.max_tcp_speed_mm_s, max_speed_frac=self.max_speed_frac,
                         max_accel_frac=self.max_accel_frac),
        )

    def params(self) -> dict:
        return plan_params(self)

    @classmethod
    def from_params(cls, p: Mapping) -> "IsoPlan":
        return plan_from_params(cls, p)


def plan_from_config(cfg, robot_name: str = "r1", **overrides) -> IsoPlan:
    """Build the plan from a validated :class:`~station.config.StationConfig`."""
    if robot_name not in cfg.robots:
        raise ConfigError(f"robots.{robot_name}: no such robot (have {', '.join(sorted(cfg.robots))})")
    rc = cfg.robots[robot_name]
    iso = cfg.iso9283
    robot = get_robot(rc.model)
    if iso.cube_corners_mm:
        return _plan_on_cube(cfg, robot_name, np.asarray(iso.cube_corners_mm, dtype=float), iso.inset_mm,
                             iso.vap_offset_mm, overrides)
    # seed 000 Table 1 -> Table 2 placed in this arm's reach and the configured workspace box (scale 1 for the
    # Table 1 arm); the inset and the vAP approach scale alike unless the config gives them. The fit checks
    # the commanded points; the gate checks the paths between them (a straight approach may cross a
    # configuration change): a cube it refuses is laid out again a shrink smaller
    given = iso.model_fields_set
    for k in range(_LAYOUT_TRIES):
        cube = fit_cube_to_reach(robot.dh_nominal, robot.joint_limits_rad, robot.home_q_rad, TOOL_DOWN,
                                 inset_mm=iso.inset_mm, approach_mm=iso.vap_offset_mm,
                                 box_min_mm=rc.workspace.min_mm, box_max_mm=rc.workspace.max_mm, first_shrinks=k)
        plan = _plan_on_cube(cfg, robot_name, cube.corners_mm,
                             iso.inset_mm if "inset_mm" in given else cube.inset_mm,
                             iso.vap_offset_mm if "vap_offset_mm" in given else cube.approach_mm, overrides)
        try:
            gate = plan.gate()
            for kind in ("pose cycle", "vAP cycle"):
                gate.check_program(cycle_program(plan, kind, 1).program, q_start=None)
        except StationError:
            if k == _LAYOUT_TRIES - 1:
                return plan  # the gate says why at the procedure's check of its programs
            continue
        return plan


#: how many times :func:`plan_from_config` lays the fitted cube out a shrink smaller when the gate refuses a path
_LAYOUT_TRIES = 6


def _plan_on_cube(cfg, robot_name: str, corners, inset_mm: float, vap_offset_mm: float, overrides) -> IsoPlan:
    rc = cfg.robots[robot_name]
    iso = cfg.iso9283
    robot = get_robot(rc.model)
    tp = cube_test_poses(corners, inset_mm=inset_mm)
    poses = {n: tuple(float(v) for v in p) for n, p in zip(tp.names, tp.positions_mm)}
    centre = corners.mean(axis=0)
    inset = corners - np.sign(corners - centre) * inset_mm
    registration = {f"R{k + 1}": tuple(float(v) for v in c) for k, c in enumerate(inset)}
    limits = rc.limits.by_characteristic()
    kw = dict(
        robot=robot, workspace_min_mm=tuple(rc.workspace.min_mm),
        workspace_max_mm=tuple(rc.workspace.max_mm), max_tcp_speed_mm_s=rc.workspace.max_tcp_speed_mm_s,
        poses_mm=poses, registration_mm=registration, cycles=iso.cycles, vap_cycles=iso.vap_cycles,
        dwell_s=iso.dwell_s, speed_frac=min(iso.speed_percent, rc.workspace.max_speed_percent) / 100.0,
        vap_offset_mm=vap_offset_mm, tracker_rate_hz=iso.tracker_rate_hz, limits=limits,
        band_mm=rc.limits.pos_band_mm or rc.limits.rp_limit_mm, payload_kg=rc.payload_kg,
        report_dir=cfg.station.report_dir,
        max_speed_frac=rc.workspace.max_speed_percent / 100.0,
        max_accel_frac=rc.workspace.max_accel_percent / 100.0,
        registration=iso.registration,
        axis_sweep_deg=tuple(iso.axis_sweep_deg),
        axis_sweep_points=iso.axis_sweep_points,
    )
    if cfg.uncertainty is not None:
        kw.update(decision_rule=cfg.uncertainty.decision_rule, uncertainty=cfg.uncertainty.budget_kwargs())
    if rc.mounting is not None:
        kw.update(mounting=mounting_of(rc.mounting))
    tracker = cfg.devices.get(device_roles(cfg, robot_name)["tracker"])
    if tracker is not None and tracker.six_dof:
        kw.update(orientation=True, angle_sd_deg=tracker.angle_sd_deg)
    kw.update(overrides)
    return IsoPlan(**kw)


def mounting_of(mc) -> dict:
    """A plan's record of the robot's mounting (a :class:`~station.config.MountingConfig`): its name and the frame
    its frame file gives (None: the run's own registered frame will be the mounting's)."""
    if mc.frame is None:
        return {"name": mc.name, "frame_file": None, "R": None, "t_mm": None}
    from station.readers.registration_files import read_frame_json

    R, t, _ = read_frame_json(mc.frame)
    return {"name": mc.name, "frame_file": mc.frame, "R": R.tolist(), "t_mm": t.tolist()}


def mounting_frame(plan: IsoPlan, reg: Registration) -> dict | None:
    """What the run stores of its mounting (``register base frame``'s ``mounting``): the name, the frame
    (``p_tracker = R p_mounting + t_mm``: the plan's, or the run's own registered frame when the plan gives
    none), where it came from, and how far the run's registered base lies from it at the test poses, mm."""
    from station.analysis.iso9283.exchangeability import base_offset_mm

    m = plan.mounting
    if m is None:
        return None
    if m.get("R") is None:
        R, t, source = reg.R, reg.t_mm, "this run's registered frame"
    else:
        R, t, source = np.asarray(m["R"], dtype=float), np.asarray(m["t_mm"], dtype=float), f"frame file {m['frame_file']}"
    offset = base_offset_mm(R, t, reg.R, reg.t_mm, list(plan.poses_mm.values()))
    return {"name": m["name"], "R": np.asarray(R).tolist(), "t_mm": np.asarray(t).tolist(), "from": source,
            "base_offset_mm": offset}


# --------------------------------------------------------------------------
# programs
# --------------------------------------------------------------------------


def _quat():
    return quat_from_matrix(TOOL_DOWN)


def _point_program(plan: IsoPlan, name: str, xyz, *, dwell_s: float, speed_frac: float = 0.2) -> Program:
    target = CartesianTarget(name, tuple(xyz), _quat(), label=f"{name}")
    return Program(
        name=f"ST_{name}", robot_name=plan.robot.name, rated_tcp_speed_mm_s=float(plan.robot.max_tcp_speed_mm_s),
        statements=(Move(target, "joint", speed_frac), Dwell(dwell_s)), accel_frac=0.5,
        title=f"station: go to {name}", rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(plan.robot),
    )


def axis_sweeps(plan: IsoPlan) -> tuple[tuple[int, np.ndarray], ...]:
    """Joint sweeps of the axis registration about the P1 configuration: (joint index, angles deg)."""
    a1, a2 = plan.axis_sweep_deg
    n = plan.axis_sweep_points
    return ((0, np.linspace(-a1, a1, n)), (1, np.linspace(-a2, a2, n)))


#: every registration point is approached with each joint moving in + (backlash on one side), deg
UNIDIRECTIONAL_PRE_DEG = 2.0


def _joint_program(plan: IsoPlan, name: str, q_deg, *, dwell_s: float, pre_deg: float | None = None) -> Program:
    """Joint move to ``q_deg`` and a dwell; with ``pre_deg`` first to ``q_deg - pre_deg`` on every joint,
    so each joint's last motion before the measurement is positive whatever came before."""
    target = JointTarget(name, tuple(float(v) for v in q_deg), label=name)
    moves: tuple = (Move(target, "joint", 0.2),)
    if pre_deg:
        pre = JointTarget(f"{name}_pre", tuple(float(v) - pre_deg for v in q_deg), label=f"{name} pre-position")
        moves = (Move(pre, "joint", 0.2),) + moves
    return Program(
        name=f"ST_{name}", robot_name=plan.robot.name, rated_tcp_speed_mm_s=float(plan.robot.max_tcp_speed_mm_s),
        statements=moves + (Dwell(dwell_s),), accel_frac=0.5,
        title=f"station: joint pose {name}", rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(plan.robot),
    )


def axis_sweep_q_deg(plan: IsoPlan) -> dict[str, np.ndarray]:
    """Joint configurations of the axis registration: joint 1, then joint 2, turned about P1's configuration."""
    p1 = CartesianTarget("P1", tuple(plan.poses_mm["P1"]), _quat())
    q0 = np.degrees(plan.gate().check_cartesian_target(p1.pose, "P1 (registration)"))
    out = {}
    for j, angles in axis_sweeps(plan):
        for k, a in enumerate(angles):
            q = q0.copy()
            q[j] += a
            out[f"J{j + 1}_{k + 1}"] = q
    return out


def programs(plan: IsoPlan) -> dict[str, object]:
    """Every program of the procedure, rendered (RAPID)."""
    out = {"home": render_rapid(_point_program(plan, "P1", plan.poses_mm["P1"], dwell_s=plan.dwell_s))}
    if plan.registration == "axes":
        # each sweep starts from a pre-position below its first point and turns one way only
        for name, q in axis_sweep_q_deg(plan).items():
            pre = UNIDIRECTIONAL_PRE_DEG if name.endswith("_1") else None
            out[f"register {name}"] = render_rapid(_joint_program(plan, name, q, dwell_s=0.2, pre_deg=pre))
    else:
        for name, xyz in plan.registration_mm.items():
            out[f"register {name}"] = render_rapid(_point_program(plan, name, xyz, dwell_s=0.2))
    out["pose cycle"] = cycle_program(plan, "pose cycle", 1)
    out["vAP cycle"] = cycle_program(plan, "vAP cycle", 1)
    return out


def cycle_program(plan: IsoPlan, kind: str, k: int):
    """Cycle ``k`` of ``kind`` (``"pose cycle"``, ``"vAP cycle"``), rendered (RAPID) and named for its cycle
    (``ISO_POSE_3``): the controller's program list tells the cycles apart, and so do the fakes' stops."""
    if kind == "pose cycle":
        prog = iso_pose_program(plan.robot, plan.poses_mm, cycles=1, dwell_s=plan.dwell_s, speed_frac=plan.speed_frac,
                                name=f"ISO_POSE_{k}")
    else:
        vap = {n: plan.poses_mm[n] for n in VAP_POSES}
        prog = vap_program(plan.robot, vap, cycles=1, dwell_s=plan.dwell_s, speed_frac=plan.speed_frac,
                           approach_mm=plan.vap_offset_mm, name=f"ISO_VAP_{k}")
    return render_rapid(prog)


def predecessor(plan: IsoPlan, kind: str, k: int) -> tuple[str, object]:
    """The step that runs just before cycle ``k`` of ``kind`` in an uninterrupted run, and its last program:
    the one that leaves the arm at the cycle's start, arriving the way the cycle expects it."""
    if kind == "vAP cycle" and k > 1:
        return f"vAP cycle {k - 1}", cycle_program(plan, kind, k - 1)
    if kind == "vAP cycle":
        return f"pose cycle {plan.cycles}", cycle_program(plan, "pose cycle", plan.cycles)
    if k > 1:
        return f"pose cycle {k - 1}", cycle_program(plan, kind, k - 1)
    last = [name for name in programs(plan) if name.startswith("register ")][-1]
    return "register base frame", programs(plan)[last]


# --------------------------------------------------------------------------
# steps
# --------------------------------------------------------------------------


@dataclass
class IsoSession(CellSession):
    """What the ISO 9283 steps share within one session (the cell's, and the analysis inputs)."""

    #: ``{"pose": (t, xyz), "vap": (t, xyz)}`` in the base frame, read from the store once per session
    streams: dict | None = None
    #: ``(main, vap)`` analysis results
    analysis: tuple | None = None
    #: the last step that moved the arm in this session (a cycle whose predecessor it is not is entered again)
    moved_by: str | None = None


def _plan(ctx: StepContext) -> IsoPlan:
    if ctx.session.plan is None:
        ctx.session.plan = IsoPlan.from_params(ctx.params)
    return ctx.session.plan


def step_check_programs(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    gate = plan.gate()
    checked = {}
    for name, rendered in programs(plan).items():
        report = gate.check_program(rendered.program, q_start=None)
        checked[name] = {"file": rendered.main_file, "moves": int(report.q_rad.shape[0]),
                         "peak_tcp_speed_mm_s": float(report.peak_tcp_speed_mm_s)}
    ctx.session.gate = gate
    return {"programs": checked, "poses_mm": {k: list(v) for k, v in plan.poses_mm.items()}}


_prompt = prompt_step


def step_connect(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    return connect_cell(ctx.session, ctx.session.gate or plan.gate())


def _move_targets(rendered) -> list[str]:
    """Target name of every move in execution order (loop bodies once): what the progress line shows."""
    from station.programs.program import Loop, Move

    names: list[str] = []
    for st in rendered.program.statements:
        body = st.body if isinstance(st, Loop) else (st,)
        names += [ins.target.name for ins in body if isinstance(ins, Move)]
    return names


#: the stream's columns of a 6-DoF target's orientation (unit quaternion, scalar first, tracker frame)
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")


def _record_batch(ctx: StepContext, batch) -> None:
    """Commit one batch of tracker samples (device time, tracker frame) to the run's stream; with a 6-DoF
    target (the plan's ``orientation``) each sample's quaternion too."""
    cols = {"t": batch.t_s, "x": batch.xyz_mm[:, 0], "y": batch.xyz_mm[:, 1], "z": batch.xyz_mm[:, 2],
            "status": batch.status}
    if _plan(ctx).orientation:
        if batch.quat_wxyz is None:
            raise DeviceError("the tracker streamed samples without an orientation in its 6-DoF mode "
                              "(devices.tracker.six_dof): is the T-Mac on the tool and the 6D mode licensed?")
        cols.update(zip(QUAT_COLUMNS, batch.quat_wxyz.T))
    ctx.record(STREAM, cols)


def _run_program(ctx: StepContext, rendered, *, timeout_s: float, stream: bool) -> dict:
    """Run one program; with ``stream`` the tracker streams and samples are committed as they come."""
    plan = _plan(ctx)
    tracker, controller = ctx.session.tracker, ctx.session.controller
    events: list[str] = []
    robot_counts: dict = {}

    def drain(timeout: float = 0.0, robot: bool = True) -> None:
        batch = tracker.read_samples(timeout_s=timeout)
        for ev in batch.events:
            events.append(f"{ev.kind.value}@{ev.t_device_s}")
        if len(batch):
            _record_batch(ctx, batch)
        if robot:
            record_robot_readings(ctx, controller, robot_counts)

    last = [time.monotonic()]

    targets = _move_targets(rendered)

    def on_status(st) -> None:
        ctx.checkpoint()
        k = int(st.moves_done)
        ctx.progress(f"-> {targets[k]}" if k < len(targets) else f"line {st.line}")
        if stream and time.monotonic() - last[0] > 0.2:
            drain()
            last[0] = time.monotonic()

    if stream and not tracker.streaming:
        # one continuous stream across the cycles (seed 000: the tracker measures the whole run);
        # a new session (resume) starts it again
        if plan.orientation:
            tracker.start_stream(plan.tracker_rate_hz, six_dof=True)
        else:
            tracker.start_stream(plan.tracker_rate_hz)
    ok = False
    try:
        status = controller.run(rendered, timeout_s=timeout_s, on_status=on_status)
        ok = True
        if stream:
            # every sample the tracker sent before the program ended (on the lockstep fakes: up to its
            # last full packet) is readable after a round trip: the step's samples do not depend on
            # how fast this host is
            tracker.sync()
    finally:
        if stream:
            # commit everything delivered so far (an interrupted attempt keeps what it took), the arm's own
            # readings too, unless the robot failed: its link may be what broke
            drain(0.0, robot=ok)
    if not stream:
        record_robot_readings(ctx, controller, robot_counts)
    out = {"cycles": int(status.cycle_count), "moves": int(status.moves_done), "events": events}
    if getattr(status, "paused", False):  # paused on the controller (a UR's pendant) and played on
        out["paused"] = True
    if robot_counts:  # the arm's own readings (a robot that streams them: the UR)
        out["robot_samples"] = robot_counts
    record = tracker.stream_record() if stream else None
    if record is not None:
        out.update(_record_counts(record))
    return out


def _record_counts(record) -> dict:
    """Stream counters so far (cumulative over the session's stream)."""
    return {"received": record.received, "lost": record.lost, "rejected": record.rejected,
            "not_measured": record.not_measured, "reconnects": record.reconnects,
            "gaps": [[g.t_before_s, g.t_after_s, g.missing, g.cause] for g in record.gaps]}


def step_stop_stream(ctx: StepContext) -> dict:
    """End of the measured block: stop the stream, commit the last samples, keep the counters."""
    tracker = ctx.session.tracker
    if not tracker.streaming:
        return {"streaming": False}
    record = tracker.stop_stream()
    batch = tracker.read_samples(timeout_s=0.0)
    if len(batch):
        _record_batch(ctx, batch)
    return {"streaming": True, **_record_counts(record)}


def _timeout(ctx: StepContext, sim_seconds: float) -> float:
    scale = ctx.session.time_scale or 1.0
    return 30.0 + sim_seconds / scale * 3.0


def step_home(ctx: StepContext) -> dict:
    ctx.session.moved_by = "home"
    return _run_program(ctx, programs(_plan(ctx))["home"], timeout_s=_timeout(ctx, 60), stream=False)


def step_register(ctx: StepContext) -> dict:
    """Tie the tracker to the robot base: joint-1/joint-2 circles (default) or a best fit."""
    plan = _plan(ctx)
    tracker = ctx.session.tracker
    progs = programs(plan)
    names = [k.split(" ", 1)[1] for k in progs if k.startswith("register ")]
    measured = []
    for name in names:
        ctx.checkpoint()
        _run_program(ctx, progs[f"register {name}"], timeout_s=_timeout(ctx, 60), stream=False)
        m = tracker.measure_stationary(duration_s=0.2)
        measured.append(np.asarray(m.xyz_mm, dtype=float))
        ctx.progress(f"point {name}")
    ctx.session.moved_by = ctx.step.name
    measured = np.array(measured)
    if plan.registration == "axes":
        q = axis_sweep_q_deg(plan)
        n1 = len(axis_sweeps(plan)[0][1])
        qr = np.radians(np.array([q[n] for n in names]))

        def fit(keep):
            k1, k2 = keep[:n1], keep[n1:]
            return register_by_axes(plan.robot.dh_nominal, qr[:n1][k1], measured[:n1][k1],
                                    qr[n1:][k2], measured[n1:][k2])
    else:
        base = np.array([plan.registration_mm[n] for n in names])

        def fit(keep):
            return fit_rigid(base[keep], measured[keep])
    n = len(names)
    reg = fit(np.ones(n, bool))
    refits = jackknife_refits(fit, n)
    u = registration_uncertainty(refits, np.array(list(plan.poses_mm.values())))
    rot = np.degrees(np.degrees(rotation_covariance(refits, reg)))
    return {"method": plan.registration, "R": reg.R.tolist(), "t_mm": reg.t_mm.tolist(), "rms_mm": reg.rms_mm,
            "residuals_mm": reg.residuals_mm.tolist(), "points": names, "points_tracker_mm": measured.tolist(),
            "uncertainty_at_poses_mm": dict(zip(plan.poses_mm, np.round(u, 4).tolist())),
            "rotation_cov_deg2": rot.tolist(), "mounting": mounting_frame(plan, reg)}


def jackknife_refits(fit, n: int) -> list[Registration]:
    """The frame refitted with each of the ``n`` points left out in turn (``fit(keep)``, keep a mask)."""
    out = []
    for k in range(n):
        keep = np.ones(n, bool)
        keep[k] = False
        out.append(fit(keep))
    return out


def registration_uncertainty(refits: list[Registration], poses_mm: np.ndarray) -> np.ndarray:
    """Jackknife standard error of where the registered frame puts each pose, mm (one per pose).

    Each point is left out in turn and the frame refitted (:func:`jackknife_refits`); the spread of the
    poses' tracker coordinates over the refits, scaled by sqrt(n - 1), is the
    frame's own uncertainty at the poses (from the robot's stop scatter and the
    tracker's noise in the registration points). It bounds how much of AP is
    the registration's.
    """
    n = len(refits)
    refs = np.array([r.to_tracker(poses_mm) for r in refits])  # (n, P, 3)
    dev = refs - refs.mean(axis=0)
    return np.sqrt((n - 1) / n * np.sum(dev**2, axis=(0, 2)))


def rotation_covariance(refits: list[Registration], reg: Registration) -> np.ndarray:
    """Jackknife covariance (3, 3), rad^2, of the frame's rotation about the base x, y, z axes.

    A refit ``R_k = R exp([delta_k])`` differs from the fit ``R`` by a small rotation ``delta_k`` of the base
    frame (``rotvec(R^T R_k)``); the covariance of the ``delta_k``, scaled by ``n - 1``, is the rotation's
    (what turns every measured orientation, :meth:`~station.analysis.uncertainty.Budget.registration_angle_sd_deg`).
    """
    from station.models.rotation import rotvec_of

    n = len(refits)
    d = np.array([rotvec_of(reg.R.T @ r.R) for r in refits]).reshape(n, 3)
    dev = d - d.mean(axis=0)
    return (n - 1) / n * dev.T @ dev


def _cycle_step(kind: str, k: int, sim_s_per_dwell: float):
    def run(ctx: StepContext) -> dict:
        plan = _plan(ctx)
        timeout_s = _timeout(ctx, sim_s_per_dwell * (plan.dwell_s + 2.0))
        before, program = predecessor(plan, kind, k)
        entered = None
        if ctx.session.moved_by != before:
            # a session that did not run the step before (a resume): its program runs again, unmeasured, so
            # the cycle starts where and as an uninterrupted run starts it (each joint's last motion, the stop)
            _run_program(ctx, program, timeout_s=timeout_s, stream=False)
            entered = f"from {before}"
        ctx.session.moved_by = ctx.step.name
        out = _run_program(ctx, cycle_program(plan, kind, k), timeout_s=timeout_s, stream=True)
        return {**out, "entered_again": entered}
    return run


def step_pose_cycle(k: int):
    return _cycle_step("pose cycle", k, 8.0)


def step_vap_cycle(k: int):
    return _cycle_step("vAP cycle", k, 12.0)


def registration_of(outputs: Mapping) -> Registration:
    out = outputs["register base frame"]
    return Registration(R=np.asarray(out["R"]), t_mm=np.asarray(out["t_mm"]),
                        residuals_mm=np.asarray(out["residuals_mm"]), rms_mm=float(out["rms_mm"]),
                        n=len(out["residuals_mm"]))


class BaseStream(NamedTuple):
    """The tracker's samples of some steps in the registered base frame, in time order: times (s), positions
    (mm), the tracker's status per sample and the tool's angles a, b, c (rad; None without a 6-DoF target)."""

    t: np.ndarray
    xyz: np.ndarray
    status: np.ndarray
    abc: np.ndarray | None


def _stream_in_base(ctx: StepContext, step_names: list[str]) -> BaseStream:
    s = ctx.samples(STREAM, steps=step_names)
    if not s:
        raise InsufficientDataError(f"no tracker samples recorded for {step_names[0]}..{step_names[-1]}")
    reg = registration_of(ctx.outputs)
    xyz = reg.to_base(np.column_stack([s["x"], s["y"], s["z"]]))
    order = np.argsort(s["t"], kind="stable")
    return BaseStream(s["t"][order], xyz[order], s["status"][order], _abc_in_base(s, reg, order))


def _abc_in_base(s: Mapping, reg: Registration, order) -> np.ndarray | None:
    """The tool's angles a, b, c (N, 3), rad, in the registered base frame, from a 6-DoF stream's quaternions
    (None: a position-only stream)."""
    if not all(c in s for c in QUAT_COLUMNS):
        return None
    quat = np.column_stack([s[c] for c in QUAT_COLUMNS])[order]
    return abc_in_base(quat, reg.R)


def analyse(plan: IsoPlan, pose_t, pose_xyz, vap_t=None, vap_xyz=None, reg=None, reg_u_at_poses=None, *,
            pose_abc_rad=None, vap_abc_rad=None, reg_rotation_cov_deg2=None):
    """Both analyses of the procedure's data (pure: arrays in, results out).

    ``pose_abc_rad`` (N, 3): the tool's angles a, b, c of the pose cycles' samples in the base frame (a 6-DoF
    tracker's): orientation AP and RP per pose against the programs' commanded orientation (tool down,
    :data:`~station.programs.builders.TOOL_DOWN`), their uncertainty with the plan's ``angle_sd_deg``;
    ``vap_abc_rad``: the same of the multi-directional cycles (orientation vAP_a, vAP_b, vAP_c per pose).

    With a stated budget (``plan.uncertainty``) every verdict carries its uncertainty and is decided by
    ``plan.decision_rule``; ``reg``: the registration the streams went through (its fit enters the budget);
    ``reg_u_at_poses``: ``{pose: jackknife standard error (3-D), mm}`` of the frame at the test poses, used
    instead of the fit's rms when given; ``reg_rotation_cov_deg2`` (3 x 3): the jackknife covariance of the
    frame's rotation about the base axes (orientation AP's frame term).
    """
    names = list(plan.poses_mm)
    commanded = np.array([plan.poses_mm[n] for n in names])
    # vAP is judged on the multi-directional cycles (below), not on the single-direction pose cycles
    several = {c.key for c in table.characteristics() if c.several_approaches}
    main_limits = {k: v for k, v in plan.limits.items() if k not in several}
    def oriented(abc_rad, n_poses):
        return {} if abc_rad is None else dict(
            orientation_rad=abc_rad, commanded_orientation_rad=np.repeat(abc_of_matrices(TOOL_DOWN), n_poses, axis=0))

    ori = oriented(pose_abc_rad, len(names))
    main = analyze_iso9283(pose_t, pose_xyz, commanded, names=names, limits=main_limits,
                           band_mm=plan.band_mm, mpt_repeats=min(3, plan.cycles), **ori)
    vap = None
    if vap_t is not None and len(vap_t):
        vnames = list(VAP_POSES)
        vcmd = np.array([plan.poses_mm[n] for n in vnames])
        # each vAP pose is approached three times in a row: that is the commanded order
        order = [n for n in vnames for _ in range(3)]
        vlim = {k: v for k, v in plan.limits.items() if k in several}
        vap = analyze_iso9283(vap_t, vap_xyz, vcmd, names=vnames, order=order, limits=vlim,
                              distance_pairs=None, band_mm=plan.band_mm, **oriented(vap_abc_rad, len(vnames)))
    if plan.uncertainty is not None:
        from station.analysis.iso9283.uncertainty import figure_uncertainties, apply_rule
        from station.analysis.uncertainty import Budget

        angle = {"angle_sd_deg": plan.angle_sd_deg} if pose_abc_rad is not None else {}
        budget = registered_budget(plan, Budget(**plan.uncertainty, rate_hz=plan.tracker_rate_hz, **angle), reg,
                                   reg_u_at_poses, reg_rotation_cov_deg2)
        main = apply_rule(main, figure_uncertainties(main, budget, pose_xyz), plan.decision_rule)
        if vap is not None:
            vap = apply_rule(vap, figure_uncertainties(vap, budget, vap_xyz), plan.decision_rule)
    return main, vap


def registered_budget(plan: IsoPlan, budget, reg, reg_u_at_poses=None, reg_rotation_cov_deg2=None):
    """``budget`` through the run's registration ``reg``: its fit, and its jackknife where the run stored one
    (the frame's standard uncertainty at the poses, ``{pose: 3-D sd, mm}``; the covariance of its rotation,
    deg^2), which replace what the fit's rms says."""
    budget = budget.with_registration(reg)
    if reg_u_at_poses:
        budget = replace(budget, registration_at_points=tuple(
            (tuple(plan.poses_mm[k]), float(v) / math.sqrt(3.0)) for k, v in reg_u_at_poses.items()
            if k in plan.poses_mm))
    if reg_rotation_cov_deg2 is not None and getattr(reg, "n", 0) >= 3:  # a jackknife of the fit's n points
        budget = replace(budget, registration_rotation_cov_deg2=tuple(
            tuple(float(x) for x in row) for row in reg_rotation_cov_deg2), registration_rotation_dof=float(reg.n - 1))
    return budget


def run_verdicts(main, vap) -> dict:
    """``{(characteristic, subject): LimitCheck}`` of the run: each from the analysis that states it."""
    vs = table.from_their_cycles(main.verdicts, vap.verdicts if vap is not None else ())
    return {(v.characteristic, v.subject): v for v in vs}


def characteristic_rows(main, vap) -> list[dict]:
    """One row per number (pose, name, value, unit, limit, passed) for the store and the report: every
    characteristic of the table the procedure states, every one a limit was configured for, and the
    orientation figures when the tracker measured the tool's orientation."""
    rows: list[dict] = []
    verdicts = run_verdicts(main, vap)
    for res in (main, vap):
        if res is None:
            continue

        oriented = table.has_orientation(res)

        def ours(c, res=res, oriented=oriented):
            return c.several_approaches is (res is vap) and (c.stated or c.key in res.limits
                                                             or (c.with_orientation and oriented))

        for c, subject, obj in table.figures(res, ours):
            v = verdicts.get((c.key, subject))
            rows.append({"pose": subject, "name": c.key, "value": c.value(obj), "unit": c.unit,
                         "limit": None if v is None else v.limit, "passed": None if v is None else v.passed})
    return rows


def measured_streams(ctx: StepContext, plan: IsoPlan) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{"pose": (t, xyz), "vap": (t, xyz), "pose_abc_rad": (N, 3) or None, "vap_abc_rad": ...}`` in the
    registered base frame, read once per session (``pose_abc_rad``, ``vap_abc_rad``: the tool's angles of a
    6-DoF stream's pose cycles, of its multi-directional cycles)."""
    streams = ctx.session.streams
    if streams is None:
        pose_steps, vap_steps = stream_steps(plan)
        pose, vap = _stream_in_base(ctx, pose_steps), _stream_in_base(ctx, vap_steps)
        streams = ctx.session.streams = {
            "pose": (pose.t, pose.xyz), "vap": (vap.t, vap.xyz), "pose_abc_rad": pose.abc, "vap_abc_rad": vap.abc}
    return streams


def _analyse_streams(ctx: StepContext, plan: IsoPlan):
    """:func:`analyse` of the session's measured streams in the run's registered frame."""
    streams = measured_streams(ctx, plan)
    out = ctx.outputs["register base frame"]
    return analyse(plan, *streams["pose"], *streams["vap"], reg=registration_of(ctx.outputs),
                   reg_u_at_poses=out.get("uncertainty_at_poses_mm"), reg_rotation_cov_deg2=out.get("rotation_cov_deg2"),
                   pose_abc_rad=streams["pose_abc_rad"], vap_abc_rad=streams["vap_abc_rad"])


def reanalyse(store, run_id: str) -> tuple[dict, list[dict]]:
    """The analysis of a finished stored run, from its plan, its registration output and the tracker samples
    of its finished steps (the same steps and frame as :func:`measured_streams`); DataError when it has none."""
    from station.errors import DataError

    rec = store.run(run_id)
    plan = IsoPlan.from_params(rec.params)
    done = store.done_steps(run_id)
    outputs = {s.name: s.output for s in done.values()}
    index = {s.name: i for i, s in done.items()}
    if "register base frame" not in outputs:
        raise DataError(f"run {run_id}: no finished registration step: nothing to re-analyse")
    reg = registration_of(outputs)

    def stream(names):
        s = store.samples(run_id, STREAM, steps=[index[n] for n in names if n in index])
        if not s:
            return np.empty(0), np.empty((0, 3)), None
        xyz = reg.to_base(np.column_stack([s["x"], s["y"], s["z"]]))
        order = np.argsort(s["t"], kind="stable")
        return s["t"][order], xyz[order], _abc_in_base(s, reg, order)

    pose_steps, vap_steps = stream_steps(plan)
    pose, vap = stream(pose_steps), stream(vap_steps)
    if not len(pose[0]):
        raise DataError(f"run {run_id}: no tracker samples of finished pose cycles")
    reg_out = outputs["register base frame"]
    main, vres = analyse(plan, *pose[:2], *vap[:2], reg=reg, reg_u_at_poses=reg_out.get("uncertainty_at_poses_mm"),
                         reg_rotation_cov_deg2=reg_out.get("rotation_cov_deg2"), pose_abc_rad=pose[2],
                         vap_abc_rad=vap[2])
    return {"pose": main.to_dict(), "vap": vres.to_dict() if vres is not None else None}, characteristic_rows(main, vres)


def stream_steps(plan: IsoPlan) -> tuple[list[str], list[str]]:
    """The steps whose samples are the pose stream and the vAP stream (its tail arrives in "stop stream")."""
    return ([f"pose cycle {k}" for k in range(1, plan.cycles + 1)],
            [f"vAP cycle {k}" for k in range(1, plan.vap_cycles + 1)] + ["stop stream"])


def step_analyse(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    main, vap = _analyse_streams(ctx, plan)
    rows = characteristic_rows(main, vap)
    ctx.store.put_characteristics(ctx.run_id, rows)
    result = {"pose": main.to_dict(), "vap": vap.to_dict() if vap is not None else None}
    ctx.store.put_result(ctx.run_id, "iso9283", result)
    ctx.session.analysis = (main, vap)
    # no verdict here: the run's one verdict is decided from the stored rows (procedures.decision.decide)
    out = {"partial": bool(main.partial),
           "warnings": list(main.warnings) + (list(vap.warnings) if vap is not None else []),
           "n_rows": len(rows)}
    if plan.uncertainty is not None:
        out.update(decision_rule=plan.decision_rule)
    return out


def step_report(ctx: StepContext) -> dict:
    from procedures.iso9283_report import build_report
    from station.readers.registration_files import write_frame_json
    from station.report import write_report

    plan = _plan(ctx)
    if ctx.session.analysis is None:  # a resumed run whose analysis ran in an earlier session
        ctx.session.analysis = _analyse_streams(ctx, plan)
    main, vap = ctx.session.analysis
    marginal = [f"{m['pose']} {m['name']} = {m['value']:.4g} {m['unit']}: marginal (passes, within its "
                f"marginal band of a limit)" for m in record_measurements(ctx.store, ctx.run_id) if m["marginal"]]
    rows = ctx.store.characteristics(ctx.run_id)
    run = ctx.store.run(ctx.run_id)
    report = build_report(ctx, plan, run, rows, main, vap, streams=measured_streams(ctx, plan),
                          reg=registration_of(ctx.outputs), vap_poses=VAP_POSES)
    decision = decide(SPEC, ctx.store, ctx.run_id, finished=True)
    report.outcome, report.reasons = decision.outcome, list(decision.reasons)
    report.notes += [sentence for _, _, sentence in decision.marginal] + marginal
    path = write_report(report, Path(plan.report_dir) / f"{ctx.run_id}.html")
    # the registered frame beside the report, in the form `station analyze iso9283 --frame` reads
    frame = write_frame_json(path.with_name(f"{ctx.run_id}.frame.json"), ctx.outputs["register base frame"])
    return {"report": str(path.resolve()), "verdict": report.verdict, "frame": str(frame.resolve())}


def safe_state(session: IsoSession) -> None:
    """Stop the program and the stream; keep the connections for a resume to reopen."""
    stop_cell(session)


def build_procedure(plan: IsoPlan) -> Procedure:
    """The ISO 9283 procedure as named steps."""
    steps = [
        Step("check programs", step_check_programs, every_session=True),
        Step("mount reflector", _prompt("Mount the tracker reflector on the tool flange (SMR in its nest)")),
        Step("clear the cell", _prompt("Clear the robot cell and close the safety fence")),
        Step("connect devices", step_connect, every_session=True),
        Step("home", step_home, every_session=True),
        Step("register base frame", step_register),
    ]
    steps += [Step(f"pose cycle {k}", step_pose_cycle(k), label=f"{k}/{plan.cycles}") for k in range(1, plan.cycles + 1)]
    steps += [Step(f"vAP cycle {k}", step_vap_cycle(k), label=f"{k}/{plan.vap_cycles}")
              for k in range(1, plan.vap_cycles + 1)]
    steps += [Step("stop stream", step_stop_stream), Step("analyse", step_analyse, offline=True),
              Step("report", step_report, offline=True)]
    return Procedure("iso9283", steps, safe_state=safe_state)


# --------------------------------------------------------------------------
# the procedure's entry in the registry
# --------------------------------------------------------------------------


def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    """The stored plan of a new run."""
    return plan_from_config(cfg, robot, **{"report_dir": report_dir, **overrides}).params()


subject = robot_subject


def device_roles(cfg, robot: str) -> dict[str, str]:
    subject(cfg, robot)
    return {"tracker": "tracker", "controller": cfg.robots[robot].controller}


def _fmt(r) -> str:
    if r is None or r["value"] is None:
        return "-"
    v = r["value"]
    mark = "" if r["passed"] is None else ("" if r["passed"] else "!")
    return f"{v:.0f}" if r["name"] == "n_cycles" else f"{v:.3f}{mark}"


def summary(store, run_id: str) -> list[str]:
    """The results table, the verdict and the report, as console lines."""
    rows = store.characteristics(run_id)
    if not rows:
        return []
    lines = []
    by_pose: dict[str, dict] = {}
    for r in rows:
        by_pose.setdefault(r["pose"], {})[r["name"]] = r
    names = {r["name"] for r in rows}
    shown = [c for c in table.characteristics() if c.stated or c.key in names]
    cols = [c for c in shown if c.level == "pose"]
    lines.append(f"{'pose':<8}" + "".join(f"{c.column:>10}" for c in cols))
    for pose in sorted(p for p in by_pose if p.startswith("P") and "-" not in p):
        lines.append(f"{pose:<8}" + "".join(f"{_fmt(by_pose[pose].get(c.key)):>10}" for c in cols))
    for pose, d in sorted(by_pose.items()):
        for c in shown:
            if c.level != "pose" and c.key in d:
                lines.append(f"{c.key:<7} {pose:<8} {_fmt(d[c.key]):>10}")
    if not any(r["limit"] is not None for r in rows):
        lines.append("no limits configured")
    lines += _decision_lines(store, run_id)
    try:
        pose = store.result(run_id, "iso9283")["pose"]
    except Exception:  # noqa: BLE001 - a run stored before the analysis kept its reasons
        pose = None
    if pose is not None and "iso_reasons" in pose:
        lines.append(conformance_text(pose["iso_reasons"]))
    rep = [s.output for s in store.steps(run_id) if s.name == "report" and s.status == "done"]
    if rep:
        lines.append(f"report: {rep[0]['report']}")
        if rep[0].get("frame"):
            lines.append(f"frame: {rep[0]['frame']} (for station analyze iso9283 --frame)")
    return lines


def run_checks(store, run_id: str, params: Mapping) -> Checks:
    """A finished run beyond its stored limits: a configured limit the analysis did not compute, fewer
    pose cycles found at a pose than the plan asked, vAP stops missing (NOT DECIDED); ISO conformance."""
    rows = store.characteristics(run_id)
    undecided = []
    judged = {r["name"] for r in rows if r["limit"] is not None}
    for name, lim in sorted((params.get("limits") or {}).items()):
        if name not in judged:
            undecided.append(f"limit {name} <= {lim:g} configured, but {name} was not computed")
    asked = int(params.get("cycles", 0))
    for r in rows:
        if r["name"] == "n_cycles" and (r["value"] or 0) < asked:
            undecided.append(f"{r['pose']}: {0 if r['value'] is None else int(r['value'])} of {asked} pose cycles found")
    # every characteristic of the plan is stated, or the run is not decided (a resumed run must state what the
    # run left alone states; a figure the stream could not give is not a PASS by its absence)
    # (a figure with a limit says so in its own reason: not computed)
    unstated = [f"{r['name']} {r['pose']}" for r in rows
                if r["value"] is None and r["limit"] is None and r["name"] != "n_cycles"]
    if unstated:
        undecided.append("not stated (the stream could not give them): " + ", ".join(unstated))
    try:
        res = store.result(run_id, "iso9283")
    except Exception:  # noqa: BLE001 - no analysis stored: nothing of it can be decided
        return Checks(tuple(undecided + ["no ISO 9283 analysis stored"]), False, ("no analysis",))
    vap = res.get("vap") or {}
    missing = (vap.get("extraction") or {}).get("missing") or []
    if missing:
        undecided.append(f"vAP: {len(missing)} stop(s) of the {int(params.get('vap_cycles', 0))} cycles missing")
    pose = res.get("pose") or {}
    # the standard's cycles per characteristic: AP, RP, AD, RD on the pose cycles (the analysis's reasons),
    # vAP on its own multi-directional cycles
    vap_asked = int(params.get("vap_cycles", 0))
    vap_short = (f"vAP: {vap_asked} of {ISO_CYCLES} multi-directional cycles",) if vap_asked < ISO_CYCLES else ()
    # each figure's U (where a budget was asked) for the guard band of the marginal figures
    U = {(v["subject"], v["characteristic"]): v[f"U_{v['characteristic'].rsplit('_', 1)[-1]}"]
         for v in _stored_verdicts(res) if v.get(f"U_{v['characteristic'].rsplit('_', 1)[-1]}") is not None}
    return Checks(tuple(undecided), bool(pose.get("iso_conformant")) and not vap_short,
                  tuple(pose.get("iso_reasons") or ()) + vap_short, U)


def _stored_verdicts(res: Mapping) -> list[dict]:
    """The stored ISO 9283 verdicts of a run's result, each from the cycles that state it (the pose run's,
    the vAP run's vAP)."""
    return table.from_their_cycles((res.get("pose") or {}).get("verdicts", []),
                                   (res.get("vap") or {}).get("verdicts", []), key=lambda v: v.get("characteristic"))


def _decision_lines(store, run_id: str) -> list[str]:
    """The decision rule and each figure left in its guard band (from the stored verdicts), when a rule was used."""
    try:
        res = store.result(run_id, "iso9283")
    except Exception:  # noqa: BLE001 - no stored result: nothing to say
        return []
    vs = _stored_verdicts(res)
    rules = {v.get("rule") for v in vs} - {None}
    if not rules:
        return []
    lines = [f"decision rule: {', '.join(sorted(rules))} (ISO 14253-1); U = k u with k = 2"]
    for v in vs:
        if v.get("outcome") and Outcome.parse(v["outcome"]) is Outcome.NOT_DECIDED:
            U = v.get(f"U_{table.unit_of(v['characteristic'])}")
            head = f"{Outcome.NOT_DECIDED} {v['characteristic']} {v['subject']}: "
            lines.append(head + (f"{v['value']:.4g} +/- {U:.2g} against {v['limit']:g} (guard band "
                                 f"{v['guard_band'][0]:.4g}..{v['guard_band'][1]:.4g})"
                                 if U is not None and v.get("guard_band") else v.get("note", "")))
    return lines


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    """The plan against its tracker's rates, the safety gate (every program, every target) and the report folder."""
    plan = IsoPlan.from_params(params)
    problems = report_dir_problems(plan.report_dir)
    problems += tracker_rate_problems(devices, plan.tracker_rate_hz, field="iso9283.tracker_rate_hz")
    problems += orientation_problems(plan, devices)
    try:
        rendered = programs(plan)
    except StationError as exc:
        return problems + [f"programs: {exc}"]
    gate = plan.gate()
    for name, prog in rendered.items():
        try:
            gate.check_program(prog.program, q_start=None)
        except StationError as exc:
            problems.append(f"program {name!r}: {exc}")
    return problems


def orientation_problems(plan: IsoPlan, devices, programme: str = "pose") -> list[str]:
    """A 6-DoF plan whose tracker cannot stream orientation; orientation limits (of ``programme``'s figures) on a
    position-only tracker."""
    from station.characteristics import characteristics

    problems = []
    if plan.orientation:
        cls = devices.drivers.get("tracker") if devices is not None else None
        if cls is None and devices is not None and "tracker" in devices.urls:
            from drivers.tracker_url import tracker_class

            try:
                cls = tracker_class(devices.urls["tracker"])
            except StationError:
                cls = None  # the URL's own problem is told by the rate check
        if cls is not None and not getattr(cls, "measures_orientation", False):
            problems.append(f"devices.tracker.six_dof: this tracker ({getattr(cls, 'protocol', '?')}) streams "
                            "positions only, not a 6-DoF target's orientation")
    else:
        angles = sorted(k for k in plan.limits
                        if any(c.key == k and c.with_orientation for c in characteristics(programme)))
        if angles:
            problems.append(f"limits {', '.join(angles)}: orientation limits need a 6-DoF tracker "
                            "(devices.tracker.six_dof = true); this one measures positions only")
    return problems


SPEC = ProcedureSpec(
    name="iso9283",
    standard="ISO 9283",
    new_params=new_params,
    build=lambda params: build_procedure(IsoPlan.from_params(params)),
    new_session=lambda devices: IsoSession(devices),
    subject=subject,
    device_roles=device_roles,
    fake_cell="fakes.cells:iso9283_cell",
    result_key="iso9283",
    summary=summary,
    preflight=preflight_problems,
    checks=run_checks,
    reanalyse=reanalyse,
)
