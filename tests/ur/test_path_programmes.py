"""A path programme on the UR fake over its real protocols: the driver gates and sends movel with r and movec,
the fake blends the run (the corner rounded by the radius) and follows the circle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fakes.urscript import parse_program
from station.models import kinematics
from station.models.cartesian_path import circle_through
from station.programs.path_builders import iso_path_tests


def test_blended_rectangle_and_circle_on_the_ur(world, fake, make_driver, rng):
    d = make_driver(fake)
    robot = world.robot
    centre = kinematics.tool_position(robot.dh_nominal, robot.home_q_rad)
    rot = kinematics.fk(robot.dh_nominal, robot.home_q_rad)[:3, :3]
    blend = float(np.round(rng.uniform(5.0, 20.0), 3))
    side = float(rng.uniform(150.0, 220.0))
    tests = {t.kind: t for t in iso_path_tests(robot, centre, side, cycles=1, speed_fracs=(0.1,),
                                               kinds=("rectangle_blend", "circle_large"), blend_mm=blend,
                                               orientation=rot)}
    arm = world.arm
    pt = tests["rectangle_blend"]
    st = d.run(pt.program, timeout_s=120.0)
    assert st.moves_done == 5 and st.cycle_count == 1
    script = parse_program(fake.scripts_received[-1])
    rs = [c.kwargs.get("r") for c in script.statements if c.name == "movel"]
    assert rs[3:] == [None] and rs[:3] == pytest.approx([blend / 1000.0] * 3)  # the last corner stops
    run = arm.moves[-1] if arm.moves[-1].kind != "settle" else arm.moves[-2]
    t = np.linspace(run.t_start, run.t_end, 4000)
    p = kinematics.tool_position(robot.dh_nominal, arm.commanded_q_rad(t))
    corner = np.asarray(pt.path["corners_mm"][2])
    assert np.min(np.linalg.norm(p - corner, axis=1)) == pytest.approx(blend / (2 * math.sqrt(2)), rel=0.01, abs=0.02)
    pc = tests["circle_large"]
    d.run(pc.program, timeout_s=120.0)
    assert sum(c.name == "movec" for c in parse_program(fake.scripts_received[-1]).statements) == 2
    run = arm.moves[-1] if arm.moves[-1].kind != "settle" else arm.moves[-2]
    t = np.linspace(run.t_start, run.t_end, 4000)
    p = kinematics.tool_position(robot.dh_nominal, arm.commanded_q_rad(t))
    c, r, u, w = circle_through(*np.asarray(pc.path["points_mm"]))
    n = np.cross(u, w)
    rel = p - c
    assert np.max(np.abs(np.linalg.norm(rel - np.outer(rel @ n, n), axis=1) - r)) < 0.01
    assert np.max(np.abs(rel @ n)) < 0.01
    ang = np.unwrap(np.arctan2(rel @ w, rel @ u))
    assert abs(ang[-1] - ang[0]) == pytest.approx(2 * math.pi, abs=1e-3)  # the whole circle in one run
