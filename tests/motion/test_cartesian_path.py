"""The controller's path interpolator (station.models.cartesian_path): circles through three points, corner
zones, the speed profile and its ripple, the joint knots."""

from __future__ import annotations

import math

import numpy as np
import pytest

from station.errors import DataError
from station.models import kinematics as kin
from station.models.cartesian_path import Ripple, Segment, arc_points, circle_through, plan_path, solve_knots
from station.models.robots import get_robot


def _pose(p):
    T = np.eye(4)
    T[:3, 3] = p
    return T


def _frame(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q


def test_circle_through_three_points_and_the_arc_that_passes_the_middle_one(rng):
    R = _frame(rng)
    c, r = rng.uniform(-500, 500, 3), rng.uniform(10, 400)
    a = np.sort(rng.uniform(0, 2 * np.pi, 3))
    p = [c + r * (math.cos(x) * R[:, 0] + math.sin(x) * R[:, 1]) for x in a]
    c2, r2, _, _ = circle_through(*p)
    assert np.allclose(c2, c, atol=1e-6) and r2 == pytest.approx(r, rel=1e-9)
    pts = arc_points(p[0], p[1], p[2], 2001)
    assert np.allclose(pts[0], p[0]) and np.allclose(pts[-1], p[2], atol=1e-9)
    assert np.min(np.linalg.norm(pts - p[1], axis=1)) < 2 * r * (a[2] - a[0]) / 2000  # it passes the via point
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
    assert step == pytest.approx(r * (a[2] - a[0]), rel=1e-5)
    with pytest.raises(DataError, match="on one line"):
        circle_through(c, c + R[:, 0], c + 2 * R[:, 0])


def test_a_zone_rounds_the_corner_and_the_profile_runs_from_rest_to_rest(rng):
    R = _frame(rng)
    turn = rng.uniform(math.radians(20), math.radians(160))
    # speeds the legs can reach: 200 mm holds the ramp up to v and down to a sharp corner's speed at 3000 mm/s^2
    # (v^2 / a <= 200 - 30 mm: v <= 714 mm/s; at 768 mm/s the cruise peaked at 693, CI seed 2368088325)
    zone, v = rng.uniform(2.0, 30.0), rng.uniform(100.0, 650.0)
    d1, d2 = R[:, 0], math.cos(turn) * R[:, 0] + math.sin(turn) * R[:, 1]
    corner = rng.uniform(-300, 300, 3)
    start, end = corner - 200.0 * d1, corner + 200.0 * d2
    plan = plan_path(_pose(start), [Segment(_pose(corner), v, zone), Segment(_pose(end), v)], accel_mm_s2=3000.0,
                     ipo_period_s=0.0005, ripple=Ripple(0.0))
    xyz = plan.poses[:, :3, 3]
    # a quadratic Bezier from zone before to zone after the corner: its midpoint is zone |d2 - d1| / 4 from it
    # (the interpolator walks a polyline of it with 0.25 mm steps: chords a few um inside)
    assert np.min(np.linalg.norm(xyz - corner, axis=1)) == pytest.approx(zone * np.linalg.norm(d2 - d1) / 4,
                                                                          rel=1e-3, abs=5e-3)
    assert np.allclose(xyz[0], start) and np.allclose(xyz[-1], end)
    speed = np.linalg.norm(np.diff(xyz, axis=0), axis=1) / np.diff(plan.t_knots)
    assert speed.max() == pytest.approx(v, rel=0.01) and speed[0] < 0.05 * v and speed[-1] < 0.05 * v
    # without the zone the path goes through the corner
    sharp = plan_path(_pose(start), [Segment(_pose(corner), v, 0.0), Segment(_pose(end), v)], accel_mm_s2=3000.0,
                      ipo_period_s=0.0005)
    assert np.min(np.linalg.norm(sharp.poses[:, :3, 3] - corner, axis=1)) < 0.05


def test_the_ripple_modulates_the_cruise_speed(rng):
    amp, f = rng.uniform(0.002, 0.02), rng.uniform(2.0, 9.0)
    L, v = 2000.0, 500.0
    plan = plan_path(_pose([0, 0, 0]), [Segment(_pose([L, 0, 0]), v)], accel_mm_s2=4000.0, ipo_period_s=0.001,
                     ripple=Ripple(amp, f, rng.uniform(0, 2 * np.pi)))
    t = 0.5 * (plan.t_knots[1:] + plan.t_knots[:-1])
    speed = np.diff(plan.poses[:, 0, 3]) / np.diff(plan.t_knots)
    mid = (plan.s_knots[1:] > 0.2 * L) & (plan.s_knots[1:] < 0.8 * L)
    X = np.column_stack([np.ones(mid.sum()), np.sin(2 * np.pi * f * t[mid]), np.cos(2 * np.pi * f * t[mid])])
    c = np.linalg.lstsq(X, speed[mid], rcond=None)[0]
    assert c[0] == pytest.approx(v, rel=2e-3) and math.hypot(c[1], c[2]) / c[0] == pytest.approx(amp, rel=0.05)


def test_joint_knots_follow_the_path_and_an_unreachable_path_is_refused():
    robot = get_robot("industrial-3100")
    T0 = kin.fk(robot.dh_nominal, robot.home_q_rad)
    p0 = T0[:3, 3]
    T1 = T0.copy()
    T1[:3, 3] = p0 + [150.0, 0.0, -100.0]
    plan = plan_path(T0, [Segment(T1, 300.0)], accel_mm_s2=3000.0)
    t, q, _ = solve_knots(robot.dh_nominal, robot.home_q_rad, plan, robot.joint_limits_rad,
                          robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2)
    assert np.allclose(kin.tool_position(robot.dh_nominal, q), plan.poses[:, :3, 3], atol=1e-3)
    far = T0.copy()
    far[:3, 3] = p0 + [0.0, 0.0, 1e4]
    with pytest.raises(DataError, match="reachable"):
        solve_knots(robot.dh_nominal, robot.home_q_rad, plan_path(T0, [Segment(far, 300.0)], accel_mm_s2=3000.0),
                    robot.joint_limits_rad, robot.joint_speed_limits_rad_s, robot.joint_accel_limits_rad_s2)


def test_a_blended_run_that_only_turns_the_tool_is_refused_by_name(rng):
    """A run whose moves all keep the tool point has no path to round or time: refused (the fine moves that only
    turn are the linear move planner's, station.models.motion)."""
    p = rng.uniform(-500, 500, 3)
    turned = _pose(p)
    turned[:3, :3] = _frame(rng)
    if np.linalg.det(turned[:3, :3]) < 0:  # a rotation, not a reflection
        turned[:3, 0] *= -1.0
    with pytest.raises(DataError, match="does not move the tool point"):
        plan_path(_pose(p), [Segment(turned, 100.0, 5.0), Segment(_pose(p), 100.0)], accel_mm_s2=1000.0)
