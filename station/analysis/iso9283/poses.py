"""ISO 9283 test poses from the test cube (seed 000, section 2.1-2.2).

The cube has edges parallel to the robot base frame and corners labelled as in
seed 000 Table 1::

    C1 (xmax, ymax, zmax)   C5 (xmax, ymax, zmin)
    C2 (xmax, ymin, zmax)   C6 (xmax, ymin, zmin)
    C3 (xmin, ymin, zmax)   C7 (xmin, ymin, zmin)
    C4 (xmin, ymax, zmax)   C8 (xmin, ymax, zmin)

The five commanded poses lie in the measuring plane C4-C1-C6-C7 (a diagonal
plane of the cube): P1 is the cube centre (the crossing of the plane's
diagonals C4-C6 and C1-C7); P2, P3, P4, P5 lie on those diagonals, moved from
the corners C4, C1, C6, C7 towards the centre, at (10 +/- 2) % of the
diagonal's length from the corner.  The seed moves each corner by 100 mm along
x, y and z, which for the 1200 mm cube of Table 1 is 8.33 % of the diagonal
and gives Table 2 exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import ConfigError

#: seed 000 Table 1, corners C1..C8 of the NACHI 8608 test cube, mm (base frame)
TABLE1_CORNERS_MM: tuple[tuple[float, float, float], ...] = (
    (600.0, 2300.0, 2000.0),
    (600.0, 1100.0, 2000.0),
    (-600.0, 1100.0, 2000.0),
    (-600.0, 2300.0, 2000.0),
    (600.0, 2300.0, 800.0),
    (600.0, 1100.0, 800.0),
    (-600.0, 1100.0, 800.0),
    (-600.0, 2300.0, 800.0),
)

#: seed 000 Table 2, commanded poses P1..P5, mm
TABLE2_POSES_MM: tuple[tuple[float, float, float], ...] = (
    (0.0, 1700.0, 1400.0),
    (-500.0, 2200.0, 1900.0),
    (500.0, 2200.0, 1900.0),
    (500.0, 1200.0, 900.0),
    (-500.0, 1200.0, 900.0),
)

#: corner (0-based index into C1..C8) from which P2, P3, P4, P5 are inset
_CORNER_OF_POSE = (3, 0, 5, 6)  # C4, C1, C6, C7
#: sign pattern of each corner relative to the cube centre, C1..C8
_CORNER_SIGNS = np.array(
    [
        [+1, +1, +1],
        [+1, -1, +1],
        [-1, -1, +1],
        [-1, +1, +1],
        [+1, +1, -1],
        [+1, -1, -1],
        [-1, -1, -1],
        [-1, +1, -1],
    ],
    dtype=float,
)


@dataclass(frozen=True)
class TestPoses:
    """Commanded test poses P1..P5 of ISO 9283 (seed 000 Table 2).

    Attributes
    ----------
    names : tuple of str
        ``("P1", "P2", "P3", "P4", "P5")``.
    positions_mm : ndarray, shape (5, 3)
        Commanded positions in the cube's (base) frame, mm.
    fraction_of_diagonal : ndarray, shape (4,)
        Distance of P2..P5 from their corner (C4, C1, C6, C7) as a fraction of
        the diagonal's length (the (10 +/- 2) % rule).
    corners_mm : ndarray, shape (8, 3)
        The cube corners C1..C8 the poses came from.
    inset_mm : ndarray, shape (3,)
        The per-axis move from the corner towards the centre.
    """

    __test__ = False  # not a pytest test class despite the name

    names: tuple[str, ...]
    positions_mm: np.ndarray
    fraction_of_diagonal: np.ndarray
    corners_mm: np.ndarray
    inset_mm: np.ndarray

    def as_rows(self) -> list[tuple[str, float, float, float]]:
        """``[(name, x_mm, y_mm, z_mm), ...]`` for a ``name,x,y,z`` poses file."""
        return [(n, *map(float, p)) for n, p in zip(self.names, self.positions_mm)]


def cube_test_poses(
    corners_mm,
    inset_mm=100.0,
    *,
    fraction_range: tuple[float, float] = (0.08, 0.12),
    rel_tol: float = 1e-9,
) -> TestPoses:
    """Commanded poses P1..P5 from the test cube (seed 000 section 2.2).

    Parameters
    ----------
    corners_mm : array_like, shape (8, 3)
        Corners C1..C8 in the order and labelling of seed 000 Table 1, mm.
        They must form a cube with edges parallel to the base frame.
    inset_mm : float or array_like, shape (3,)
        Move of each corner towards the centre along x, y and z, mm (the seed
        uses 100 mm).  The moved point must stay on the plane's diagonal.
    fraction_range : (float, float)
        Allowed distance from the corner as a fraction of the diagonal,
        default (0.08, 0.12) = (10 +/- 2) %.
    rel_tol : float
        Relative tolerance for the cube shape and the on-diagonal check.

    Returns
    -------
    TestPoses

    Raises
    ------
    ConfigError
        The corners are not an axis-parallel cube labelled as in Table 1, the
        inset leaves the diagonal, or it breaks the (10 +/- 2) % rule.
    """
    c = np.asarray(corners_mm, dtype=float)
    if c.shape != (8, 3):
        raise ConfigError(f"corners_mm must have shape (8, 3) (C1..C8 x xyz), got {c.shape}")
    if not np.all(np.isfinite(c)):
        bad = np.argwhere(~np.isfinite(c))[0]
        raise ConfigError(f"corners_mm: C{bad[0] + 1} {'xyz'[bad[1]]} is not finite")
    lo, hi = c.min(axis=0), c.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    edge = hi - lo
    scale = float(max(edge.max(), 1.0))
    if np.any(edge <= rel_tol * scale):
        raise ConfigError(f"corners_mm: the cube is degenerate (edges {edge.tolist()} mm)")
    expected = centre + _CORNER_SIGNS * half
    err = np.abs(c - expected).max(axis=1)
    if np.any(err > rel_tol * scale):
        k = int(np.argmax(err))
        raise ConfigError(
            f"corners_mm: C{k + 1} = {c[k].tolist()} is not the corner expected for an "
            f"axis-parallel cube labelled as in seed 000 Table 1 (expected {expected[k].tolist()})"
        )
    if np.ptp(edge) > rel_tol * scale:
        raise ConfigError(
            f"corners_mm: not a cube, edge lengths x, y, z = {edge.tolist()} mm differ"
        )

    inset = np.broadcast_to(np.asarray(inset_mm, dtype=float), (3,)).copy()
    if not np.all(np.isfinite(inset)) or np.any(inset <= 0):
        raise ConfigError(f"inset_mm must be finite and > 0 per axis, got {inset.tolist()}")
    lo_f, hi_f = fraction_range
    if not (0 < lo_f < hi_f < 0.5):
        raise ConfigError(f"fraction_range must satisfy 0 < low < high < 0.5, got {fraction_range}")

    corners = c[list(_CORNER_OF_POSE)]  # (4, 3)
    towards = -_CORNER_SIGNS[list(_CORNER_OF_POSE)]  # unit signs pointing at the centre
    poses = corners + towards * inset
    diag_vec = 2.0 * half * towards  # corner -> opposite corner of the plane
    diag_len = float(np.linalg.norm(diag_vec[0]))
    move = poses - corners
    # on the diagonal: the move must be parallel to the diagonal direction
    cross = np.linalg.norm(np.cross(move, diag_vec), axis=1) / diag_len
    if np.any(cross > rel_tol * scale):
        raise ConfigError(
            f"inset_mm {inset.tolist()} moves the corners off the diagonals of the measuring "
            f"plane C4-C1-C6-C7 (off by {cross.max():.3g} mm); use an inset proportional to "
            f"the cube's edges"
        )
    frac = np.linalg.norm(move, axis=1) / diag_len
    if np.any(frac < lo_f * (1 - rel_tol)) or np.any(frac > hi_f * (1 + rel_tol)):
        raise ConfigError(
            f"inset_mm {inset.tolist()} puts P2..P5 at {100 * frac[0]:.2f} % of the diagonal "
            f"({diag_len:.1f} mm) from the corners; ISO 9283 requires "
            f"{100 * lo_f:.0f}..{100 * hi_f:.0f} % (10 +/- 2 %)"
        )
    positions = np.vstack([centre, poses])
    return TestPoses(
        names=("P1", "P2", "P3", "P4", "P5"),
        positions_mm=positions,
        fraction_of_diagonal=frac,
        corners_mm=c.copy(),
        inset_mm=inset,
    )


#: the arm the seed's cube (Table 1) was laid out for; the station's stand-in for the NACHI 8608
TABLE1_ROBOT = "industrial-3100"


def span_mm(dh) -> float:
    """An arm's span from its DH table: the sum of every link length and offset, ``sum |a| + |d|`` (mm).

    Not the reach to a point, but a length that scales with the arm: two arms
    of the same shape and different size have spans in the ratio of their sizes.
    """
    dh = np.asarray(dh, dtype=float)
    return float(np.sum(np.abs(dh[:, 0])) + np.sum(np.abs(dh[:, 2])))


@dataclass(frozen=True)
class ScaledCube:
    """Seed 000 Table 1 placed in another arm's workspace (see :func:`cube_for_robot`).

    Attributes
    ----------
    corners_mm : ndarray, shape (8, 3)
        C1..C8 in that arm's base frame.
    inset_mm : float
        The corner-to-pose move of sec. 2.2 scaled alike (P2..P5 stay at 8.33 % of the diagonal).
    scale : float
        Span of the arm / span of the Table 1 arm (1 for that arm: Table 1 and Table 2 exactly).
    """

    corners_mm: np.ndarray
    inset_mm: float
    scale: float
    approach_mm: float = 100.0


def cube_for_robot(dh, inset_mm: float = 100.0, *, home_q_rad=None, reference_dh=None) -> ScaledCube:
    """Seed 000 Table 1 -> Table 2 applied to an arm's reach.

    The seed's cube (1200 mm edge, centre (0, 1700, 1400) mm, in front of the
    arm along +y) and its 100 mm inset are scaled about the base origin by the
    ratio of the arm's span to the span of the arm the table was laid out for
    (:data:`TABLE1_ROBOT`, ``reference_dh``), so the cube keeps its share of
    the reach and the poses of Table 2 their 8.33 % of the diagonal. With
    ``home_q_rad`` the cube is then turned about the base z axis by the
    multiple of 90 deg that puts it in front of the arm as it stands at home
    (the azimuth of its home TCP; +y for the Table 1 arm), so its edges stay
    parallel to the base axes (sec. 2.1) and the corners are labelled C1..C8
    as in Table 1 again. For the Table 1 arm the seed's numbers come back
    exactly. Whether every pose is reachable is the safety gate's question
    (it solves each target before anything moves).
    """
    if reference_dh is None:
        from station.models.robots import get_robot

        reference_dh = get_robot(TABLE1_ROBOT).dh_nominal
    scale = span_mm(dh) / span_mm(reference_dh)
    if not (math.isfinite(scale) and scale > 0):
        raise ConfigError(f"cannot scale the test cube: span ratio {scale!r}")
    if abs(scale - 1.0) < 1e-12:
        scale = 1.0
    corners = np.asarray(TABLE1_CORNERS_MM, dtype=float) * scale
    turns = 0
    if home_q_rad is not None:
        from station.models import kinematics

        p = kinematics.fk(np.asarray(dh, dtype=float), np.asarray(home_q_rad, dtype=float))[:3, 3]
        azimuth = math.degrees(math.atan2(p[1], p[0]))
        turns = int(round((azimuth - 90.0) / 90.0)) % 4
    for _ in range(turns):  # a quarter turn about z: (x, y) -> (-y, x)
        corners = np.column_stack([-corners[:, 1], corners[:, 0], corners[:, 2]])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    corners = 0.5 * (lo + hi) + _CORNER_SIGNS * 0.5 * (hi - lo)
    return ScaledCube(corners_mm=corners, inset_mm=float(inset_mm) * scale, scale=scale, approach_mm=100.0 * scale)


#: how far inside the workspace box :func:`fit_cube_to_reach` keeps every commanded point, mm
BOX_CLEARANCE_MM = 1.0


def fit_cube_to_reach(dh, joint_limits_rad, home_q_rad, tool_rotation, *, inset_mm: float = 100.0,
                      approach_mm: float = 100.0, vap_poses=("P1", "P2", "P4"), shrink: float = 0.95,
                      max_shrinks: int = 20, box_min_mm=None, box_max_mm=None,
                      first_shrinks: int = 0) -> ScaledCube:
    """:func:`cube_for_robot`, shrunk about its centre until the arm reaches every point the ISO 9283
    procedure commands with the tool held at ``tool_rotation`` (3, 3).

    Checked by the nominal inverse kinematics from the home pose: the five
    poses of sec. 2.2, the inset corners (the best-fit registration) and the
    vAP pre-points ``pose - approach * d`` for d along +x, +y, +z (sec. 3.3),
    the approach scaled with the cube. Each shrink multiplies the edge and the
    inset by ``shrink`` (P2..P5 keep their 8.33 % of the diagonal), so the cube
    is the largest of the seed's shape and place the arm reaches (sec. 2.1:
    the largest volume allowed). The arm the table was laid out for gets
    Table 1 unchanged. ConfigError after ``max_shrinks``.

    ``box_min_mm``/``box_max_mm`` (3,): the safety gate's workspace box. Every
    commanded point must also lie inside it: the cube is moved into the box
    where its points fit (the least move) and shrunk where they do not, so a
    plan is never laid out for a place the gate will refuse. ``first_shrinks``:
    start that many shrinks smaller (a caller whose own check of the laid-out
    paths refused the larger cube).
    """
    from station.models import kinematics

    cube = cube_for_robot(dh, inset_mm, home_q_rad=home_q_rad)
    approach = float(approach_mm) * cube.scale
    R = np.asarray(tool_rotation, dtype=float)
    corners, inset = cube.corners_mm, cube.inset_mm
    centre0 = corners.mean(axis=0)
    corners = centre0 + shrink ** first_shrinks * (corners - centre0)
    inset *= shrink ** first_shrinks
    # a point on the box's face may round outside it in a program's text: keep BOX_CLEARANCE_MM inside
    box = None if box_min_mm is None or box_max_mm is None else (
        np.asarray(box_min_mm, dtype=float) + BOX_CLEARANCE_MM, np.asarray(box_max_mm, dtype=float) - BOX_CLEARANCE_MM)

    def commanded_points(corners, inset):
        tp = cube_test_poses(corners, inset_mm=inset)
        centre = corners.mean(axis=0)
        points = [tp.positions_mm, corners - np.sign(corners - centre) * inset]
        for name in vap_poses:
            p = tp.positions_mm[tp.names.index(name)]
            points.append(p - approach * np.eye(3))
        return np.vstack(points)

    for _ in range(max_shrinks + 1):
        pts = commanded_points(corners, inset)
        centre = corners.mean(axis=0)
        if box is not None:
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            if np.any(hi - lo > box[1] - box[0]):  # larger than the box: smaller first
                corners = centre + shrink * (corners - centre)
                inset *= shrink
                approach *= shrink
                continue
            move = np.maximum(box[0] - lo, 0.0) + np.minimum(box[1] - hi, 0.0)  # the least move into it
            corners, pts = corners + move, pts + move
            centre = corners.mean(axis=0)
        T = np.repeat(np.eye(4)[None], len(pts), axis=0)
        T[:, :3, :3] = R
        T[:, :3, 3] = pts
        first = kinematics.ik(dh, T[:1], home_q_rad, joint_limits_rad)
        if first.all_success:
            sol = kinematics.ik(dh, T, first.q_rad[0], joint_limits_rad)
            if sol.all_success:
                return ScaledCube(corners_mm=corners, inset_mm=inset, scale=cube.scale, approach_mm=approach)
        corners = centre + shrink * (corners - centre)
        inset *= shrink
    where = " inside the workspace box" if box is not None else ""
    raise ConfigError(f"no test cube of the seed's shape in front of this arm is reachable{where} with the tool "
                      f"orientation given (shrunk {max_shrinks} times by {shrink})")
