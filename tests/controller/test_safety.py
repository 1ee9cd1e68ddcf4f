"""The safety gate: reachability, joint limits, workspace box, speed caps; refusals name the line."""

from __future__ import annotations

import re

import numpy as np
import pytest
from pydantic import ValidationError

from station.errors import ConfigError, SafetyError
from station.models import kinematics
from station.programs import (
    CartesianTarget,
    Dwell,
    JointTarget,
    Move,
    Program,
    calibration_program,
    iso_pose_program,
    render_rapid,
    vap_program,
)
from station.programs.builders import home_orientation
from station.safety import SafetyGate, SafetyLimits


def _line_of(text: str, line: int) -> str:
    return text.splitlines()[line - 1]


def _refusal_line(exc: SafetyError) -> int:
    m = re.match(r"line (\d+): ", str(exc))
    assert m, f"refusal does not name a line: {exc}"
    return int(m.group(1))


def test_iso_and_vap_programs_pass_and_reach_their_targets(gate, robot, iso_poses):
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=3))
    rep = gate.check_program(r)
    order = ["P1", "P2", "P3", "P4", "P5", "P1"]
    assert np.allclose(rep.tcp_mm, [iso_poses[n] for n in order], atol=gate.limits.ik_tol_mm)
    lo, hi = gate.joint_limits_rad.T
    assert np.all((rep.q_rad >= lo) & (rep.q_rad <= hi))
    assert rep.peak_tcp_speed_mm_s <= gate.max_tcp_speed_mm_s
    sub = {n: iso_poses[n] for n in ("P1", "P2", "P4")}
    gate.check_program(render_rapid(vap_program(robot, sub, cycles=2)))


def test_target_outside_the_box_is_refused_naming_line_and_target(rng, gate, robot, iso_poses):
    poses = dict(iso_poses)
    name = str(rng.choice(["P2", "P3", "P4", "P5"]))
    axis = int(rng.integers(0, 3))
    xyz = list(poses[name])
    xyz[axis] = gate.box_max[axis] + rng.uniform(1.0, 50.0)
    poses[name] = tuple(xyz)
    r = render_rapid(iso_pose_program(robot, poses, cycles=2))
    with pytest.raises(SafetyError) as ei:
        gate.check_program(r)
    msg = str(ei.value)
    assert f"move to {name}" in msg and "outside the workspace box" in msg and f"{'xyz'[axis]} [" in msg
    assert f"p_{name}," in _line_of(r.text, _refusal_line(ei.value))


def test_unreachable_target_is_refused(robot, iso_poses):
    big = SafetyLimits(workspace_min_mm=(-5000, -5000, -5000), workspace_max_mm=(5000, 5000, 5000), max_tcp_speed_mm_s=2000)
    gate = SafetyGate(robot, big)
    poses = dict(iso_poses)
    poses["P4"] = (0.0, 3600.0, 900.0)  # beyond the 3.1 m reach
    r = render_rapid(iso_pose_program(robot, poses, cycles=2))
    with pytest.raises(SafetyError, match="not reachable") as ei:
        gate.check_program(r)
    assert "p_P4," in _line_of(r.text, _refusal_line(ei.value))


def test_tighter_joint_limits_are_enforced(rng, robot):
    j = int(rng.integers(0, 6))
    lim_deg = np.degrees(robot.joint_limits_rad).copy()
    tight = lim_deg * 0.5
    limits = SafetyLimits(
        workspace_min_mm=(-5000,) * 3,
        workspace_max_mm=(5000,) * 3,
        max_tcp_speed_mm_s=2000,
        joint_limits_deg=tuple(map(tuple, tight)),
    )
    gate = SafetyGate(robot, limits)
    q = np.tile(np.degrees(robot.home_q_rad), (3, 1)).clip(tight[:, 0], tight[:, 1])
    q[1, j] = tight[j, 1] + rng.uniform(0.5, 5.0)  # inside the robot's limits, outside the cell's
    assert q[1, j] < lim_deg[j, 1]
    r = render_rapid(calibration_program(robot, q))
    with pytest.raises(SafetyError, match=f"joint {j + 1} at") as ei:
        gate.check_program(r, q_start=np.radians(q[0]))
    assert "j_Q0002," in _line_of(r.text, _refusal_line(ei.value))
    # configured limits may only tighten the robot's
    wide = lim_deg.copy()
    wide[j, 1] += 1.0
    with pytest.raises(ConfigError, match=f"joint_limits_deg\\[{j}\\]"):
        SafetyGate(robot, limits.model_copy(update={"joint_limits_deg": tuple(map(tuple, wide))}))


def test_speed_and_acceleration_caps(rng, robot, iso_poses, limits):
    cap = float(rng.uniform(0.3, 0.9))
    gate = SafetyGate(robot, limits.model_copy(update={"max_speed_frac": cap}))
    ok = iso_pose_program(robot, iso_poses, cycles=2, speed_frac=cap * 0.99)
    gate.check_program(render_rapid(ok))
    over = render_rapid(iso_pose_program(robot, iso_poses, cycles=2, speed_frac=min(1.0, cap * 1.05)))
    with pytest.raises(SafetyError, match="speed .* exceeds the cap") as ei:
        gate.check_program(over)
    assert "MoveL" in _line_of(over.text, _refusal_line(ei.value))
    # TCP speed cap below the rated speed
    v_cap = float(rng.uniform(500, 1500))
    gate = SafetyGate(robot, limits.model_copy(update={"max_tcp_speed_mm_s": v_cap}))
    with pytest.raises(SafetyError, match="TCP speed"):
        gate.check_program(render_rapid(iso_pose_program(robot, iso_poses, cycles=2, speed_frac=1.0)))
    gate.check_program(render_rapid(iso_pose_program(robot, iso_poses, cycles=2, speed_frac=0.99 * v_cap / 2000.0)))
    # acceleration cap
    gate = SafetyGate(robot, limits.model_copy(update={"max_accel_frac": 0.5}))
    with pytest.raises(SafetyError, match="acceleration 100 % exceeds the cap 50 %"):
        gate.check_program(render_rapid(iso_pose_program(robot, iso_poses, cycles=2, accel_frac=1.0)))


def test_fast_joint_move_is_refused_by_its_peak_tcp_speed(gate, robot, iso_poses):
    """A joint move at full speed swings the TCP far faster than the cap."""
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=2, interpolation="joint", speed_frac=1.0))
    with pytest.raises(SafetyError, match="estimated peak TCP speed") as ei:
        gate.check_program(r)
    assert float(re.search(r"speed at most ([0-9.]+) % here", str(ei.value)).group(1)) < 100.0


def test_peak_tcp_speed_estimate_matches_the_planned_joint_move(rng, gate, robot, iso_poses):
    """The estimate is the cruise TCP speed of the synchronised profile the arm plans."""
    from station.models.motion import plan_joint_move

    a, b = rng.choice(list(iso_poses), size=2, replace=False)
    qa = gate.check_cartesian_target(np.array(iso_poses[a]), "a")
    qb = gate.check_cartesian_target(np.array(iso_poses[b]), "b", q_seed=qa)
    frac = float(rng.uniform(0.1, 1.0))
    est = gate.joint_move_peak_tcp_speed(qa, qb, frac)
    assert est == pytest.approx(frac * gate.joint_move_peak_tcp_speed(qa, qb, 1.0), rel=1e-12)
    plan = plan_joint_move(qa, qb, robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2, speed_frac=frac, profile="trapezoid")
    t = np.linspace(0.0, plan.duration_s, 4001)
    q = plan.trajectory.evaluate(t, 0)
    qd = plan.trajectory.evaluate(t, 1)
    jv = kinematics.joint_jacobian(robot.dh_nominal, q)[:, :3, :]
    actual = float(np.max(np.linalg.norm(np.einsum("nij,nj->ni", jv, qd), axis=1)))
    assert actual <= est * (1 + 1e-6)
    # the estimate is the TCP speed at the cruise joint rates, taken over the whole path: where the
    # planned move cruises, its TCP speed is exactly that; elsewhere it is slower (accelerating)
    dq = qb - qa
    qdot_cruise = dq / np.max(np.abs(dq) / (frac * robot.joint_speed_limits_rad_s))
    at_cruise = np.linalg.norm(jv @ qdot_cruise, axis=1)
    cruise = np.max(np.abs(qd) / (frac * robot.joint_speed_limits_rad_s), axis=1) > 0.999
    tcp = np.linalg.norm(np.einsum("nij,nj->ni", jv, qd), axis=1)
    np.testing.assert_allclose(tcp[cruise], at_cruise[cruise], rtol=2e-3)
    # and over the whole path the estimate is the largest of those (the gate samples every 0.5 deg)
    assert est == pytest.approx(float(at_cruise.max()), rel=2e-3)


def test_joint_path_leaving_the_box_is_refused(robot):
    """Both ends inside the box, but the joint-interpolated TCP path swings outside."""
    limits = SafetyLimits(workspace_min_mm=(-600, -2500, 0), workspace_max_mm=(600, 2500, 2500), max_tcp_speed_mm_s=2000)
    gate = SafetyGate(robot, limits)
    q0 = np.degrees(robot.home_q_rad)
    q1 = q0.copy()
    q1[0] -= 180.0  # base turns half a turn: the TCP sweeps around through |x| ~ 1.7 m
    p = Program(
        "SWING",
        robot.name,
        robot.max_tcp_speed_mm_s,
        (Move(JointTarget("A", tuple(q0)), "joint", 0.05), Dwell(0.5), Move(JointTarget("B", tuple(q1)), "joint", 0.05)),
    )
    ends = kinematics.tool_position(robot.dh_nominal, np.radians([q0, q1]))
    assert not np.any(gate._outside_box(ends))
    r = render_rapid(p)
    with pytest.raises(SafetyError, match="path leaves the workspace") as ei:
        gate.check_program(r, q_start=robot.home_q_rad)
    assert "j_B," in _line_of(r.text, _refusal_line(ei.value))


def test_linear_path_through_the_wrist_singularity_is_refused(gate, robot, iso_poses):
    """With the home orientation the P2 -> P3 line passes the wrist singularity (q5 = 0)."""
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=2, orientation=np.array(home_orientation(robot))))
    with pytest.raises(SafetyError, match="singularity") as ei:
        gate.check_program(r)
    assert "MoveL p_P3," in _line_of(r.text, _refusal_line(ei.value))


def test_program_for_another_robot_is_refused(gate, iso_poses):
    from station.models.robots import get_robot

    other = get_robot("ur10e")
    p = Program("X", other.name, other.max_tcp_speed_mm_s, (Move(CartesianTarget("A", (0.0, 500.0, 500.0))),))
    with pytest.raises(SafetyError, match="made for robot 'ur10e'"):
        gate.check_program(p)


def test_single_target_checks(rng, gate, robot):
    q = gate.check_cartesian_target(np.array([0.0, 1700.0, 1400.0]), "probe")
    assert np.allclose(kinematics.tool_position(robot.dh_nominal, q), [0.0, 1700.0, 1400.0], atol=gate.limits.ik_tol_mm)
    with pytest.raises(SafetyError, match="probe: position .* outside"):
        gate.check_cartesian_target(np.array([0.0, 500.0, 1400.0]), "probe")
    with pytest.raises(SafetyError, match="not finite"):
        gate.check_cartesian_target(np.array([0.0, np.nan, 1400.0]), "probe")
    with pytest.raises(SafetyError, match="shape"):
        gate.check_joint_target(np.zeros(5), "probe")
    with pytest.raises(SafetyError, match="speed 150 % exceeds"):
        gate.check_speed("probe", speed_frac=1.5)
    v = float(rng.uniform(2001, 5000))
    with pytest.raises(SafetyError, match="TCP speed"):
        gate.check_speed("probe", tcp_speed_mm_s=v)
    gate.check_speed("probe", speed_frac=1.0, accel_frac=1.0, tcp_speed_mm_s=1999.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"workspace_min_mm": (0, 0, 0), "workspace_max_mm": (0, 1, 1), "max_tcp_speed_mm_s": 100},
        {"workspace_min_mm": (0, 0, 0), "workspace_max_mm": (1, 1, float("nan")), "max_tcp_speed_mm_s": 100},
        {"workspace_min_mm": (0, 0, 0), "workspace_max_mm": (1, 1, 1), "max_tcp_speed_mm_s": -1},
        {"workspace_min_mm": (0, 0, 0), "workspace_max_mm": (1, 1, 1), "max_tcp_speed_mm_s": 1, "max_speed_frac": 1.2},
        {"workspace_min_mm": (0, 0, 0), "workspace_max_mm": (1, 1, 1), "max_tcp_speed_mm_s": 1, "joint_limits_deg": ((0, 1),) * 5},
        {"workspace_min_mm": (0, 0, 0), "workspace_max_mm": (1, 1, 1), "max_tcp_speed_mm_s": 1, "unknown_key": 1},
    ],
)
def test_bad_limits_are_refused(kwargs):
    with pytest.raises(ValidationError):
        SafetyLimits(**kwargs)


def test_single_motion_checks_for_drivers_without_programs(rng, gate, robot, iso_poses):
    """The UR driver gates each URScript move with these."""
    q0 = gate.check_cartesian_target(np.array(iso_poses["P1"]), "p1")
    q1 = gate.check_linear_motion(q0, np.array(iso_poses["P3"]), "movel", speed_mm_s=500.0)
    assert np.allclose(kinematics.tool_position(robot.dh_nominal, q1), iso_poses["P3"], atol=gate.limits.ik_tol_mm)
    with pytest.raises(SafetyError, match="movel: TCP speed"):
        gate.check_linear_motion(q0, np.array(iso_poses["P3"]), "movel", speed_mm_s=2500.0)
    with pytest.raises(SafetyError, match="movej: .*outside the workspace"):
        gate.check_joint_motion(q0, np.array([0.0, 900.0, 1400.0]), "movej", speed_frac=0.1)
    q2 = gate.check_joint_motion(q0, q1, "movej", speed_frac=0.05)
    assert np.allclose(q2, q1)
    # joint speeds in rad/s against the robot's limits times the speed cap
    lim = robot.joint_speed_limits_rad_s
    j = int(rng.integers(0, 6))
    v = 0.5 * lim.copy()
    gate.check_speed("speedj", joint_speed_rad_s=v)
    v[j] = lim[j] * 1.01
    with pytest.raises(SafetyError, match=f"joint speed of joint {j + 1}"):
        gate.check_speed("speedj", joint_speed_rad_s=v)
    with pytest.raises(SafetyError, match="joint speed"):
        gate.check_speed("movej", joint_speed_rad_s=float(lim.min()) * 1.01)
    with pytest.raises(SafetyError, match="joint acceleration"):
        gate.check_speed("movej", joint_accel_rad_s2=float(robot.joint_accel_limits_rad_s2.min()) * 1.5)


def test_a_program_checked_again_reuses_the_solved_kinematics_bit_for_bit(gate, robot, iso_poses, monkeypatch):
    """The gate keeps what it solved: a station checks every cycle's program again from the same joints."""
    import station.safety as safety

    monkeypatch.setattr(safety, "_IK_MEMO", type(safety._IK_MEMO)())
    calls = []
    real_ik = kinematics.ik
    monkeypatch.setattr(safety.kinematics, "ik", lambda *a, **k: calls.append(1) or real_ik(*a, **k))
    r = render_rapid(iso_pose_program(robot, iso_poses, cycles=2))
    first = gate.check_program(r)
    n_first = len(calls)
    assert n_first > 0
    again = gate.check_program(r)
    assert len(calls) == n_first
    # what a caller does with the joints it was given does not reach the memo
    target = np.array(iso_poses["P3"], dtype=float)
    q = gate.check_cartesian_target(target, "P3")
    kept = q.copy()
    q[:] = np.nan
    assert np.array_equal(gate.check_cartesian_target(target, "P3"), kept)
    fresh = SafetyGate(robot, gate.limits)
    monkeypatch.setattr(safety, "_IK_MEMO", type(safety._IK_MEMO)())
    solved = fresh.check_program(r)
    assert np.array_equal(again.q_rad, solved.q_rad) and np.array_equal(again.tcp_mm, solved.tcp_mm)
    # another start is another problem
    gate.check_program(r, q_start=again.q_rad[1])
    assert len(calls) > n_first + 2
