"""The three-plane corner jig of seed 002 section 2, as pure geometry.

The jig is a triangular pyramid cut from the corner of a cube (seed 002
Fig. 1): three mutually perpendicular right-isosceles faces meet at the
corner, and the cut through the three neighbouring cube vertices is the
equilateral base. The **feature point** is the corner, the intersection of
the three perpendicular planes (seed 002 eq. (2)).

Frames
------
In the jig's own cube frame the corner is the origin and the three edges run
along ``+x, +y, +z`` with length ``edge_mm``. In the tool frame the corner sits
at ``vertex_tool_mm`` (default the TCP, so the TCP *is* the feature point, as
in seed 002 where the tool offset is the jig's length) and the cube diagonal
``(1, 1, 1)/sqrt(3)`` points back to the flange (``-z`` of the tool): the
base is mounted on the flange and the corner points away from it. The edges
are spread at 120 deg around the tool axis, the first in the tool's x-z plane,
then turned by ``roll_rad`` about the tool z axis.

Faces (index: name, outward normal):
``0, 1, 2``: the corner faces opposite edge ``k`` (normal ``-e_k``);
``3``: the base (normal ``(e1 + e2 + e3)/sqrt(3)`` = ``-z`` tool, towards the flange).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import ConfigError, DataError

__all__ = ["CornerJig", "plane_intersection", "transform_points", "sample_triangles", "point_plane_distance"]

#: index of the base (mounting) face
BASE_FACE = 3


def transform_points(T, points) -> np.ndarray:
    """Apply a homogeneous transform (4, 4) to points (N, 3)."""
    T = np.asarray(T, dtype=float)
    p = np.asarray(points, dtype=float)
    return p @ T[:3, :3].T + T[:3, 3]


@dataclass(frozen=True)
class CornerJig:
    """Geometry of the corner jig in the tool frame.

    Parameters
    ----------
    edge_mm : float
        Length of the three perpendicular edges (> 0).
    vertex_tool_mm : array_like, shape (3,)
        The corner (feature point) in the tool frame, mm.
    roll_rad : float
        Rotation of the jig about the tool z axis.
    """

    edge_mm: float = 60.0
    vertex_tool_mm: tuple = (0.0, 0.0, 0.0)
    roll_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.edge_mm, (int, float)) and math.isfinite(self.edge_mm) and self.edge_mm > 0):
            raise ConfigError(f"`edge_mm` must be a finite number > 0, got {self.edge_mm!r}")
        v = np.asarray(self.vertex_tool_mm, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ConfigError(f"`vertex_tool_mm` must be 3 finite numbers, got {self.vertex_tool_mm!r}")
        object.__setattr__(self, "vertex_tool_mm", tuple(float(x) for x in v))
        if not math.isfinite(self.roll_rad):
            raise ConfigError(f"`roll_rad` must be finite, got {self.roll_rad!r}")

    @property
    def edge_dirs_tool(self) -> np.ndarray:
        """Unit edge directions ``e_1, e_2, e_3`` as rows (3, 3), right-handed."""
        h = math.sqrt(2.0 / 3.0)
        z = -1.0 / math.sqrt(3.0)
        phi = self.roll_rad + np.array([0.0, 2.0, 4.0]) * np.pi / 3.0
        E = np.stack([h * np.cos(phi), h * np.sin(phi), np.full(3, z)], axis=1)
        if np.linalg.det(E) < 0:
            E = E[[0, 2, 1]]
        return E

    @property
    def feature_point_tool_mm(self) -> np.ndarray:
        """The corner, intersection of the three perpendicular planes (3,)."""
        return np.array(self.vertex_tool_mm)

    @property
    def vertices_tool_mm(self) -> np.ndarray:
        """Corner then the three edge ends (4, 3)."""
        v = self.feature_point_tool_mm
        return np.concatenate([v[None], v + self.edge_mm * self.edge_dirs_tool])

    @property
    def face_triangles_tool_mm(self) -> np.ndarray:
        """Triangles (4, 3, 3): faces 0-2 (opposite edge k), face 3 the base."""
        V = self.vertices_tool_mm
        return np.stack([V[[0, 2, 3]], V[[0, 3, 1]], V[[0, 1, 2]], V[[1, 3, 2]]])

    @property
    def face_normals_tool(self) -> np.ndarray:
        """Outward unit normals (4, 3)."""
        E = self.edge_dirs_tool
        base = E.sum(axis=0) / math.sqrt(3.0)
        return np.concatenate([-E, base[None]])

    def planes_tool(self) -> tuple[np.ndarray, np.ndarray]:
        """The three corner planes ``n_k . x = d_k`` in the tool frame.

        Returns
        -------
        normals : ndarray, shape (3, 3)
            Outward unit normals (rows).
        offsets_mm : ndarray, shape (3,)
        """
        n = self.face_normals_tool[:3]
        return n, n @ self.feature_point_tool_mm

    def in_frame(self, T_frame_tool) -> dict:
        """Triangles, normals, planes and feature point in another frame.

        Parameters
        ----------
        T_frame_tool : array_like, shape (4, 4)
            Pose of the tool in the target frame.

        Returns
        -------
        dict
            ``triangles_mm`` (4, 3, 3), ``normals`` (4, 3),
            ``plane_offsets_mm`` (4,) (``n . x = d``), ``feature_point_mm`` (3,).
        """
        T = np.asarray(T_frame_tool, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DataError(f"`T_frame_tool` must be a finite (4, 4) transform, got shape {T.shape}")
        tri = transform_points(T, self.face_triangles_tool_mm.reshape(-1, 3)).reshape(4, 3, 3)
        nrm = self.face_normals_tool @ T[:3, :3].T
        fp = transform_points(T, self.feature_point_tool_mm[None])[0]
        offsets = np.einsum("ij,ij->i", nrm, tri[:, 0])
        return {"triangles_mm": tri, "normals": nrm, "plane_offsets_mm": offsets, "feature_point_mm": fp}

    def face_areas_mm2(self) -> np.ndarray:
        """Areas of the four faces (4,)."""
        return _triangle_areas(self.face_triangles_tool_mm)


def _triangle_areas(tri: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def sample_triangles(triangles, counts, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random points on triangles.

    Parameters
    ----------
    triangles : array_like, shape (F, 3, 3)
    counts : array_like of int, shape (F,)
        Points per triangle.
    rng : numpy.random.Generator

    Returns
    -------
    points : ndarray, shape (sum(counts), 3)
    face : ndarray of int, shape (sum(counts),)
        Index of the triangle each point lies on.
    """
    tri = np.asarray(triangles, dtype=float)
    counts = np.asarray(counts, dtype=int)
    face = np.repeat(np.arange(tri.shape[0]), counts)
    u = rng.random((face.size, 2))
    flip = u.sum(axis=1) > 1.0
    u[flip] = 1.0 - u[flip]
    t = tri[face]
    pts = t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])
    return pts, face


def point_plane_distance(points, normal, offset) -> np.ndarray:
    """Signed distances ``n . p - d`` of points (N, 3) to the plane ``n . x = d`` (unit ``n``)."""
    n = np.asarray(normal, dtype=float)
    return np.asarray(points, dtype=float) @ (n / np.linalg.norm(n)) - float(offset) / float(np.linalg.norm(n))


def plane_intersection(normals, points, max_condition: float = 1e6) -> np.ndarray:
    """Intersection of three planes, seed 002 eq. (2).

    ``p = [n1; n2; n3]^-1 [n1 . p1; n2 . p2; n3 . p3]``.

    Parameters
    ----------
    normals : array_like, shape (3, 3)
        Plane normals as rows (need not be unit).
    points : array_like, shape (3, 3)
        One point on each plane, rows, mm.
    max_condition : float
        Refuse (nearly) parallel planes above this condition number.

    Returns
    -------
    p : ndarray, shape (3,)

    Raises
    ------
    DataError
        Wrong shapes, non-finite input, or planes that do not meet in one point.
    """
    N = np.asarray(normals, dtype=float)
    P = np.asarray(points, dtype=float)
    if N.shape != (3, 3) or P.shape != (3, 3):
        raise DataError(f"`normals` and `points` must both have shape (3, 3), got {N.shape} and {P.shape}")
    if not (np.all(np.isfinite(N)) and np.all(np.isfinite(P))):
        raise DataError("`normals` and `points` must be finite")
    cond = np.linalg.cond(N)
    if not np.isfinite(cond) or cond > max_condition:
        raise DataError(f"the three planes do not meet in one point (condition number {cond:.3g})")
    return np.linalg.solve(N, np.einsum("ij,ij->i", N, P))
