"""Corner jig geometry (seed 002 sec. 2) and the simulated scanner's point clouds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fakes.sim.scanner import LABEL_BACKGROUND, LABEL_OUTLIER, SimScanner, look_at
from station.errors import ConfigError, DataError
from station.models.jig import CornerJig, plane_intersection, point_plane_distance


def test_jig_geometry(rng):
    jig = CornerJig(edge_mm=rng.uniform(30, 90), vertex_tool_mm=tuple(rng.uniform(-5, 5, 3)), roll_rad=rng.uniform(-3, 3))
    E = jig.edge_dirs_tool
    np.testing.assert_allclose(E @ E.T, np.eye(3), atol=1e-12)  # mutually perpendicular
    assert np.linalg.det(E) == pytest.approx(1.0)
    np.testing.assert_allclose(E.sum(axis=0) / math.sqrt(3), [0, 0, -1], atol=1e-12)  # diagonal to the flange
    n, d = jig.planes_tool()
    fp = jig.feature_point_tool_mm
    # seed 002 eq. (2): the three planes meet at the corner
    np.testing.assert_allclose(plane_intersection(n, np.tile(fp, (3, 1))), fp, atol=1e-9)
    tri = jig.face_triangles_tool_mm
    for k in range(3):
        np.testing.assert_allclose(tri[k] @ n[k] - d[k], 0, atol=1e-9)
    # outward normals: the solid's centroid is behind every face
    c = jig.vertices_tool_mm.mean(axis=0)
    for k in range(4):
        assert np.dot(jig.face_normals_tool[k], c - tri[k, 0]) < 0
    L = jig.edge_mm
    np.testing.assert_allclose(jig.face_areas_mm2(), [L * L / 2] * 3 + [math.sqrt(3) / 4 * 2 * L * L])


def test_plane_intersection_refuses_parallel_planes():
    with pytest.raises(DataError, match="do not meet"):
        plane_intersection([[0, 0, 1], [0, 0, 1], [1, 0, 0]], np.zeros((3, 3)))
    with pytest.raises(DataError, match=r"\(3, 3\)"):
        plane_intersection(np.eye(2), np.zeros((3, 3)))


def _scene(rng, **kw):
    """A scanner 700 mm in front of a tool whose corner points at it, tilted a little."""
    base_T_tool = np.eye(4)
    base_T_tool[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    base_T_tool[:3, 3] = rng.uniform(-200, 200, 3) + [0, 0, 1000]
    z_tool = base_T_tool[:3, 2]
    eye = base_T_tool[:3, 3] + 700.0 * z_tool
    scanner = SimScanner(look_at(eye, base_T_tool[:3, 3]), CornerJig(edge_mm=60.0), **kw)
    return scanner, base_T_tool


def test_noise_free_points_lie_on_their_faces(rng):
    scanner, T = _scene(rng, noise_sigma_mm=0.0, outlier_fraction=0.0)
    scan = scanner.render(T, rng)
    jig_pts = scan.labels >= 0
    assert jig_pts.sum() > 1000
    assert set(np.unique(scan.labels[jig_pts])) == set(scan.visible_faces) == {0, 1, 2}
    for k in range(3):
        p = scan.points_mm[scan.labels == k]
        np.testing.assert_allclose(point_plane_distance(p, scan.plane_normals[k], scan.plane_offsets_mm[k]), 0, atol=1e-9)
    # feature point = the tool pose's corner, in the scanner frame
    fp = scanner.scanner_T_base @ np.append(T[:3, 3], 1.0)
    np.testing.assert_allclose(scan.feature_point_mm, fp[:3], atol=1e-9)
    np.testing.assert_allclose(
        plane_intersection(scan.plane_normals, scan.plane_normals * scan.plane_offsets_mm[:, None]), fp[:3], atol=1e-9
    )
    assert np.all(scanner.in_frustum(scan.points_mm))


def test_noise_statistics_on_planes(rng):
    sigma = 0.02
    scanner, T = _scene(rng, noise_sigma_mm=sigma, outlier_fraction=0.0, density_per_mm2=3.0)
    scan = scanner.render(T, rng)
    z2 = []
    for k in range(3):
        p = scan.points_mm[scan.labels == k]
        n = scan.plane_normals[k]
        dist = point_plane_distance(p, n, scan.plane_offsets_mm[k])
        ray = p / np.linalg.norm(p, axis=1, keepdims=True)
        c2 = (ray @ n) ** 2
        var = sigma**2 * c2 + (sigma / 3) ** 2 * (1 - c2)  # depth sigma along the ray, sigma/3 across
        z2.append(dist**2 / var)
    z2 = np.concatenate(z2)
    n = z2.size
    from scipy import stats

    assert stats.chi2.ppf(1e-5, n) < z2.sum() < stats.chi2.ppf(1 - 1e-5, n)


def test_back_faces_culled_and_background_occluded(rng):
    scanner, T = _scene(rng, noise_sigma_mm=0.0, outlier_fraction=0.0, background_density_per_mm2=0.05)
    # turn the tool so that face 0 looks away from the scanner
    n0 = CornerJig().face_normals_tool[0]
    view_tool = T[:3, :3].T @ (scanner.base_T_scanner[:3, 3] - T[:3, 3])
    view_tool /= np.linalg.norm(view_tool)
    axis = np.cross(n0, view_tool)
    angle = math.acos(np.clip(n0 @ view_tool, -1, 1)) - math.radians(100)  # face 0 now 100 deg off the view
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    T2 = T.copy()
    T2[:3, :3] = T[:3, :3] @ R
    scan = scanner.render(T2, rng)
    n0_scan = scan.plane_normals[0]
    centroid = (scanner.scanner_T_base @ T2 @ np.append(CornerJig().face_triangles_tool_mm[0].mean(0), 1))[:3]
    assert n0_scan @ (-centroid) < 0
    assert 0 not in scan.visible_faces and not np.any(scan.labels == 0)
    # background: nothing in the jig's shadow around the corner's line of sight
    scan = scanner.render(T, rng)
    bg = scan.points_mm[scan.labels == LABEL_BACKGROUND]
    assert bg.shape[0] > 1000
    u = scan.feature_point_mm / np.linalg.norm(scan.feature_point_mm)
    ang = np.arccos(np.clip(bg @ u / np.linalg.norm(bg, axis=1), -1, 1))
    r_shadow = 0.5 * (60.0 / math.sqrt(6)) / 800.0  # half the inradius of the silhouette, far side
    assert ang.min() > r_shadow
    assert (ang < 4 * r_shadow).sum() > 0  # points right next to the silhouette remain


def test_outliers_and_empty_view(rng):
    f = 0.05
    scanner, T = _scene(rng, outlier_fraction=f, background=False)
    scan = scanner.render(T, rng)
    n = scan.labels.size
    k = int((scan.labels == LABEL_OUTLIER).sum())
    sd = math.sqrt(n * f * (1 - f))
    assert abs(k - n * f) < 6 * sd + 5
    far = T.copy()
    far[:3, 3] += 5000.0
    empty = scanner.render(far, rng)
    assert not np.any(empty.labels >= 0)


def test_scanner_configuration_refused():
    with pytest.raises(ConfigError, match="outlier_fraction"):
        SimScanner(np.eye(4), outlier_fraction=0.9)
    with pytest.raises(ConfigError, match="depth_range_mm"):
        SimScanner(np.eye(4), depth_range_mm=(900, 100))
    with pytest.raises(ConfigError, match="edge_mm"):
        CornerJig(edge_mm=-1.0)
