"""Test poses from the cube (seed 000 section 2.2, Tables 1-2)."""

from __future__ import annotations

import numpy as np
import pytest

from station.analysis.iso9283.poses import TABLE1_CORNERS_MM, TABLE2_POSES_MM, cube_test_poses
from station.errors import ConfigError

SIGNS = np.array([[1, 1, 1], [1, -1, 1], [-1, -1, 1], [-1, 1, 1], [1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1]])


def cube(centre, edge):
    return np.asarray(centre, float) + 0.5 * edge * SIGNS


def test_table2_exactly_from_table1_and_100mm():
    tp = cube_test_poses(TABLE1_CORNERS_MM, 100.0)
    assert tp.names == ("P1", "P2", "P3", "P4", "P5")
    assert np.array_equal(tp.positions_mm, np.array(TABLE2_POSES_MM))
    # 100 mm per axis is 8.33 % of the 2078 mm diagonal (seed 2.2)
    assert np.allclose(tp.fraction_of_diagonal, 100 * np.sqrt(3) / (1200 * np.sqrt(3)))
    assert round(100 * tp.fraction_of_diagonal[0], 2) == 8.33
    assert tp.as_rows()[1] == ("P2", -500.0, 2200.0, 1900.0)


def test_random_cube_geometry(rng):
    edge = rng.uniform(200, 2000)
    centre = rng.uniform(-1000, 1000, 3)
    frac = rng.uniform(0.081, 0.119)
    inset = frac * edge  # per axis: |move| = sqrt(3) inset, diagonal = sqrt(3) edge
    tp = cube_test_poses(cube(centre, edge), inset)
    P = tp.positions_mm
    assert np.allclose(P[0], centre)
    assert np.allclose(tp.fraction_of_diagonal, frac)
    # P2..P5 on the diagonals C4-C6 and C1-C7 of the plane, symmetric about P1
    c = cube(centre, edge)
    for k, (corner, opposite) in enumerate([(3, 5), (0, 6), (5, 3), (6, 0)]):
        d = c[opposite] - c[corner]
        v = P[k + 1] - c[corner]
        assert np.linalg.norm(np.cross(v, d)) < 1e-9 * edge**2
        assert np.dot(v, d) > 0
    assert np.allclose(P[1] + P[3], 2 * centre) and np.allclose(P[2] + P[4], 2 * centre)


@pytest.mark.parametrize("inset", [50.0, 60.0, 160.0, 250.0])
def test_refuses_inset_outside_10_pm_2_percent(inset):
    with pytest.raises(ConfigError, match=r"10 \+/- 2"):
        cube_test_poses(TABLE1_CORNERS_MM, inset)


def test_rule_boundary(rng):
    edge = rng.uniform(300, 1500)
    c = cube(rng.uniform(-500, 500, 3), edge)
    cube_test_poses(c, 0.0805 * edge)
    cube_test_poses(c, 0.1195 * edge)
    with pytest.raises(ConfigError):
        cube_test_poses(c, 0.0795 * edge)
    with pytest.raises(ConfigError):
        cube_test_poses(c, 0.1205 * edge)


def test_refuses_bad_cubes():
    c = np.array(TABLE1_CORNERS_MM)
    box = c.copy()
    box[:, 1] = np.where(box[:, 1] > 1700, 2200.0, 1100.0)  # 1200 x 1100 x 1200
    with pytest.raises(ConfigError, match="not a cube"):
        cube_test_poses(box, 100.0)
    swapped = c[[1, 0, 2, 3, 4, 5, 6, 7]]
    with pytest.raises(ConfigError, match="C1"):
        cube_test_poses(swapped, 100.0)
    a = np.radians(10)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    with pytest.raises(ConfigError, match="axis-parallel"):
        cube_test_poses((c - c.mean(0)) @ rot.T + c.mean(0), 100.0)
    with pytest.raises(ConfigError, match="shape"):
        cube_test_poses(c[:7], 100.0)
    bad = c.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ConfigError, match="C3 y"):
        cube_test_poses(bad, 100.0)
    with pytest.raises(ConfigError, match="off the diagonals"):
        cube_test_poses(c, [100.0, 90.0, 100.0])
    with pytest.raises(ConfigError, match="inset_mm"):
        cube_test_poses(c, -100.0)


def test_the_ur_cube_is_laid_out_inside_the_configured_workspace_box(rng):
    """A UR5e whose config gives a safety box of its own (drawn about the home TCP, 150-700 mm each way: the old layout was refused for 16 of 40 such boxes, the fitted one for none):
    the plan's cube, registration points and vAP approaches lie inside it, and the gate passes every
    pose and vAP program (before, a +-700 mm box refused an approach at x = -718 mm at preflight)."""
    from pathlib import Path

    from fakes.cells import demo_config
    from procedures.iso9283 import cycle_program, plan_from_config
    from station.config import config_from_dict
    from station.models import kinematics
    from station.models.robots import get_robot

    robot = get_robot("ur5e")
    home = kinematics.tool_position(robot.dh_nominal, robot.home_q_rad)
    lo, hi = home - rng.uniform(150.0, 700.0, 3), home + rng.uniform(150.0, 700.0, 3)
    d = demo_config(Path("unused"), cycles=3, vap_cycles=2, rate_hz=100.0, robot="ur5e")
    d["robots"]["r1"]["workspace"].update(min_mm=lo.tolist(), max_mm=hi.tolist())
    plan = plan_from_config(config_from_dict(d, "a UR5e in its own box"))
    pts = np.vstack([list(plan.poses_mm.values()), list(plan.registration_mm.values())]
                    + [np.asarray(plan.poses_mm[n]) - plan.vap_offset_mm * np.eye(3) for n in ("P1", "P2", "P4")])
    assert np.all(pts >= lo - 1e-6) and np.all(pts <= hi + 1e-6), (lo, hi)
    gate = plan.gate()
    for kind in ("pose cycle", "vAP cycle"):
        gate.check_program(cycle_program(plan, kind, 1).program, q_start=None)  # SafetyError if refused
