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
