"""The seed's feature point algorithm, as the reference (seed 002 sec. 2.2-2.3).

A faithful transcription of the two stages of seed 002 Fig. 2, vectorised
with numpy over a fixed number of sample sets so that it runs on scans of
200k points; :func:`station.analysis.jig_features.feature_point` is the
station's own algorithm, and ``bench/bench_jig_features.py`` compares them.

Stage 1, sample sets forming a plane (sec. 2.2)
    ``n_sets`` random sets of 4 points are drawn. Each must pass

    * **filter 1** (Fig. 3): the distances from the set's centre to its four
      points all lie in ``radius_range_mm``;
    * **filter 2** (Fig. 4): the normal vectors of the four points (each
      from the principal axes of the points around it, see below) are
      parallel: every pairwise ``|n_i . n_j| >= cos(point_normal_tol_deg)``;
    * **filter 3** (Figs. 5-6): the normals of the four triangles the points
      form agree with the mean of the point normals: every
      ``|n_tri . n_mean| >= triangle_dot_min`` (the seed: "smaller than 1"
      rejects; the threshold just below 1 is that test under noise). This
      rejects sets on two parallel planes, whose point normals agree.

    A set that passes is a plane: its points, its centre and the mean of its
    triangle normals go on.

Stage 2, plane clustering and the intersection of three faces (sec. 2.3)
    The first set founds a plane group; every later set is compared with
    the existing groups in turn:

    * **step 1** (Fig. 9): its normal is parallel to the group's
      (``|n_s . n_g| >= cos(parallel_tol_deg)``), else try the next group;
    * **step 2** (Fig. 10): the direction ``v`` from the group's centre to
      the set's centre lies in both planes (its angles to both normals
      within ``90 +- inplane_tol_deg``), else try the next group;
    * **step 3**, eq. (1): the height of the set's centre along the group
      normal lies in the group's band, ``P_plane,Z,min < P_center,Z <
      P_plane,Z,max`` with the band the group centre's height
      ``+- height_tol_mm``: the set joins the group (its normal and centre
      become the running means of its members); otherwise the set is
      dropped.

    A set that matches no group founds a new one. Of the groups with at
    least ``min_group_sets`` sets, the three whose normals are mutually
    perpendicular (within ``perpendicular_tol_deg``) and whose centres lie
    within ``max_center_distance_mm`` of each other, with the most sets, are
    the jig's faces; their intersection is eq. (2) with each group's normal
    and centre.

Where the seed leaves a choice
------------------------------
* **Sampling.** "Random 4 sample points" drawn from the whole scan almost
  never pass filter 1 when the jig is a small part of the scan (all four on
  one face and close together: about 1 in 10^5 for the simulated scanner's
  default scene). ``sampling="local"`` (default) draws the first point at
  random from the whole scan and the other three at random from the points
  in the same cell of a grid (randomly placed, cube diagonal twice the
  largest radius of filter 1): filter 1's upper bound applied while
  sampling, whatever the point density; filter 1 is still applied to the
  set. ``sampling="uniform"`` is the literal draw.
* **Point normals** (filter 2) are not defined further in the seed; each
  point takes the principal-axes normal of the points sharing its cell of a
  grid of side ``2 * normal_radius_mm`` (a fixed neighbourhood in space, not
  a number of neighbours, so the normal's noise does not grow with the
  scanner's resolution). Points in cells of fewer than 3 points have none
  and their sets fail filter 2.
* **Step 2 failing** is not spelled out; the set goes on to the next group
  (a parallel plane at another height, as in Fig. 10).
* The result has no uncertainty (``sigma_mm`` NaN); ``inliers`` counts the
  sample points of each face's group and ``rms_mm`` their distances to the
  group planes.
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np
from station.analysis.arm.jig_features import JigFeature, check_points
from station.numeric import finite_number
from station.errors import ConfigError, DataError, InsufficientDataError
from station.models.jig import plane_intersection

__all__ = ["seed_feature_point"]

#: the four triangles of a 4-point set (filter 3)
_TRIANGLES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])


def _grid_cells(P: np.ndarray, side_mm: float, offset_mm: np.ndarray) -> np.ndarray:
    """Cell number (0..C-1) of every point in a grid of cubes of ``side_mm``."""
    Q = P - P.min(axis=0) + offset_mm
    dims = np.floor(Q.max(axis=0) / side_mm).astype(np.int64) + 1
    if float(np.prod(dims.astype(float))) > 2.0**62:
        raise DataError(f"the cloud spans {Q.max(axis=0).round(1).tolist()} mm: too many {side_mm:g} mm cells to number")
    ijk = np.floor(Q / side_mm).astype(np.int64)
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    return np.unique(key, return_inverse=True)[1].reshape(-1)


def _point_normals(P: np.ndarray, radius_mm: float) -> np.ndarray:
    """Unit normal of every point from the points of its grid cell (NaN in cells of < 3 points)."""
    cell = _grid_cells(P, 2.0 * radius_mm, np.zeros(3))
    nc = int(cell.max()) + 1
    cnt = np.bincount(cell, minlength=nc).astype(float)
    Q = P - P.min(axis=0)
    s1 = np.stack([np.bincount(cell, Q[:, a], nc) for a in range(3)], axis=1)
    s2 = np.empty((nc, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            s2[:, a, b] = s2[:, b, a] = np.bincount(cell, Q[:, a] * Q[:, b], nc)
    m = s1 / cnt[:, None]
    cov = s2 / cnt[:, None, None] - m[:, :, None] * m[:, None, :]
    _, vec = np.linalg.eigh(cov)
    normal = vec[:, :, 0]
    normal[cnt < 3] = np.nan
    return normal[cell]


def _draw_sets(P, rng, n_sets, sampling, r_max):
    """Indices (S, 4) of the sample sets (sets with a repeated point left out)."""
    n = P.shape[0]
    if sampling == "uniform":
        sets = rng.integers(0, n, size=(n_sets, 4))
    else:
        side = 2.0 * r_max / math.sqrt(3.0)
        cell = _grid_cells(P, side, rng.random(3) * side)
        order = np.argsort(cell, kind="stable")
        counts = np.bincount(cell)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        anchor = rng.integers(0, n, size=n_sets)
        c = cell[anchor]
        others = order[start[c][:, None] + (rng.random((n_sets, 3)) * counts[c][:, None]).astype(np.int64)]
        sets = np.column_stack([anchor, others])
    s = np.sort(sets, axis=1)
    return sets[(np.diff(s, axis=1) > 0).all(axis=1)]


def _filters(P, normals, sets, *, r_min, r_max, cos_point, tri_dot_min):
    """Filters 1-3 (sec. 2.2.1-2.2.3). Returns the surviving sets, their centres and normals."""
    pts = P[sets]  # (S, 4, 3)
    centre = pts.mean(axis=1)
    r = np.linalg.norm(pts - centre[:, None, :], axis=2)
    keep = ((r >= r_min) & (r <= r_max)).all(axis=1)  # filter 1
    sets, pts, centre = sets[keep], pts[keep], centre[keep]
    if not len(sets):
        return sets, centre, np.zeros((0, 3))
    # filter 2: the four point normals are parallel
    pn = normals[sets]  # (S, 4, 3)
    dots = np.abs(np.einsum("sik,sjk->sij", pn, pn))
    keep = (dots >= cos_point).all(axis=(1, 2))  # NaN normals compare False
    sets, pts, centre, pn = sets[keep], pts[keep], centre[keep], pn[keep]
    # filter 3: every triangle's normal agrees with the mean point normal
    sign = np.where(np.einsum("sik,sk->si", pn, pn[:, 0]) < 0, -1.0, 1.0)
    mean_pn = (pn * sign[:, :, None]).mean(axis=1)
    mean_pn /= np.linalg.norm(mean_pn, axis=1, keepdims=True)
    t = pts[:, _TRIANGLES]  # (S, 4, 3, 3)
    tn = np.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0])
    norm = np.linalg.norm(tn, axis=2)
    tn = tn / np.where(norm > 0, norm, 1.0)[:, :, None]
    tdot = np.einsum("stk,sk->st", tn, mean_pn)
    keep = ((np.abs(tdot) >= tri_dot_min) & (norm > 0)).all(axis=1)
    sets, centre, tn, tdot = sets[keep], centre[keep], tn[keep], tdot[keep]
    # the set's normal: the mean of its triangle normals, signs aligned
    normal = (tn * np.where(tdot < 0, -1.0, 1.0)[:, :, None]).mean(axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    return sets, centre, normal


def _cluster(centre, normal, *, cos_parallel, inplane_sin, height_tol_mm):
    """Plane clustering, steps 1-3 (sec. 2.3.1-2.3.3). Returns the group of each set (-1: dropped)."""
    S = centre.shape[0]
    g_nsum = np.zeros((S, 3))  # sums of aligned member normals
    g_csum = np.zeros((S, 3))
    g_count = np.zeros(S)
    g_normal = np.zeros((S, 3))
    g_centre = np.zeros((S, 3))
    group = np.full(S, -1)
    G = 0
    for s in range(S):
        n_s, c_s = normal[s], centre[s]
        joined = dropped = False
        if G:
            gn, gc = g_normal[:G], g_centre[:G]
            dot = gn @ n_s
            parallel = np.abs(dot) >= cos_parallel  # step 1
            v = c_s - gc
            vlen = np.linalg.norm(v, axis=1)
            vu = v / np.where(vlen > 0, vlen, 1.0)[:, None]
            # step 2: v lies in both planes (angles to both normals near 90 deg)
            in_plane = (vlen == 0) | ((np.abs(vu @ n_s) <= inplane_sin) & (np.abs(np.einsum("gk,gk->g", vu, gn)) <= inplane_sin))
            cand = np.flatnonzero(parallel & in_plane)
            if cand.size:
                g = int(cand[0])  # the first group in order that passes steps 1-2
                height = float(gn[g] @ v[g])
                if -height_tol_mm < height < height_tol_mm:  # step 3, eq. (1)
                    sgn = 1.0 if dot[g] >= 0 else -1.0
                    g_nsum[g] += sgn * n_s
                    g_csum[g] += c_s
                    g_count[g] += 1
                    g_normal[g] = g_nsum[g] / np.linalg.norm(g_nsum[g])
                    g_centre[g] = g_csum[g] / g_count[g]
                    group[s] = g
                    joined = True
                else:
                    dropped = True
        if not joined and not dropped:
            g_nsum[G], g_csum[G], g_count[G] = n_s, c_s, 1
            g_normal[G], g_centre[G] = n_s, c_s
            group[s] = G
            G += 1
    return group, g_normal[:G], g_centre[:G], g_count[:G].astype(int)


def seed_feature_point(
    points_mm,
    rng: np.random.Generator,
    *,
    n_sets: int = 40000,
    sampling: str = "local",
    radius_range_mm=(1.5, 6.0),
    normal_radius_mm: float = 2.5,
    point_normal_tol_deg: float = 10.0,
    triangle_dot_min: float = 0.995,
    parallel_tol_deg: float = 5.0,
    inplane_tol_deg: float = 3.0,
    height_tol_mm: float = 0.3,
    perpendicular_tol_deg: float = 5.0,
    max_center_distance_mm: float = 150.0,
    min_group_sets: int = 10,
) -> JigFeature:
    """Feature point of the corner jig by seed 002's algorithm (see the module docstring).

    Parameters
    ----------
    points_mm : array_like, shape (N, 3)
        The scan, mm. Must be finite.
    rng : numpy.random.Generator
        Draws the sample sets; the result is deterministic given it.
    n_sets : int
        Random 4-point sample sets drawn.
    sampling : {"local", "uniform"}
        How the four points of a set are drawn.
    radius_range_mm : (float, float)
        Filter 1: allowed distances from a set's centre to its points.
    normal_radius_mm : float
        Half the side of the grid cells that give the point normals (filter 2).
    point_normal_tol_deg : float
        Filter 2: largest angle between two point normals of a set.
    triangle_dot_min : float
        Filter 3: smallest ``|n_tri . n_mean|``, in (0, 1).
    parallel_tol_deg : float
        Step 1: largest angle between a set's normal and a group's.
    inplane_tol_deg : float
        Step 2: largest departure from 90 deg between the centre-to-centre
        direction and either normal.
    height_tol_mm : float
        Step 3, eq. (1): half height of a group's band.
    perpendicular_tol_deg : float
        The three faces' normals must be perpendicular within this.
    max_center_distance_mm : float
        The three faces' group centres must lie within this of each other.
    min_group_sets : int
        Sets a group needs to count as a face.

    Returns
    -------
    JigFeature
        ``method="seed"``; ``sigma_mm`` and ``covariance_mm2`` are NaN.

    Raises
    ------
    DataError, InsufficientDataError
        Bad cloud, or no three perpendicular plane groups (the message says
        how many groups of how many sets were found).
    ConfigError
        A parameter out of range (named).
    """
    if not isinstance(rng, np.random.Generator):
        raise ConfigError(f"`rng` must be a numpy.random.Generator, got {type(rng).__name__}")
    if sampling not in ("local", "uniform"):
        raise ConfigError(f"`sampling` must be 'local' or 'uniform', got {sampling!r}")
    for name, value in (("n_sets", n_sets), ("min_group_sets", min_group_sets)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
            raise ConfigError(f"`{name}` must be an integer >= 1, got {value!r}")
    normal_radius_mm = finite_number(normal_radius_mm, "normal_radius_mm", positive=True)
    try:
        r_min, r_max = (float(x) for x in radius_range_mm)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"`radius_range_mm` must be (min, max) in mm: {exc}") from exc
    if not (math.isfinite(r_min) and math.isfinite(r_max) and 0 <= r_min < r_max):
        raise ConfigError(f"`radius_range_mm` must satisfy 0 <= min < max, got {radius_range_mm!r}")
    if not 0 < float(triangle_dot_min) < 1:
        raise ConfigError(f"`triangle_dot_min` must be in (0, 1), got {triangle_dot_min!r}")
    tols = {}
    for name, value in (("point_normal_tol_deg", point_normal_tol_deg), ("parallel_tol_deg", parallel_tol_deg),
                        ("inplane_tol_deg", inplane_tol_deg), ("perpendicular_tol_deg", perpendicular_tol_deg)):
        tols[name] = finite_number(value, name, positive=True)
        if tols[name] >= 45:
            raise ConfigError(f"`{name}` must be < 45 deg, got {value!r}")
    height_tol_mm = finite_number(height_tol_mm, "height_tol_mm", positive=True)
    max_center_distance_mm = finite_number(max_center_distance_mm, "max_center_distance_mm", positive=True)
    P = check_points(points_mm)
    if P.shape[0] < 12:
        raise InsufficientDataError(f"{P.shape[0]} points cannot hold three faces of 4-point sample sets")

    sets = _draw_sets(P, rng, int(n_sets), sampling, r_max)
    sets, centre, normal = _filters(
        P, _point_normals(P, normal_radius_mm), sets, r_min=r_min, r_max=r_max,
        cos_point=math.cos(math.radians(tols["point_normal_tol_deg"])), tri_dot_min=float(triangle_dot_min),
    )
    group, g_normal, g_centre, g_count = _cluster(
        centre, normal, cos_parallel=math.cos(math.radians(tols["parallel_tol_deg"])),
        inplane_sin=math.sin(math.radians(tols["inplane_tol_deg"])), height_tol_mm=height_tol_mm,
    )
    faces = np.flatnonzero(g_count >= min_group_sets)
    faces = faces[np.argsort(-g_count[faces], kind="stable")][:12]
    sin_perp = math.sin(math.radians(tols["perpendicular_tol_deg"]))
    best, best_score = None, -1
    for tri in combinations(faces.tolist(), 3):
        N = g_normal[tri, :]
        G = np.abs(N @ N.T)
        if G[0, 1] > sin_perp or G[0, 2] > sin_perp or G[1, 2] > sin_perp:
            continue
        C = g_centre[tri, :]
        if max(np.linalg.norm(C[i] - C[j]) for i, j in ((0, 1), (0, 2), (1, 2))) > max_center_distance_mm:
            continue
        score = int(g_count[list(tri)].sum())
        if score > best_score:
            best, best_score = tri, score
    if best is None:
        counts = ", ".join(str(int(c)) for c in g_count[faces]) or "none"
        raise InsufficientDataError(
            f"seed algorithm: {len(sets)} sample sets passed filters 1-3, forming {faces.size} plane group(s) with "
            f">= {min_group_sets} sets (sets per group: {counts}); no three of them are mutually perpendicular "
            f"faces meeting at a corner"
        )
    idx = list(best)
    N = g_normal[idx]
    C = g_centre[idx]
    point = plane_intersection(N, C)  # eq. (2)
    # outward normals, as the station's result reports them: the other groups' centres lie behind each face
    for k in range(3):
        if sum(N[k] @ (C[j] - point) for j in range(3) if j != k) > 0:
            N[k] = -N[k]
    sq, cnt = 0.0, 0
    for k, g in enumerate(idx):
        pts = P[sets[group == g]].reshape(-1, 3)
        d = (pts - C[k]) @ N[k]
        sq += float(d @ d)
        cnt += d.size
    G = np.abs(N @ N.T)
    angles = np.degrees(np.arccos(np.clip([G[0, 1], G[0, 2], G[1, 2]], 0.0, 1.0)))
    nan3 = np.full(3, np.nan)
    return JigFeature(
        point_mm=point,
        sigma_mm=nan3,
        covariance_mm2=np.full((3, 3), np.nan),
        normals=N,
        inliers=tuple(4 * int(g_count[g]) for g in idx),
        rms_mm=math.sqrt(sq / cnt),
        method="seed",
        noise_mm=nan3.copy(),
        face_angles_deg=angles,
    )
