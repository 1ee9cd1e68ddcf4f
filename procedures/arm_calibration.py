"""Kinematic calibration of an arm (seed 002 sec. 2-3) with a tracker or a 3D scanner, as a readable list of steps.

The instrument is the config's ``arm_calibration.instrument``, stored with
the plan: ``"tracker"`` (a reflector on the flange, described below) or
``"scanner"`` (the corner jig on the tool, a fixed 3D scanner behind a hot
folder, :mod:`drivers.scanner`). Both are one procedure: the same plan,
gate-checked programs, resumable batches, identification, report and history
per serial; the scanner changes the candidates, the mount prompt, the
devices (scanner and controller) and the measure step (see
:func:`step_measure_scanner`: capture, then the jig corner by
:func:`station.analysis.jig_features.feature_point`, seed 002 eq. (2); a
cloud without the jig is a failed pose, recorded with its reason and left
out of the fit). The identification is the absolute one (scanner <- base,
seed 002 sec. 3) or distances, on the poses where the jig was found.

Tracker runs:

1. ``check programs`` - the measurement poses (chosen when the run was
   planned, stored with it) are each a program (ABB RAPID) that the safety
   gate passes, path from the previous pose included, before anything
   connects;
2. ``mount reflector`` / ``clear the cell`` - operator prompts;
3. ``connect devices`` - tracker and controller (taking over from a
   session that died);
4. ``measure k/M`` - a batch of poses per step: each approached with every
   joint moving in + for its last degrees (one side of the backlash, as the
   seed's hand-taught poses are), a dwell, and a stationary tracker
   measurement committed to the store at once; a killed run resumes at the
   batch it was in and keeps every measured pose (an arm that stands
   elsewhere on the plan's path, inside the batch or at home, is first
   taken along that path to the pose before the batch,
   :func:`to_batch_start_program`);
5. ``identify`` - seed 002's identification on the training poses
   (:func:`station.analysis.arm_calibration.calibrate_arm`), validated on
   test poses drawn apart from them; the identified model is written as a
   JSON model file beside the report and stored with the run under the
   robot's serial;
6. ``report`` - the seed's figures (errors before and after per pose, RMSE
   per iteration, the parameter changes with their uncertainties).

How the poses are chosen (:func:`plan_from_config`): candidate tool poses
spread over the robot's workspace box with the tool tilted up to
``tilt_deg`` from the ISO programs' tool-down orientation, solved by the
nominal model's inverse kinematics near the home configuration, kept when
the gate's box and joint limits allow them (and, with ``instrument_mm``,
when the reflector faces the tracker); the training poses are the
D-optimal choice of :func:`station.analysis.pose_selection.select_poses`,
the test poses a random draw from the remaining candidates, and the
sequence is ordered nearest-first in joint space with every joint path
checked by the gate. Scanner runs draw their candidates with
:func:`scanner_candidate_poses` instead: the jig corner (the TCP) inside the
scanner's field, the tool z axis at the scanner within the jig's view cone.
"""

from __future__ import annotations

import json
import math
import os
import re
import secrets
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from procedures.cell import (ROBOT_STREAM, CellSession, connect_cell, connect_controller, prompt_step,
                            record_robot_readings, robot_subject, stop_cell)
from procedures.preflight import report_dir_problems
from procedures.registry import ProcedureSpec
from procedures.live_views import arm_calibration_view
from procedures.plan_params import plan_from_params, plan_params
from station.analysis.arm.calibration import Split, calibrate_arm, calibration_json
from station.analysis.arm.jig_features import feature_point
from station.analysis.arm.pose_planning import (PRE_DEG, _path_ok, along_chain, candidate_poses, order_poses,
                                                scanner_candidate_poses)
from station.analysis.arm.pose_selection import select_poses
from station.device_urls import parse_device_url
from station.errors import ConfigError, InsufficientDataError, SafetyError, StationError
from station.models.robots import RobotSpec, get_robot
from station.programs.builders import rated_tcp_accel_mm_s2
from station.programs.program import Dwell, JointTarget, Move, Program
from station.programs.rapid import render_rapid
from station.runner import Procedure, Step, StepContext
from station.safety import SafetyGate, SafetyLimits

NAME = "arm-calibration"
STREAM = "points"
#: scanner runs: the jig corner found per pose (scanner frame, mm), its 1-sigma, the cloud's size, found 1/0
SCAN_STREAM = "features"
RESULT_KEY = "arm_calibration"


@dataclass(frozen=True)
class ArmCalPlan:
    """The stored plan of a calibration run (JSON-able via :meth:`params`)."""

    robot: RobotSpec
    workspace_min_mm: tuple[float, float, float]
    workspace_max_mm: tuple[float, float, float]
    max_tcp_speed_mm_s: float
    max_speed_frac: float
    max_accel_frac: float
    #: the measurement sequence (deg), in the order measured
    q_deg: tuple[tuple[float, ...], ...]
    #: role of each pose: "reference", "train" or "test"
    roles: tuple[str, ...]
    method: str = "absolute"
    dwell_s: float = 0.3
    measure_s: float = 0.2
    speed_frac: float = 0.2
    poses_per_step: int = 8
    report_dir: str = "reports"
    selection: dict | None = None
    #: "tracker" (reflector on the flange) or "scanner" (corner jig on the tool, fixed 3D scanner)
    instrument: str = "tracker"
    #: scanner: how long one capture may take (s)
    scan_timeout_s: float = 30.0
    #: the model the identification starts from (7, 5) mm/rad; None: the robot's nominal one
    start_dh: tuple | None = None

    @property
    def is_ur(self) -> bool:
        """A UR: identified as plain DH (no beta) so that the result is written as UR calibration deltas."""
        return self.robot.controller == "ur"

    def gate(self) -> SafetyGate:
        return SafetyGate(self.robot, SafetyLimits(
            workspace_min_mm=self.workspace_min_mm, workspace_max_mm=self.workspace_max_mm,
            max_tcp_speed_mm_s=self.max_tcp_speed_mm_s, max_speed_frac=self.max_speed_frac,
            max_accel_frac=self.max_accel_frac))

    @property
    def n_batches(self) -> int:
        return math.ceil(len(self.q_deg) / self.poses_per_step)

    def batch(self, k: int) -> range:
        """Pose indices of batch ``k`` (1-based)."""
        return range((k - 1) * self.poses_per_step, min(k * self.poses_per_step, len(self.q_deg)))

    def split(self) -> Split:
        roles = np.array(self.roles)
        train = np.flatnonzero((roles == "reference") | (roles == "train"))
        return Split(int(np.flatnonzero(roles == "reference")[0]), train, np.flatnonzero(roles == "test"))

    def params(self) -> dict:
        return plan_params(self)

    @classmethod
    def from_params(cls, p: Mapping) -> "ArmCalPlan":
        return plan_from_params(cls, p)


def plan_from_config(cfg, robot_name: str = "r1", **overrides) -> ArmCalPlan:
    """Choose the poses of a new run (stored with it: a resume measures the same poses)."""
    if robot_name not in cfg.robots:
        raise ConfigError(f"robots.{robot_name}: no such robot (have {', '.join(sorted(cfg.robots))})")
    rc = cfg.robots[robot_name]
    ac = cfg.arm_calibration
    seed = int(overrides.pop("selection_seed", secrets.randbits(32)))
    robot = get_robot(rc.model)
    base = dict(robot=robot, workspace_min_mm=tuple(rc.workspace.min_mm), workspace_max_mm=tuple(rc.workspace.max_mm),
                max_tcp_speed_mm_s=rc.workspace.max_tcp_speed_mm_s,
                max_speed_frac=rc.workspace.max_speed_percent / 100.0,
                max_accel_frac=rc.workspace.max_accel_percent / 100.0)
    method = overrides.pop("method", ac.method)
    n_train = int(overrides.pop("train_poses", ac.train_poses))
    n_test = int(overrides.pop("test_poses", ac.test_poses))
    selection = overrides.pop("selection", ac.selection)
    probe = ArmCalPlan(q_deg=(), roles=(), **base)
    gate = probe.gate()
    rng = np.random.default_rng(seed)
    n_cand = int(overrides.pop("candidates", ac.candidates))
    if ac.instrument == "scanner":
        cand = scanner_candidate_poses(
            robot, gate, n_cand, rng, eye_mm=ac.instrument_mm, look_at_mm=ac.instrument_look_at_mm,
            fov_mm=ac.scanner_fov_mm, working_distance_mm=ac.scanner_working_distance_mm,
            depth_range_mm=ac.scanner_depth_range_mm, half_angle_deg=ac.jig_half_angle_deg)
    else:
        cand = candidate_poses(robot, gate, n_cand, rng, tilt_deg=ac.tilt_deg,
                               instrument_mm=ac.instrument_mm, half_angle_deg=ac.reflector_half_angle_deg)
    if cand.shape[0] < n_train + n_test:
        raise InsufficientDataError(
            f"only {cand.shape[0]} admissible candidate poses for {n_train} training and {n_test} test poses: "
            + ("widen the workspace box, the tilt or the candidates" if ac.instrument == "tracker" else
               "check instrument_mm / instrument_look_at_mm (the scanner's field must lie in the workspace box "
               "where the arm reaches it with the tool facing the scanner) or add candidates"))
    info: dict[str, Any] = {"seed": seed, "method": selection, "candidates": int(cand.shape[0])}
    if selection == "d-optimal":
        sel = select_poses(robot.dh_nominal, cand, n_train)
        train = sel.indices
        info.update(log_det=sel.log_det, o1=sel.o1, swaps=sel.swaps)
    else:
        train = rng.choice(cand.shape[0], n_train, replace=False)
    rest = np.setdiff1d(np.arange(cand.shape[0]), train)
    test = rng.choice(rest, n_test, replace=False) if n_test else np.zeros(0, np.int64)
    chosen = np.r_[train, test]
    roles_all = ["train"] * len(train) + ["test"] * len(test)
    order, dropped = order_poses(gate, robot.home_q_rad, cand[chosen])
    seq = [int(chosen[k]) for k in order]
    roles = [roles_all[k] for k in order]
    # a pose no safe joint path reaches is replaced by the nearest unused candidate the last pose reaches
    unused = set(range(cand.shape[0])) - set(chosen.tolist())
    for k in dropped:
        near = sorted(unused, key=lambda c: float(np.max(np.abs(cand[c] - cand[seq[-1]]))))
        for c in near:
            if _path_ok(gate, cand[seq[-1]], cand[c]):
                seq.append(c)
                roles.append(roles_all[k])
                unused.discard(c)
                break
    q_seq = cand[seq]
    roles[roles.index("train")] = "reference"  # the first training pose measured is the distances' reference
    info["replaced_after_path_checks"] = len(dropped)
    kw = dict(base, q_deg=tuple(tuple(float(v) for v in np.degrees(q)) for q in q_seq), roles=tuple(roles),
              method=method, dwell_s=ac.dwell_s, measure_s=ac.measure_s,
              speed_frac=min(ac.speed_percent, rc.workspace.max_speed_percent) / 100.0,
              poses_per_step=ac.poses_per_step, report_dir=cfg.station.report_dir, selection=info,
              instrument=ac.instrument, scan_timeout_s=ac.scan_timeout_s)
    if ac.ur_calibration:
        from station.models.arm_model_file import read_ur_calibration

        # the UR's previous calibration (read back as the controller holds it) is where this one starts
        kw["start_dh"] = tuple(tuple(float(v) for v in r) for r in read_ur_calibration(ac.ur_calibration,
                                                                                        robot.dh_nominal))
    kw.update(overrides)
    return ArmCalPlan(**kw)


# --------------------------------------------------------------------------
# programs
# --------------------------------------------------------------------------
#: a joint move's speed is chosen so that its estimated peak TCP speed stays this fraction of the gate's cap
SPEED_CAP_MARGIN = 0.95


def move_speed_frac(plan: ArmCalPlan, gate: SafetyGate, qa_deg, qb_deg) -> float:
    """The speed fraction of the joint move ``qa_deg -> qb_deg``: the plan's, or less where the move's
    estimated peak TCP speed at the plan's speed would pass the gate's TCP speed cap (a long move of a
    small arm whose joints turn fast), so the plan keeps within the cap instead of being refused."""
    v = gate.joint_move_peak_tcp_speed(np.radians(qa_deg), np.radians(qb_deg), plan.speed_frac)
    cap = SPEED_CAP_MARGIN * gate.max_tcp_speed_mm_s
    return plan.speed_frac if v <= cap else plan.speed_frac * cap / v


def pose_program(plan: ArmCalPlan, k: int, gate: SafetyGate | None = None, path_deg=None) -> Program:
    """Pose ``k``: to a pre-position ``PRE_DEG`` below on every joint, then the pose, then a dwell; each move
    from the plan's waypoint before it at the plan's speed or less (:func:`move_speed_frac`). ``gate`` and
    ``path_deg`` (:func:`plan_path_deg`'s waypoints), when a caller has them, are not built again."""
    gate = gate or plan.gate()
    w = plan_path_deg(plan)[0] if path_deg is None else path_deg
    q = plan.q_deg[k]
    name = f"C{k + 1}"
    pre = JointTarget(f"{name}_pre", tuple(v - PRE_DEG for v in q), label=f"{name} pre-position")
    target = JointTarget(name, tuple(q), label=name)
    s_pre = move_speed_frac(plan, gate, w[2 * k], w[2 * k + 1])
    s_pose = move_speed_frac(plan, gate, w[2 * k + 1], w[2 * k + 2])
    return Program(
        name=f"ST_{name}", robot_name=plan.robot.name, rated_tcp_speed_mm_s=float(plan.robot.max_tcp_speed_mm_s),
        statements=(Move(pre, "joint", s_pre), Move(target, "joint", s_pose), Dwell(plan.dwell_s)),
        accel_frac=0.5, title=f"station: calibration pose {name}",
        rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(plan.robot),
    )


#: how far (deg, any joint) from the plan's path an arm may stand and be on it: a controlled stop keeps a joint
#: move's path to within the servo lag, tenths of a degree at most. Only whether the arm is taken along the path
#: depends on it: every move, the first one included, is gated from where the arm stands
ON_PATH_DEG = 0.5


def plan_path_deg(plan: ArmCalPlan) -> tuple[np.ndarray, list[str]]:
    """The joint path of the whole plan as its gate checked it (:func:`check_programs`): home, then each pose's
    pre-position and pose (2N + 1, 6) deg; and the waypoints' names. Pose ``i`` (0-based) is waypoint 2i + 2."""
    w, names = [np.degrees(plan.robot.home_q_rad)], ["home"]
    for i, q in enumerate(plan.q_deg):
        q = np.asarray(q, float)
        w += [q - PRE_DEG, q]
        names += [f"C{i + 1}_pre", f"C{i + 1}"]
    return np.array(w), names


def to_batch_start_program(plan: ArmCalPlan, k: int, q_now_deg) -> tuple[Program | None, list[str]]:
    """The way to the start of batch ``k`` (the pose before it; home for the first) for an arm that does not
    stand there: a run stopped inside the batch left it on a later move, or it stands at home (re-homed, a new
    simulated cell). The batch's first program was gated from its start only.

    The arm goes along the plan's own path (:func:`along_chain`), back or forward: no joint path the plan's
    gate did not check is driven. None when the arm already stands at the start, or stands on no move of the
    plan (then the controller's gate judges the first pose program from where it stands, as for any start).
    """
    w, names = plan_path_deg(plan)
    goal = 2 * plan.batch(k)[0]
    way = along_chain(w, q_now_deg, goal, ON_PATH_DEG)
    if way is None or not len(way):
        return None, []
    index = {tuple(v): n for v, n in zip(map(tuple, w), names)}
    labels = [index[tuple(q)] for q in way]
    gate = plan.gate()
    starts = [np.asarray(q_now_deg, float)] + [np.asarray(q, float) for q in way[:-1]]
    moves = tuple(Move(JointTarget(f"R{i + 1}", tuple(float(v) for v in q), label=f"to {labels[i]}"),
                       "joint", move_speed_frac(plan, gate, qa, q)) for i, (qa, q) in enumerate(zip(starts, way)))
    return Program(name=f"ST_TO{k}", robot_name=plan.robot.name,
                   rated_tcp_speed_mm_s=float(plan.robot.max_tcp_speed_mm_s), statements=moves, accel_frac=0.5,
                   title=f"station: along the plan to the start of batch {k}",
                   rated_tcp_accel_mm_s2=rated_tcp_accel_mm_s2(plan.robot)), labels


def _to_batch_start(ctx: StepContext, plan: ArmCalPlan, k: int, controller) -> list[str]:
    """Drive the arm along the plan's path to the start of batch ``k`` when it stands elsewhere on it; the
    waypoints passed (empty when it stood at the start)."""
    program, labels = to_batch_start_program(plan, k, np.degrees(controller.joints_rad()))
    if program is None:
        return []
    ctx.progress(f"to {labels[-1]}")
    controller.run(render_rapid(program), timeout_s=_timeout(ctx, 60.0 * len(labels)),
                   on_status=lambda st: ctx.checkpoint())
    return labels


def check_programs(plan: ArmCalPlan) -> list[str]:
    """Every pose program through the gate, each from the pose before it (home first); the problems."""
    gate = plan.gate()
    path = plan_path_deg(plan)[0]
    problems = []
    q_prev = plan.robot.home_q_rad
    for k in range(len(plan.q_deg)):
        try:
            gate.check_program(pose_program(plan, k, gate, path), q_start=q_prev)
        except StationError as exc:
            problems.append(f"pose C{k + 1}: {exc}")
        q_prev = np.radians(plan.q_deg[k])
    return problems


# --------------------------------------------------------------------------
# steps
# --------------------------------------------------------------------------
@dataclass
class ArmCalSession(CellSession):
    """What the calibration steps share within one session (the cell's, and the scanner)."""

    scanner: Any = None
    #: the measured points and scanner details, read from the store once per session
    measured: tuple | None = None
    #: the calibration of those points (identify and report share it)
    calibration: Any = None


def _plan(ctx: StepContext) -> ArmCalPlan:
    if ctx.session.plan is None:
        ctx.session.plan = ArmCalPlan.from_params(ctx.params)
    return ctx.session.plan


def step_check_programs(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    problems = check_programs(plan)
    if problems:
        raise SafetyError("; ".join(problems))
    ctx.session.gate = plan.gate()
    roles = list(plan.roles)
    return {"poses": len(plan.q_deg), "train": roles.count("train") + 1, "test": roles.count("test"),
            "selection": plan.selection}


_prompt = prompt_step


def step_connect(ctx: StepContext) -> dict:
    return connect_cell(ctx.session, ctx.session.gate or _plan(ctx).gate())


def step_connect_scanner(ctx: StepContext) -> dict:
    """Scanner (its hot folder) and controller; an earlier session's program or watchdog fault is taken over."""
    session = ctx.session
    scanner = session.scanner = session.device("scanner")
    info = scanner.connect()
    return {"scanner": str(getattr(info, "name", info)),
            **connect_controller(session, session.gate or _plan(ctx).gate())}


def _timeout(ctx: StepContext, sim_seconds: float) -> float:
    return 30.0 + sim_seconds / (ctx.session.time_scale or 1.0) * 3.0


def _capture_name(run_id: str, i: int) -> str:
    """A capture name of its own for every scan (a re-measured pose never meets an earlier answer)."""
    return f"{re.sub(r'[^A-Za-z0-9._-]', '_', run_id)[:80]}-C{i + 1}-{secrets.token_hex(3)}"


def step_measure_scanner(k: int):
    """Batch ``k`` with the scanner: each pose programmed, captured, and its jig corner found (seed 002 eq. (2)).

    A cloud in which the jig is not found is recorded as a failed pose (the
    reason in the step's output) and the run goes on; a scanner that does not
    answer or answers with a broken file stops the step (resumable).
    """
    def run(ctx: StepContext) -> dict:
        plan = _plan(ctx)
        scanner, controller = ctx.session.scanner, ctx.session.controller
        done, failed = [], {}
        ctx.checkpoint()
        back = _to_batch_start(ctx, plan, k, controller)
        for i in plan.batch(k):
            ctx.checkpoint()
            ctx.progress(f"pose C{i + 1}")
            controller.run(render_rapid(pose_program(plan, i)), timeout_s=_timeout(ctx, 60.0),
                           on_status=lambda st: ctx.checkpoint())
            cloud = scanner.capture(_capture_name(ctx.run_id, i), timeout_s=plan.scan_timeout_s)
            try:
                f = feature_point(cloud)
                xyz, sig, found = f.point_mm, f.sigma_mm, 1.0
            except InsufficientDataError as exc:
                xyz, sig, found = np.full(3, np.nan), np.full(3, np.nan), 0.0
                failed[f"C{i + 1}"] = f"jig not found in {cloud.shape[0]} points: {exc}"
            ctx.record(SCAN_STREAM, {
                "pose": np.array([i], float), "x": xyz[:1], "y": xyz[1:2], "z": xyz[2:3],
                "sigma_x": sig[:1], "sigma_y": sig[1:2], "sigma_z": sig[2:3],
                "points": np.array([cloud.shape[0]], float), "found": np.array([found])})
            done.append(i + 1)
        return {"poses": done, "failed": failed, **({"approach": back} if back else {})}
    return run


def step_measure(k: int):
    def run(ctx: StepContext) -> dict:
        plan = _plan(ctx)
        tracker, controller = ctx.session.tracker, ctx.session.controller
        done = []
        ctx.checkpoint()
        back = _to_batch_start(ctx, plan, k, controller)
        for i in plan.batch(k):
            ctx.checkpoint()
            ctx.progress(f"pose C{i + 1}")
            rendered = render_rapid(pose_program(plan, i))
            controller.run(rendered, timeout_s=_timeout(ctx, 60.0), on_status=lambda st: ctx.checkpoint())
            record_robot_readings(ctx, controller)  # the move's; what follows is the measurement's
            m = tracker.measure_stationary(duration_s=plan.measure_s)
            xyz = np.asarray(m.xyz_mm, dtype=float)
            # the joint angles beside the point, so that the run's export is an arm CSV `calibrate arm` reads:
            # the arm's own while the tracker measured where it gives them (RTDE on a UR), else the commanded
            row = {"pose": np.array([i], float),
                   **{f"q{j + 1}": np.array([float(plan.q_deg[i][j])]) for j in range(6)},
                   "x": xyz[:1], "y": xyz[1:2], "z": xyz[2:3],
                   "t": np.array([np.nan if m.t_device_s is None else float(m.t_device_s)])}
            q_meas = _measured_joints_deg(ctx, controller)
            if q_meas is not None:
                row.update({f"q{j + 1}": q_meas[j:j + 1] for j in range(6)})
            row["q_measured"] = np.array([0.0 if q_meas is None else 1.0])
            ctx.record(STREAM, row)
            done.append(i + 1)
        return {"poses": done, **({"approach": back} if back else {})}
    return run


def _measured_joints_deg(ctx: StepContext, controller) -> np.ndarray | None:
    """Mean joint angles (deg) the robot reported since the last call (the measurement's; committed to the
    ``robot`` stream too), or None when it gives no readings stream (the Modbus controller: the plan's joint
    angles are used)."""
    r = controller.readings()
    if r is None:
        return None
    if not len(r):
        return np.degrees(np.asarray(controller.joints_rad(), dtype=float))
    ctx.record(ROBOT_STREAM, r.columns())
    return np.degrees(np.mean(r.q_rad, axis=0))


def measured_joints_deg(ctx: StepContext, plan: ArmCalPlan) -> np.ndarray:
    """(N, 6) joint angles of the poses in plan order, deg: the arm's own reading where the robot gave one
    (a UR's RTDE ``actual_q`` while the tracker measured), else the commanded ones of the plan."""
    q = np.array(plan.q_deg, dtype=float)
    steps = [f"measure {k}" for k in range(1, plan.n_batches + 1)]
    s = ctx.samples(STREAM, steps=steps)
    if s and "q1" in s:
        idx = s["pose"].astype(int)
        qm = np.column_stack([s[f"q{j}"] for j in range(1, 7)])
        ok = np.isfinite(qm).all(axis=1)
        q[idx[ok]] = qm[ok]
    return q


def measured_points(ctx: StepContext, plan: ArmCalPlan) -> np.ndarray:
    """(N, 3) tracker points in plan order; the last measurement of a pose measured twice (a resumed batch)."""
    steps = [f"measure {k}" for k in range(1, plan.n_batches + 1)]
    s = ctx.samples(STREAM, steps=steps)
    out = np.full((len(plan.q_deg), 3), np.nan)
    if s:
        idx = s["pose"].astype(int)
        out[idx] = np.column_stack([s["x"], s["y"], s["z"]])
    missing = np.flatnonzero(~np.isfinite(out).all(axis=1))
    if missing.size:
        raise InsufficientDataError(f"poses not measured: {', '.join(f'C{i + 1}' for i in missing[:10])}"
                                    + (" ..." if missing.size > 10 else ""))
    return out


@dataclass(frozen=True)
class ScannerPoints:
    """The jig corners of a scanner run, plan order: NaN rows for the failed poses."""

    point_mm: np.ndarray  # (N, 3), scanner frame
    sigma_mm: np.ndarray  # (N, 3), 1 sigma from the corner fit
    failed: dict  # "C5" -> reason


def scanner_points(ctx: StepContext, plan: ArmCalPlan) -> ScannerPoints:
    """The corners found per pose (the last capture of a pose measured twice) and why the others failed."""
    names = [f"measure {k}" for k in range(1, plan.n_batches + 1)]
    s = ctx.samples(SCAN_STREAM, steps=names)
    n = len(plan.q_deg)
    pt, sg, seen, found = np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.zeros(n, bool), np.zeros(n, bool)
    if s:
        idx = s["pose"].astype(int)
        pt[idx] = np.column_stack([s["x"], s["y"], s["z"]])
        sg[idx] = np.column_stack([s["sigma_x"], s["sigma_y"], s["sigma_z"]])
        seen[idx] = True
        found[idx] = s["found"] > 0.5
    missing = np.flatnonzero(~seen)
    if missing.size:
        raise InsufficientDataError(f"poses not measured: {', '.join(f'C{i + 1}' for i in missing[:10])}"
                                    + (" ..." if missing.size > 10 else ""))
    reasons: dict[str, str] = {}
    for st in ctx.store.steps(ctx.run_id):
        if st.name in names and st.status == "done" and st.output:
            reasons.update(st.output.get("failed") or {})
    failed = {f"C{i + 1}": reasons.get(f"C{i + 1}", "jig not found") for i in np.flatnonzero(~found)}
    return ScannerPoints(pt, sg, failed)


def _kept_split(plan: ArmCalPlan, keep: np.ndarray) -> Split:
    """The plan's split over the poses kept (``keep`` (N,) bool); the reference moves to the first kept train pose."""
    split = plan.split()
    new = np.cumsum(keep) - 1
    train = np.array([i for i in split.train if keep[i]], dtype=np.int64)
    test = np.array([i for i in split.test if keep[i]], dtype=np.int64)
    if train.size == 0:
        raise InsufficientDataError("the jig was found in none of the training poses")
    ref = split.reference if keep[split.reference] else int(train[0])
    return Split(int(new[ref]), new[train], new[test])


def _calibrate(plan: ArmCalPlan, points: np.ndarray, q_deg: np.ndarray | None = None):
    """Identify from the measured points (N, 3) at the joint angles ``q_deg`` (N, 6) (default: the plan's);
    rows with NaN (scanner poses without the jig) are left out. A UR is identified as plain DH (no beta)
    from its start model (its previous calibration, or the nominal one)."""
    keep = np.isfinite(points).all(axis=1)
    split = plan.split() if keep.all() else _kept_split(plan, keep)
    q = np.array(plan.q_deg if q_deg is None else q_deg, dtype=float)
    dh0 = plan.robot.dh_nominal if plan.start_dh is None else np.array(plan.start_dh, dtype=float)
    return calibrate_arm(dh0, np.radians(q)[keep], points[keep],
                         method=plan.method, joint_limits_rad=plan.robot.joint_limits_rad, split=split,
                         use_beta=not plan.is_ur)


def _points(ctx: StepContext, plan: ArmCalPlan) -> tuple[np.ndarray, ScannerPoints | None]:
    if plan.instrument == "scanner":
        sp = scanner_points(ctx, plan)
        return sp.point_mm, sp
    return measured_points(ctx, plan), None


def _measured(ctx: StepContext, plan: ArmCalPlan) -> tuple[np.ndarray, ScannerPoints | None]:
    if ctx.session.measured is None:
        ctx.session.measured = _points(ctx, plan)
    return ctx.session.measured


def _calibration(ctx: StepContext, plan: ArmCalPlan):
    if ctx.session.calibration is None:
        q = measured_joints_deg(ctx, plan) if plan.instrument == "tracker" else None
        ctx.session.calibration = _calibrate(plan, _measured(ctx, plan)[0], q)
    return ctx.session.calibration


def step_identify(ctx: StepContext) -> dict:
    plan = _plan(ctx)
    _, sp = _measured(ctx, plan)
    cal = _calibration(ctx, plan)
    doc = calibration_json(cal, name=f"{plan.robot.name} calibrated", joint_limits_rad=plan.robot.joint_limits_rad)
    doc["instrument"] = plan.instrument
    if sp is not None:
        ok = np.isfinite(sp.sigma_mm).all(axis=1)
        doc["failed_poses"] = sp.failed
        doc["feature_sigma_mm"] = {
            "median": float(np.median(np.linalg.norm(sp.sigma_mm[ok], axis=1))) if ok.any() else None,
            "max": float(np.max(np.linalg.norm(sp.sigma_mm[ok], axis=1))) if ok.any() else None}
    run = ctx.store.run(ctx.run_id)
    doc["robot"] = {"model": plan.robot.name, "serial": run.serial, "overhaul_state": run.overhaul_state}
    doc["selection"] = plan.selection
    from station.readers.out_files import write_output

    model_path = write_output(Path(plan.report_dir) / f"{ctx.run_id}-model.json", json.dumps(doc["model"], indent=2),
                              "report_dir")
    doc["model_file"] = str(model_path.resolve())
    if plan.is_ur:
        from station.models.arm_model_file import ur_deltas, write_ur_calibration

        # the deltas are the controller's: relative to the UR's nominal model, whatever this run started from
        conf = Path(plan.report_dir) / f"{ctx.run_id}-calibration.conf"
        write_ur_calibration(conf, ur_deltas(cal.dh, plan.robot.dh_nominal))
        doc["ur_calibration_file"] = str(conf.resolve())
    recorded = ctx.samples(STREAM, steps=[f"measure {k}" for k in range(1, plan.n_batches + 1)])
    doc["joints"] = ("measured" if plan.instrument == "tracker" and recorded and "q_measured" in recorded
                     and bool(np.all(recorded["q_measured"] == 1.0)) else "commanded")
    ctx.store.put_result(ctx.run_id, RESULT_KEY, doc)
    limit = (run.config.get("arm_calibration") or {}).get("test_error_limit_mm")
    ctx.store.put_characteristics(ctx.run_id, error_rows(doc, limit))
    return {"train_mean_after_mm": doc["train"]["mean_abs_after_mm"],
            "test_mean_after_mm": doc["test"]["mean_abs_after_mm"] if doc["test"] else None,
            "model_file": doc["model_file"], "converged": doc["converged"],
            "ur_calibration_file": doc.get("ur_calibration_file"),
            "failed_poses": sorted(doc.get("failed_poses", {}))}


def error_rows(doc: Mapping, test_limit_mm: float | None) -> list[dict]:
    """The calibration's characteristics (pose ``train`` / ``test``): mean |error| before and after, max
    after; ``test`` ``mean_error_after_mm`` is judged against ``arm_calibration.test_error_limit_mm``
    (no test poses with a limit: not computed, NOT DECIDED)."""
    rows = []
    for part in ("train", "test"):
        d = doc.get(part)
        for name, key in (("mean_error_before_mm", "mean_abs_before_mm"), ("mean_error_after_mm", "mean_abs_after_mm"),
                          ("max_error_after_mm", "max_abs_after_mm")):
            value = None if not d else float(d[key])
            lim = test_limit_mm if (part == "test" and name == "mean_error_after_mm") else None
            if value is None and lim is None:
                continue
            passed = None if (lim is None or value is None) else bool(value <= lim)
            rows.append({"pose": part, "name": name, "value": value, "unit": "mm", "limit": lim, "passed": passed})
    return rows


DIAGNOSIS_KEY = "diagnosis"


def step_diagnose(ctx: StepContext) -> dict:
    """What the station's simulation of this arm gets wrong (issue: diagnose), on the poses just measured.

    The poses are measured in order, each approached from below on every joint, so backlash shows as
    not testable here (one direction only); the other named effects are tested and selected as by
    ``station diagnose arm``. Too few poses for a candidate is reported, not a failure of the run.
    """
    from station.analysis.diagnose.arm import diagnose_arm

    plan = _plan(ctx)
    points, _ = _measured(ctx, plan)
    q = np.radians(measured_joints_deg(ctx, plan) if plan.instrument == "tracker" else np.array(plan.q_deg))
    ok = np.isfinite(points).all(axis=1)
    try:
        diag = diagnose_arm(plan.robot.dh_nominal, q[ok], points[ok], robot=plan.robot)
    except InsufficientDataError as exc:
        ctx.store.put_result(ctx.run_id, DIAGNOSIS_KEY, {"skipped": str(exc)})
        return {"skipped": str(exc)}
    doc = diag.to_json()
    ctx.store.put_result(ctx.run_id, DIAGNOSIS_KEY, doc)
    return {"effects": [f"{s['effect']}" + (f" joint {s['joint']}" if s.get("joint") else "") for s in doc["steps"]],
            "final_heldout_rms": doc["final_heldout_rms"], "noise_floor": doc["noise_floor"]}


def selection_text(info: dict | None) -> str:
    """The pose selection in words, for the report (``info`` as the plan stores it)."""
    if not info:
        return "given in the config"
    parts = [f"{info.get('method', '?')} from {info.get('candidates', '?')} admissible candidate poses"]
    if info.get("method") == "d-optimal":
        if info.get("o1") is not None:
            parts.append(f"observability O1 {info['o1']:.3g}")
        if info.get("log_det") is not None:
            parts.append(f"log det {info['log_det']:.4g}")
        if info.get("swaps") is not None:
            parts.append(f"{info['swaps']} exchange(s)")
    if info.get("replaced_after_path_checks"):
        parts.append(f"{info['replaced_after_path_checks']} pose(s) no safe path reached replaced by the nearest "
                     "reachable candidate")
    if info.get("seed") is not None:
        parts.append(f"seed {info['seed']}")
    return "; ".join(parts)


def step_report(ctx: StepContext) -> dict:
    from procedures.arm_calibration_report import build_report
    from station.report import write_report

    plan = _plan(ctx)
    _, sp = _measured(ctx, plan)
    cal = _calibration(ctx, plan)
    run = ctx.store.run(ctx.run_id)
    facts = {"run": ctx.run_id, "overhaul state": str(run.overhaul_state), "instrument": plan.instrument,
             "pose selection": selection_text(plan.selection)}
    if sp is not None:
        facts["poses without the jig (left out)"] = "; ".join(f"{k}: {v}" for k, v in sp.failed.items()) or "none"
    report = build_report(cal, title=f"Kinematic calibration of {plan.robot.name} serial {run.serial}",
                          facts=facts)
    path = write_report(report, Path(plan.report_dir) / f"{ctx.run_id}.html")
    return {"report": str(path.resolve())}


def build_procedure(plan: ArmCalPlan) -> Procedure:
    scanner = plan.instrument == "scanner"
    mount = (Step("mount jig", _prompt("Mount the corner jig on the tool flange (its corner at the TCP)")) if scanner
             else Step("mount reflector", _prompt("Mount the tracker reflector on the tool flange (SMR in its nest)")))
    steps = [
        Step("check programs", step_check_programs, every_session=True),
        mount,
        Step("clear the cell", _prompt("Clear the robot cell and close the safety fence"), every_session=True),
        Step("connect devices", step_connect_scanner if scanner else step_connect, every_session=True),
    ]
    measure = step_measure_scanner if scanner else step_measure
    steps += [Step(f"measure {k}", measure(k), label=f"{k}/{plan.n_batches}")
              for k in range(1, plan.n_batches + 1)]
    steps += [Step("identify", step_identify), Step("diagnose", step_diagnose), Step("report", step_report)]
    return Procedure(NAME, steps, safe_state=stop_cell)


# --------------------------------------------------------------------------
# the procedure's entry in the registry
# --------------------------------------------------------------------------
def new_params(cfg, robot: str, report_dir: str, overrides: Mapping) -> dict:
    return plan_from_config(cfg, robot, **{"report_dir": report_dir, **overrides}).params()


subject = robot_subject


def device_roles(cfg, robot: str) -> dict[str, str]:
    subject(cfg, robot)
    instrument = "scanner" if cfg.arm_calibration.instrument == "scanner" else "tracker"
    return {instrument: instrument, "controller": cfg.robots[robot].controller}


def history(store, serial: str) -> list[dict]:
    """Every finished calibration of robot ``serial`` in the store, oldest first."""
    out = []
    for rec in store.runs():
        if rec.procedure != NAME or rec.serial != serial:
            continue
        try:
            doc = store.result(rec.run_id, RESULT_KEY)
        except Exception:  # noqa: BLE001 - a run that has not identified yet has no result
            continue
        out.append({"run_id": rec.run_id, "overhaul_state": rec.overhaul_state, "method": doc["method"],
                    "instrument": doc.get("instrument", "tracker"),
                    "test": doc["test"], "train": doc["train"], "model_file": doc.get("model_file")})
    return out


def summary(store, run_id: str) -> list[str]:
    try:
        doc = store.result(run_id, RESULT_KEY)
    except Exception:  # noqa: BLE001
        return []
    lines = [f"{doc.get('instrument', 'tracker')}, method {doc['method']}: {len(doc['identified'])} parameters identified, {len(doc['fixed'])} fixed, "
             f"condition number {doc['condition_number']:.1f}, {doc['iterations']} iterations"]
    for label in ("train", "test"):
        d = doc[label]
        if d:
            lines.append(f"{label:<6} mean |error| {d['mean_abs_before_mm']:.4f} -> {d['mean_abs_after_mm']:.4f} mm, "
                         f"max {d['max_abs_before_mm']:.4f} -> {d['max_abs_after_mm']:.4f} mm "
                         f"({d['n']} poses)")
    failed = doc.get("failed_poses") or {}
    if failed:
        lines.append(f"{len(failed)} poses without the jig, left out: " + ", ".join(sorted(failed)))
    try:
        diag = store.result(run_id, DIAGNOSIS_KEY)
    except Exception:  # noqa: BLE001 - a run stored before the diagnosis step has none
        diag = None
    if diag and "steps" in diag:
        found = ", ".join(f"{st['effect']}" + (f" (joint {st['joint']})" if st.get("joint") else "")
                          for st in diag["steps"]) or "nothing beyond the noise"
        lines.append(f"diagnosis: {found}; held-out rms {diag['simulation_heldout_rms']:.4f} -> "
                     f"{diag['final_heldout_rms']:.4f} mm (noise floor {diag['noise_floor']:.4f} mm)")
    elif diag:
        lines.append(f"diagnosis skipped: {diag.get('skipped')}")
    lines.append(f"model: {doc.get('model_file')}")
    serial = doc.get("robot", {}).get("serial")
    if serial:
        earlier = [h for h in history(store, serial) if h["run_id"] != run_id]
        for h in earlier[-3:]:
            t = h["test"] or h["train"]
            lines.append(f"earlier {h['run_id']} ({h['overhaul_state']}): mean |error| after "
                         f"{t['mean_abs_after_mm']:.4f} mm")
    rep = [s.output["report"] for s in store.steps(run_id) if s.name == "report" and s.status == "done"]
    if rep:
        lines.append(f"report: {rep[0]}")
    return lines


def scanner_folder_problems(devices) -> list[str]:
    """Why the scanner's hot folder (its ``ply://`` URL) cannot be used; checked on the file system only."""
    url = getattr(devices, "urls", {}).get("scanner")
    if url is None:
        return []
    try:
        u = parse_device_url(url)
    except StationError as exc:
        return [f"scanner URL: {exc}"]
    if u.kind != "scanner":
        return [f"scanner URL {url}: a {u.kind} device cannot scan (use ply:///path/to/hot/folder)"]
    folder = Path(u.path or "")
    if not folder.is_dir():
        return [f"scanner folder {folder} does not exist or is not a folder"]
    if not os.access(folder, os.R_OK | os.W_OK | os.X_OK):
        return [f"scanner folder {folder}: the station may not read and write in it"]
    return []


def preflight_problems(params: Mapping, cfg, devices) -> list[str]:
    plan = ArmCalPlan.from_params(params)
    extra = scanner_folder_problems(devices) if plan.instrument == "scanner" else []
    return report_dir_problems(plan.report_dir) + extra + check_programs(plan)


SPEC = ProcedureSpec(
    name=NAME,
    new_params=new_params,
    build=lambda params: build_procedure(ArmCalPlan.from_params(params)),
    new_session=lambda devices: ArmCalSession(devices),
    subject=subject,
    device_roles=device_roles,
    fake_cell="fakes.cells:arm_calibration_cell",
    result_key=RESULT_KEY,
    summary=summary,
    preflight=preflight_problems,
    live_view=lambda store, run_id, params: arm_calibration_view(store, run_id, params, tracker_stream=STREAM,
                                                                 scanner_stream=SCAN_STREAM),
)
