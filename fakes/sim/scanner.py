"""Simulated structured-light 3D scanner looking at the corner jig (seed 002).

The scanner stands fixed in the cell; the arm carries the corner jig
(:class:`station.models.jig.CornerJig`) into its field of view. A scan is a
point cloud in the scanner frame (mm; optical axis ``+z``, the eye at the
origin) containing:

* **jig faces** facing the scanner (back-face culling, which is exact
  self-occlusion for a convex solid), sampled uniformly with a density
  ``density_per_mm2`` times the cosine of the viewing angle (a pixel grid
  sees a tilted face more sparsely). The mounting base (face 3) is hidden
  by the flange and never rendered.
* **background**: a plane behind the jig (default perpendicular to the
  optical axis, ``background_offset_mm`` behind the working distance: a panel
  or the cell wall), sampled at ``background_density_per_mm2`` over the field
  of view, minus the points the jig hides (ray-triangle test).
* **noise**: Gaussian, ``noise_sigma_mm`` along the viewing ray (depth) and a
  third of it across (the AITZ 3DS of seed 002 sec. 3.3 is specified at
  0.02 mm accuracy, 700 mm working distance, 450 mm field).
* **outliers**: a fraction ``outlier_fraction`` of the points, uniform in
  the jig's bounding box grown by 20 mm ("flying pixels").
* **occluders** (optional, none by default): spheres fixed in the scanner
  frame (a cable, a clamp, a gripper finger) that hide whatever lies behind
  them and show their own front surface (at ``density_per_mm2`` times the
  cosine of the viewing angle, labelled ``LABEL_OCCLUDER``).

Everything outside the viewing frustum (``fov_mm`` wide at the working
distance, depths ``depth_range_mm``) is clipped. Points are shuffled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.errors import ConfigError, DataError
from station.models.jig import BASE_FACE, CornerJig, sample_triangles
from station.numeric import finite_number

__all__ = ["SimScanner", "ScanResult", "look_at", "LABEL_BACKGROUND", "LABEL_OUTLIER", "LABEL_OCCLUDER"]

LABEL_BACKGROUND = -1
LABEL_OUTLIER = -2
LABEL_OCCLUDER = -3


def look_at(eye_mm, target_mm, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Pose (4, 4) of a camera at ``eye_mm`` whose ``+z`` axis points at ``target_mm``."""
    eye = np.asarray(eye_mm, dtype=float)
    tgt = np.asarray(target_mm, dtype=float)
    z = tgt - eye
    nz = np.linalg.norm(z)
    if nz == 0 or not np.isfinite(nz):
        raise ConfigError("`eye_mm` and `target_mm` must differ and be finite")
    z = z / nz
    upv = np.asarray(up, dtype=float)
    x = np.cross(z, upv)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


@dataclass(frozen=True)
class ScanResult:
    """One simulated scan.

    Attributes
    ----------
    points_mm : ndarray, shape (M, 3)
        Point cloud in the scanner frame.
    labels : ndarray of int, shape (M,)
        Truth per point: jig face 0-2, ``LABEL_BACKGROUND``, ``LABEL_OUTLIER``
        or ``LABEL_OCCLUDER``.
    feature_point_mm : ndarray, shape (3,)
        True jig corner in the scanner frame.
    plane_normals : ndarray, shape (3, 3)
        True outward normals of the three corner faces (scanner frame).
    plane_offsets_mm : ndarray, shape (3,)
        ``n . x = d`` of those planes.
    visible_faces : tuple of int
        Corner faces the scanner saw.
    scanner_T_tool : ndarray, shape (4, 4)
        Tool pose in the scanner frame.
    """

    points_mm: np.ndarray
    labels: np.ndarray
    feature_point_mm: np.ndarray
    plane_normals: np.ndarray
    plane_offsets_mm: np.ndarray
    visible_faces: tuple
    scanner_T_tool: np.ndarray


def _behind_spheres(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """True where the segment from the origin to a point passes through a sphere first.

    A point on a sphere's front surface is not hidden by that sphere (the ray
    enters the sphere at the point itself).
    """
    hidden = np.zeros(points.shape[0], dtype=bool)
    if points.size == 0:
        return hidden
    pp = np.einsum("ij,ij->i", points, points)
    for c, r in zip(centers, radii):
        # |t p - c|^2 = r^2  ->  t^2 |p|^2 - 2 t (c . p) + |c|^2 - r^2 = 0
        cp = points @ c
        disc = cp * cp - pp * (c @ c - r * r)
        root = np.sqrt(np.maximum(disc, 0.0))
        t_in = (cp - root) / pp
        t_out = (cp + root) / pp
        hidden |= (disc > 0) & (t_in < 1.0 - 1e-9) & (t_out > 0.0)
    return hidden


def _ray_hits_triangles(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """True where the segment from the origin to a point crosses a triangle first.

    Moeller-Trumbore, vectorised over points (N) and triangles (F).
    """
    if points.size == 0 or tri.size == 0:
        return np.zeros(points.shape[0], dtype=bool)
    d = points[:, None, :]  # ray direction scaled: hit parameter in (0, 1)
    v0 = tri[None, :, 0]
    e1 = tri[None, :, 1] - v0
    e2 = tri[None, :, 2] - v0
    pvec = np.cross(d, e2)
    det = np.einsum("nfk,nfk->nf", e1, pvec)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = -v0  # origin - v0
    u = np.einsum("nfk,nfk->nf", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    v = np.einsum("nfk,nfk->nf", d, qvec) * inv
    s = np.einsum("nfk,nfk->nf", e2, qvec) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (s > 1e-9) & (s < 1 - 1e-9)
    return np.any(hit, axis=1)


class SimScanner:
    """A fixed 3D scanner that renders the corner jig at an arm pose.

    Parameters
    ----------
    base_T_scanner : array_like, shape (4, 4)
        Scanner pose in the robot base frame (optical axis = its ``+z``).
    jig : CornerJig
        The jig on the tool.
    working_distance_mm : float
        Distance of the focal plane (default 700 mm, seed 002).
    fov_mm : float
        Width of the field at the working distance (default 450 mm).
    depth_range_mm : (float, float)
        Measurable depths along the optical axis.
    noise_sigma_mm : float
        Depth noise (1 sigma).
    density_per_mm2 : float
        Points per mm^2 on a jig face seen head-on.
    outlier_fraction : float
        Fraction of outliers, in [0, 0.5].
    background : bool
        Render the background plane.
    background_offset_mm : float
        Background plane distance behind the working distance.
    background_density_per_mm2 : float
        Points per mm^2 on the background.
    occluders : sequence of (center_mm, radius_mm)
        Spheres fixed in the scanner frame that hide what is behind them
        (default none).
    """

    def __init__(
        self,
        base_T_scanner,
        jig: CornerJig | None = None,
        *,
        working_distance_mm: float = 700.0,
        fov_mm: float = 450.0,
        depth_range_mm=(450.0, 1100.0),
        noise_sigma_mm: float = 0.02,
        density_per_mm2: float = 1.0,
        outlier_fraction: float = 0.01,
        background: bool = True,
        background_offset_mm: float = 250.0,
        background_density_per_mm2: float = 0.02,
        occluders=(),
    ) -> None:
        T = np.array(base_T_scanner, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError(f"`base_T_scanner` must be a finite (4, 4) transform, got shape {T.shape}")
        self.base_T_scanner = T
        self.scanner_T_base = np.linalg.inv(T)
        self.jig = jig if jig is not None else CornerJig()
        if not isinstance(self.jig, CornerJig):
            raise ConfigError(f"`jig` must be a CornerJig, got {type(self.jig).__name__}")
        self.working_distance_mm = finite_number(working_distance_mm, "working_distance_mm", positive=True)
        self.fov_mm = finite_number(fov_mm, "fov_mm", positive=True)
        try:
            z0, z1 = (float(x) for x in depth_range_mm)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"`depth_range_mm` must be (near, far): {exc}") from exc
        if not (math.isfinite(z0) and math.isfinite(z1) and 0 < z0 < z1):
            raise ConfigError(f"`depth_range_mm` must satisfy 0 < near < far, got {depth_range_mm!r}")
        self.depth_range_mm = (z0, z1)
        self.noise_sigma_mm = finite_number(noise_sigma_mm, "noise_sigma_mm", nonneg=True)
        self.density_per_mm2 = finite_number(density_per_mm2, "density_per_mm2", positive=True)
        self.outlier_fraction = finite_number(outlier_fraction, "outlier_fraction", nonneg=True, hi=0.5)
        self.background = bool(background)
        self.background_offset_mm = finite_number(background_offset_mm, "background_offset_mm", positive=True)
        self.background_density_per_mm2 = finite_number(background_density_per_mm2, "background_density_per_mm2", nonneg=True)
        self.tan_half_fov = 0.5 * self.fov_mm / self.working_distance_mm
        centers, radii = [], []
        for i, occ in enumerate(occluders):
            try:
                c, r = occ
                c = np.asarray(c, dtype=float)
                r = float(r)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"`occluders[{i}]` must be (center_mm, radius_mm): {exc}") from exc
            if c.shape != (3,) or not np.all(np.isfinite(c)) or not (math.isfinite(r) and r > 0):
                raise ConfigError(f"`occluders[{i}]` must be 3 finite center coordinates and a radius > 0, got {occ!r}")
            if np.linalg.norm(c) <= r:
                raise ConfigError(f"`occluders[{i}]` contains the scanner's eye (the origin)")
            centers.append(c)
            radii.append(r)
        self.occluder_centers_mm = np.array(centers, dtype=float).reshape(-1, 3)
        self.occluder_radii_mm = np.array(radii, dtype=float)

    def in_frustum(self, points_mm: np.ndarray) -> np.ndarray:
        """True for scanner-frame points (N, 3) the scanner can measure."""
        p = np.asarray(points_mm, dtype=float)
        z = p[:, 2]
        lim = self.tan_half_fov * np.maximum(z, 0.0)
        return (
            (z >= self.depth_range_mm[0])
            & (z <= self.depth_range_mm[1])
            & (np.abs(p[:, 0]) <= lim)
            & (np.abs(p[:, 1]) <= lim)
        )

    def render(self, base_T_tool, rng: np.random.Generator) -> ScanResult:
        """Scan the jig carried at tool pose ``base_T_tool``.

        Parameters
        ----------
        base_T_tool : array_like, shape (4, 4)
            True tool pose in the robot base frame.
        rng : numpy.random.Generator

        Returns
        -------
        ScanResult
            May hold no jig points if the jig is outside the field of view.
        """
        T = np.asarray(base_T_tool, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DataError(f"`base_T_tool` must be a finite (4, 4) pose, got shape {T.shape}")
        s_T_tool = self.scanner_T_base @ T
        geo = self.jig.in_frame(s_T_tool)
        tri, nrm = geo["triangles_mm"], geo["normals"]
        areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        centroids = tri.mean(axis=1)
        view = -centroids / np.linalg.norm(centroids, axis=1, keepdims=True)  # towards the eye
        cosang = np.einsum("ij,ij->i", nrm, view)
        front = cosang > 0
        front[BASE_FACE] = False
        counts = np.where(front, rng.poisson(self.density_per_mm2 * areas * np.clip(cosang, 0, 1)), 0)
        jig_pts, face = sample_triangles(tri, counts, rng)

        pts = [jig_pts]
        labels = [face]
        if self.background and self.background_density_per_mm2 > 0:
            z_bg = self.working_distance_mm + self.background_offset_mm
            half = self.tan_half_fov * z_bg
            n_bg = rng.poisson(self.background_density_per_mm2 * (2 * half) ** 2)
            bg = np.column_stack([rng.uniform(-half, half, n_bg), rng.uniform(-half, half, n_bg), np.full(n_bg, z_bg)])
            # the jig (all faces, base included: the flange sits behind it) hides what is behind it
            bg = bg[~_ray_hits_triangles(bg, tri)]
            pts.append(bg)
            labels.append(np.full(bg.shape[0], LABEL_BACKGROUND))
        P = np.concatenate(pts)
        L = np.concatenate(labels)
        if self.occluder_radii_mm.size:
            P, L = self._occlude(P, L, tri, rng)
        # noise: along the ray and a third of it across
        if self.noise_sigma_mm > 0 and P.size:
            ray = P / np.linalg.norm(P, axis=1, keepdims=True)
            noise = rng.normal(0.0, self.noise_sigma_mm / 3.0, P.shape)
            noise += (rng.normal(0.0, self.noise_sigma_mm, P.shape[0]) - np.einsum("ij,ij->i", noise, ray))[:, None] * ray
            P = P + noise
        n_out = rng.binomial(P.shape[0], self.outlier_fraction) if P.shape[0] else 0
        if n_out:
            vmin = tri.reshape(-1, 3).min(axis=0) - 20.0
            vmax = tri.reshape(-1, 3).max(axis=0) + 20.0
            P = np.concatenate([P, rng.uniform(vmin, vmax, (n_out, 3))])
            L = np.concatenate([L, np.full(n_out, LABEL_OUTLIER)])
        keep = self.in_frustum(P)
        P, L = P[keep], L[keep]
        order = rng.permutation(P.shape[0])
        return ScanResult(
            points_mm=P[order],
            labels=L[order].astype(int),
            feature_point_mm=geo["feature_point_mm"],
            plane_normals=nrm[:3],
            plane_offsets_mm=geo["plane_offsets_mm"][:3],
            visible_faces=tuple(int(i) for i in np.nonzero(front)[0]),
            scanner_T_tool=s_T_tool,
        )

    def _occlude(self, P, L, tri, rng):
        """Hide what the occluder spheres cover and add their visible surfaces."""
        keep = ~_behind_spheres(P, self.occluder_centers_mm, self.occluder_radii_mm)
        P, L = P[keep], L[keep]
        surf = []
        for c, r in zip(self.occluder_centers_mm, self.occluder_radii_mm):
            n = rng.poisson(self.density_per_mm2 * 4.0 * math.pi * r * r)
            u = rng.normal(size=(n, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            s = c + r * u
            cosang = -np.einsum("ij,ij->i", u, s) / np.linalg.norm(s, axis=1)
            surf.append(s[rng.random(n) < cosang])  # front side, density x cos
        S = np.concatenate(surf)
        S = S[~_behind_spheres(S, self.occluder_centers_mm, self.occluder_radii_mm)]
        S = S[~_ray_hits_triangles(S, tri)]
        return np.concatenate([P, S]), np.concatenate([L, np.full(S.shape[0], LABEL_OCCLUDER)])

    def describe(self) -> dict:
        info = {
            "base_T_scanner": self.base_T_scanner.tolist(),
            "jig_edge_mm": self.jig.edge_mm,
            "working_distance_mm": self.working_distance_mm,
            "fov_mm": self.fov_mm,
            "noise_sigma_mm": self.noise_sigma_mm,
            "density_per_mm2": self.density_per_mm2,
            "outlier_fraction": self.outlier_fraction,
        }
        if self.occluder_radii_mm.size:
            info["occluders"] = [[c.tolist(), float(r)] for c, r in zip(self.occluder_centers_mm, self.occluder_radii_mm)]
        return info
