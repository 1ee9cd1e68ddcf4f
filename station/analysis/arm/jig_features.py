"""Feature point of the corner jig from a point cloud (seed 002 sec. 2).

The jig's feature point is the corner where its three mutually
perpendicular faces meet (seed 002 Fig. 1, eq. (2)). This module finds it
with an algorithm of the station's own; the seed's algorithm (random 4-point
sample sets, filters 1-3, plane clustering) is kept as the reference in
:mod:`station.analysis.arm.jig_features_seed`, and ``bench/bench_jig_features.py``
compares the two.

Algorithm of :func:`feature_point`
----------------------------------
1. **Voxel planes.** The cloud is cut into cubic voxels (``voxel_mm``). Each
   voxel with at least ``min_voxel_points`` points gets a plane from the
   principal axes of its points (moment sums, one pass over the cloud). The
   median voxel thickness (RMS distance to the voxel plane) estimates the
   scanner noise; voxels thicker than ``3x`` that (edges, clutter, voxels hit
   by outliers) are left out. If steps 1-3 do not find three faces (a face
   seen at a grazing angle holds few points per voxel), they are tried once
   more with voxels twice as large.
2. **Plane segmentation.** Planes are taken out one after another: the
   hypothesis (one voxel's plane) that most voxel points agree with (normal
   within ``angle_tol_deg``, centroid near the plane) is refitted to the
   pooled moments of its supporters, its support recomputed with a tight
   distance gate, and its voxels removed; repeated up to ``max_planes``
   while a plane keeps ``min_face_points`` points.
3. **The corner's three faces.** Of the planes found, the triple with the
   most points whose normals are mutually perpendicular within
   ``perpendicular_tol_deg`` is the jig's corner; its planes meet by seed
   002 eq. (2). Normals are turned outwards (the other faces lie behind
   each face).
4. **Point assignment.** Every point is given to its nearest face if it lies
   within ``gate_sigmas`` of that face's noise, behind the other two faces
   (inside the solid), and no farther from the corner than that face's
   voxels: background points on a face's extended plane and outliers are
   left out.
5. **Joint fit.** The three planes are fitted together as one rigid corner:
   an orthonormal frame (three rotation parameters, so the normals stay
   mutually perpendicular) and the corner point (three parameters), by
   Gauss-Newton on the point-to-plane distances ``r = n_k . (p - c)``
   weighted by each face's own noise (a scanner's depth noise projects
   differently on faces seen at different angles). The normal equations are
   built from per-face moment sums, so each iteration costs nothing per
   point. Assignment, face noise and fit are repeated until the inliers
   settle (a trimmed, i.e. hard-redescending, robust estimator).

   With ``perpendicular=False`` each face gets its own total-least-squares
   plane instead and the corner is their intersection, eq. (2) (for a jig
   whose faces are known to be off square).

Uncertainty
-----------
``covariance_mm2`` is the 1-sigma covariance of the corner from the residuals
(Gauss-Newton ``H^-1`` with each face weighted by its estimated noise
variance). It assumes independent point noise: a scanner whose neighbouring
pixels share errors, or a jig whose faces are not flat and square, makes the
true scatter larger. ``face_angles_deg`` (angles between independently
fitted face normals) shows how square the measured faces are; a departure
from 90 deg well beyond its noise says the perpendicular constraint does not
fit this jig.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from station.errors import ConfigError, DataError, InsufficientDataError
from station.models.jig import plane_intersection
from station.numeric import finite_number

__all__ = ["JigFeature", "feature_point", "check_points"]


@dataclass(frozen=True)
class JigFeature:
    """The corner jig's feature point found in one point cloud.

    Attributes
    ----------
    point_mm : ndarray, shape (3,)
        The feature point (corner), in the cloud's frame.
    sigma_mm : ndarray, shape (3,)
        1-sigma uncertainty of x, y, z from the residuals (NaN where the
        method gives none).
    covariance_mm2 : ndarray, shape (3, 3)
        Covariance of ``point_mm`` (NaN where the method gives none).
    normals : ndarray, shape (3, 3)
        Unit normals of the three faces (rows), pointing out of the jig.
    inliers : tuple of int
        Points used per face.
    rms_mm : float
        RMS point-to-plane distance of the points used.
    method : str
        ``"perpendicular-planes"``, ``"independent-planes"`` or ``"seed"``.
    noise_mm : ndarray, shape (3,)
        Point-to-plane noise per face (1 sigma).
    face_angles_deg : ndarray, shape (3,)
        Angles between independently fitted face normals (faces 0-1, 0-2,
        1-2); 90 deg for a square jig.
    """

    point_mm: np.ndarray
    sigma_mm: np.ndarray
    covariance_mm2: np.ndarray
    normals: np.ndarray
    inliers: tuple
    rms_mm: float
    method: str
    noise_mm: np.ndarray
    face_angles_deg: np.ndarray


def check_points(points_mm) -> np.ndarray:
    """A point cloud as a finite float (N, 3) array, or a DataError naming what is wrong."""
    try:
        P = np.asarray(points_mm, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"`points_mm` must be numbers, shape (N, 3): {exc}") from exc
    if P.ndim != 2 or P.shape[1] != 3:
        raise DataError(f"`points_mm` must have shape (N, 3), got {P.shape}")
    if P.shape[0] == 0:
        raise InsufficientDataError("`points_mm` is an empty point cloud: no jig to find")
    finite = np.isfinite(P).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise DataError(
            f"`points_mm` has {bad.size} points with NaN or infinite coordinates (first at row {bad[0]}); "
            "drop invalid pixels before looking for the jig"
        )
    return P


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rotation(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of the rotation vector ``w``."""
    a = float(np.linalg.norm(w))
    K = _skew(w)
    if a < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(a) / a * K + (1.0 - math.cos(a)) / (a * a) * (K @ K)


def _truncated_variance(g: float) -> float:
    """Variance of a unit normal variable restricted to ``|x| < g``."""
    phi = math.exp(-0.5 * g * g) / math.sqrt(2.0 * math.pi)
    return 1.0 - 2.0 * g * phi / math.erf(g / math.sqrt(2.0))


# ---------------------------------------------------------------- voxel planes


@dataclass(frozen=True)
class _Voxels:
    n: np.ndarray  # (V,) points
    s1: np.ndarray  # (V, 3) sum of q (q = p - origin)
    s2: np.ndarray  # (V, 3, 3) sum of q q^T
    centroid: np.ndarray  # (V, 3) in q
    normal: np.ndarray  # (V, 3)
    thickness: np.ndarray  # (V,) RMS distance to the voxel plane


def _voxel_planes(Q: np.ndarray, voxel_mm: float, min_points: int) -> tuple[_Voxels, np.ndarray]:
    """Moment sums and principal planes of the occupied voxels (Q: points relative to their minimum)."""
    dims = np.floor(Q.max(axis=0) / voxel_mm).astype(np.int64) + 1
    if float(np.prod(dims.astype(float))) > 2.0**62:
        raise DataError(f"the cloud spans {Q.max(axis=0).round(1).tolist()} mm: too many {voxel_mm:g} mm voxels to number")
    ijk = np.floor(Q / voxel_mm).astype(np.int64)
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    _, inv = np.unique(key, return_inverse=True)
    nv = int(inv.max()) + 1
    cnt = np.bincount(inv, minlength=nv).astype(float)
    s1 = np.stack([np.bincount(inv, Q[:, a], nv) for a in range(3)], axis=1)
    s2 = np.empty((nv, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            s2[:, a, b] = s2[:, b, a] = np.bincount(inv, Q[:, a] * Q[:, b], nv)
    keep = cnt >= min_points
    cnt, s1, s2 = cnt[keep], s1[keep], s2[keep]
    mean = s1 / cnt[:, None]
    cov = s2 / cnt[:, None, None] - mean[:, :, None] * mean[:, None, :]
    lam, vec = np.linalg.eigh(cov)
    vox = _Voxels(cnt, s1, s2, mean, vec[:, :, 0], np.sqrt(np.maximum(lam[:, 0], 0.0)))
    return vox, lam


def _pooled_plane(vox: _Voxels, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares plane (normal, centroid) of the points of voxels ``idx``."""
    n = vox.n[idx].sum()
    m = vox.s1[idx].sum(axis=0) / n
    C = vox.s2[idx].sum(axis=0) / n - np.outer(m, m)
    _, vec = np.linalg.eigh(C)
    return vec[:, 0], m


@dataclass(frozen=True)
class _Plane:
    normal: np.ndarray
    centroid: np.ndarray  # in q
    voxels: np.ndarray  # indices into the planar voxels
    points: int


def _segment_planes(vox: _Voxels, sel: np.ndarray, *, noise: float, voxel_mm: float, cos_tol: float,
                    min_points: int, max_planes: int, max_hypotheses: int = 256) -> list[_Plane]:
    """Sequential plane extraction over the planar voxels ``sel``."""
    remaining = np.asarray(sel)
    planes: list[_Plane] = []
    loose = 0.25 * voxel_mm  # a single voxel's normal, extrapolated across the part
    tight = 4.0 * noise + 1e-6 * voxel_mm
    while remaining.size and len(planes) < max_planes:
        N = vox.normal[remaining]
        M = vox.centroid[remaining]
        W = vox.n[remaining]
        step = max(1, int(math.ceil(remaining.size / max_hypotheses)))
        hyp = np.arange(0, remaining.size, step)
        agree = np.abs(N[hyp] @ N.T) >= cos_tol
        dist = np.abs(N[hyp] @ M.T - np.einsum("hk,hk->h", N[hyp], M[hyp])[:, None])
        score = ((agree & (dist <= loose)) * W).sum(axis=1)
        best = int(hyp[np.argmax(score)])
        members = np.flatnonzero(agree[np.argmax(score)] & (dist[np.argmax(score)] <= loose))
        if members.size == 0:
            members = np.array([best])
        for gate in (loose, tight, tight):
            normal, centroid = _pooled_plane(vox, remaining[members])
            members = np.flatnonzero((np.abs(N @ normal) >= cos_tol) & (np.abs((M - centroid) @ normal) <= gate))
            if members.size == 0:
                break
        if members.size == 0:
            remaining = np.delete(remaining, best)
            continue
        count = int(W[members].sum())
        if count < min_points:
            break
        normal, centroid = _pooled_plane(vox, remaining[members])
        planes.append(_Plane(normal, centroid, remaining[members], count))
        remaining = np.delete(remaining, members)
    return planes


def _corner_triple(planes: list[_Plane], sin_tol: float, min_points: int, tol_deg: float) -> tuple[int, int, int]:
    best, best_score = None, -1
    for tri in combinations(range(len(planes)), 3):
        N = np.array([planes[i].normal for i in tri])
        G = np.abs(N @ N.T)
        if G[0, 1] > sin_tol or G[0, 2] > sin_tol or G[1, 2] > sin_tol:
            continue
        score = sum(planes[i].points for i in tri)
        if score > best_score:
            best, best_score = tri, score
    if best is None:
        counts = ", ".join(str(p.points) for p in planes) or "none"
        if len(planes) < 3:
            raise InsufficientDataError(
                f"only {len(planes)} face(s) visible: {len(planes)} plane(s) with >= {min_points} points "
                f"(points per plane: {counts}); the jig's corner needs three faces"
            )
        raise InsufficientDataError(
            f"no three of the {len(planes)} planes found (points per plane: {counts}) are mutually "
            f"perpendicular within {tol_deg:g} deg: the jig's three faces are not all visible"
        )
    return best


def _corner_faces(Q, voxel_mm, *, min_voxel_points, min_face_points, angle_tol_deg, perpendicular_tol_deg,
                  max_planes) -> tuple[_Voxels, list[_Plane], float]:
    """Steps 1-3: voxel planes, plane segmentation, the corner's three faces; and the noise estimate."""
    vox, lam = _voxel_planes(Q, voxel_mm, min_voxel_points)
    # noise: the median thickness of voxels spread like a surface patch
    patch = np.sqrt(np.maximum(lam[:, 1], 0.0)) > voxel_mm / 8.0
    if not patch.any():
        raise InsufficientDataError(
            f"no voxel of {voxel_mm:g} mm holds a surface patch of >= {min_voxel_points} points: "
            "the cloud is too sparse for `voxel_mm` (make it larger)"
        )
    corr = np.sqrt(vox.n / np.maximum(vox.n - 3.0, 1.0))
    noise = float(np.median((vox.thickness * corr)[patch]))
    planar = np.flatnonzero(patch & (vox.thickness <= 3.0 * noise + 1e-9 * voxel_mm))
    planes = _segment_planes(
        vox, planar, noise=noise, voxel_mm=voxel_mm, cos_tol=math.cos(math.radians(angle_tol_deg)),
        min_points=min_face_points, max_planes=max_planes,
    )
    tri = _corner_triple(planes, math.sin(math.radians(perpendicular_tol_deg)), min_face_points, perpendicular_tol_deg)
    return vox, [planes[i] for i in tri], noise


# ---------------------------------------------------------------- joint fit


def _face_moments(U: np.ndarray, face: np.ndarray):
    """Per-face count, sum of u and sum of u u^T of the points ``U`` (face -1: unused)."""
    n = np.zeros(3)
    s1 = np.zeros((3, 3))
    s2 = np.zeros((3, 3, 3))
    for k in range(3):
        Uk = U[face == k]
        n[k] = Uk.shape[0]
        s1[k] = Uk.sum(axis=0)
        s2[k] = Uk.T @ Uk
    return n, s1, s2


def _gauss_newton(Nrm, e, n, s1, s2, var, max_iter=30):
    """Perpendicular corner: rows of ``Nrm`` (orthonormal) and the corner offset ``e`` from the moments' origin.

    Minimises ``sum_k sum_i (n_k . (u_i - e))^2 / var_k`` over a rotation of
    the frame and ``e``. Returns the frame, ``e``, the normal matrix ``H`` and
    the per-face sums of squared residuals.
    """
    H = np.eye(6)
    for _ in range(max_iter):
        H = np.zeros((6, 6))
        g = np.zeros(6)
        for k in range(3):
            nk = Nrm[k]
            m1 = s1[k] - n[k] * e
            M = s2[k] - np.outer(s1[k], e) - np.outer(e, s1[k]) + n[k] * np.outer(e, e)
            K = _skew(nk)
            w = 1.0 / var[k]
            H[:3, :3] += w * K @ M @ K.T
            cross = -w * np.outer(K @ m1, nk)
            H[:3, 3:] += cross
            H[3:, :3] += cross.T
            H[3:, 3:] += w * n[k] * np.outer(nk, nk)
            g[:3] += w * K @ M @ nk
            g[3:] += -w * nk * (nk @ m1)
        step = np.linalg.solve(H, -g)
        Nrm = Nrm @ _rotation(step[:3]).T
        e = e + step[3:]
        if np.linalg.norm(step[3:]) < 1e-10 and np.linalg.norm(step[:3]) < 1e-13:
            break
    ssr = np.empty(3)
    for k in range(3):
        M = s2[k] - np.outer(s1[k], e) - np.outer(e, s1[k]) + n[k] * np.outer(e, e)
        ssr[k] = Nrm[k] @ M @ Nrm[k]
    return Nrm, e, H, ssr


def _independent_planes(n, s1, s2, var, e_ref, outward):
    """Per-face TLS planes, their intersection (eq. (2)) and its covariance by propagation.

    Normals take the signs of the rows of ``outward``.
    """
    normals, cents, Cn = [], [], []
    for k in range(3):
        m = s1[k] / n[k]
        S = s2[k] - n[k] * np.outer(m, m)  # scatter about the centroid
        lam, vec = np.linalg.eigh(S)
        normals.append(vec[:, 0] if vec[:, 0] @ outward[k] >= 0 else -vec[:, 0])
        cents.append(m)
        # covariance of the normal: var / scatter along the two in-plane axes
        T = vec[:, 1:]
        Cn.append(var[k] * T @ np.diag(1.0 / lam[1:]) @ T.T)
    Nrm = np.array(normals)
    cents = np.array(cents)
    corner = plane_intersection(Nrm, cents)
    # N dc = dn_k.(m_k - c) + n_k.dm_k, rows independent
    v = np.array([(cents[k] - corner) @ Cn[k] @ (cents[k] - corner) + var[k] / n[k] for k in range(3)])
    Ninv = np.linalg.inv(Nrm)
    cov = Ninv @ np.diag(v) @ Ninv.T
    ssr = np.array([Nrm[k] @ (s2[k] - n[k] * np.outer(cents[k], cents[k])) @ Nrm[k] for k in range(3)])
    return Nrm, corner + e_ref, cov, ssr


def _angles_deg(Nrm: np.ndarray) -> np.ndarray:
    d = np.clip([abs(Nrm[0] @ Nrm[1]), abs(Nrm[0] @ Nrm[2]), abs(Nrm[1] @ Nrm[2])], 0.0, 1.0)
    return np.degrees(np.arccos(d))


# ---------------------------------------------------------------- the finder


def feature_point(
    points_mm,
    *,
    voxel_mm: float = 5.0,
    min_voxel_points: int = 6,
    min_face_points: int = 50,
    angle_tol_deg: float = 10.0,
    perpendicular_tol_deg: float = 5.0,
    max_planes: int = 8,
    gate_sigmas: float = 3.5,
    max_rounds: int = 8,
    perpendicular: bool = True,
) -> JigFeature:
    """Find the corner jig's feature point in a point cloud (see the module docstring).

    Parameters
    ----------
    points_mm : array_like, shape (N, 3)
        The scan, mm, any frame. Must be finite.
    voxel_mm : float
        Voxel edge for plane segmentation, about a tenth of the jig's edge;
        each face needs voxels with ``min_voxel_points`` points. If three
        faces are not found, voxels twice as large are tried once.
    min_voxel_points : int
        Points for a voxel to get a plane (>= 4).
    min_face_points : int
        Points (in planar voxels) for a plane to count as a face.
    angle_tol_deg : float
        Voxel normals within this angle belong to the same plane.
    perpendicular_tol_deg : float
        The corner's faces must be perpendicular within this.
    max_planes : int
        Planes extracted before the corner is chosen among them.
    gate_sigmas : float
        Points farther from their face than this many noise sigmas are left out.
    max_rounds : int
        Rounds of assignment and fitting.
    perpendicular : bool
        Fit the faces as one perpendicular corner (default) or as three
        independent planes.

    Returns
    -------
    JigFeature

    Raises
    ------
    DataError
        Not an (N, 3) array, non-finite coordinates.
    InsufficientDataError
        Empty cloud, or fewer than three mutually perpendicular faces found
        (the message says how many planes and how many points each).
    ConfigError
        A parameter out of range (named).
    """
    voxel_mm = finite_number(voxel_mm, "voxel_mm", positive=True)
    min_voxel_points = finite_number(min_voxel_points, "min_voxel_points", positive=True, integer=True)
    if min_voxel_points < 4:
        raise ConfigError(f"`min_voxel_points` must be >= 4 (a plane through 3 points has no noise), got {min_voxel_points}")
    min_face_points = finite_number(min_face_points, "min_face_points", positive=True, integer=True)
    angle_tol_deg = finite_number(angle_tol_deg, "angle_tol_deg", positive=True)
    perpendicular_tol_deg = finite_number(perpendicular_tol_deg, "perpendicular_tol_deg", positive=True)
    if angle_tol_deg >= 45 or perpendicular_tol_deg >= 45:
        raise ConfigError("`angle_tol_deg` and `perpendicular_tol_deg` must be < 45 deg")
    max_planes = finite_number(max_planes, "max_planes", positive=True, integer=True)
    gate_sigmas = finite_number(gate_sigmas, "gate_sigmas", positive=True)
    if gate_sigmas < 2:
        raise ConfigError(f"`gate_sigmas` must be >= 2 (fewer cuts the faces' own points), got {gate_sigmas}")
    max_rounds = finite_number(max_rounds, "max_rounds", positive=True, integer=True)
    P = check_points(points_mm)
    if P.shape[0] < 3 * min_face_points:
        raise InsufficientDataError(
            f"{P.shape[0]} points cannot hold three faces of >= {min_face_points} points (`min_face_points`)"
        )

    origin = P.min(axis=0)
    Q = P - origin
    # a face seen at a grazing angle, or a noisy scan, may leave too few points per
    # voxel: one retry with voxels twice as large before giving up
    first_error = None
    for size in (voxel_mm, 2.0 * voxel_mm):
        try:
            vox, faces, noise = _corner_faces(
                Q, size, min_voxel_points=min_voxel_points, min_face_points=min_face_points,
                angle_tol_deg=angle_tol_deg, perpendicular_tol_deg=perpendicular_tol_deg, max_planes=max_planes,
            )
            voxel_mm = size
            break
        except InsufficientDataError as exc:
            first_error = first_error or exc
    else:
        raise InsufficientDataError(f"{first_error} (also with {2 * voxel_mm:g} mm voxels)") from first_error
    Nrm = np.array([f.normal for f in faces])
    corner = plane_intersection(Nrm, np.array([f.centroid for f in faces]))
    # outward normals: the other faces' points lie behind each face
    for k in range(3):
        side = sum(
            float(((vox.centroid[faces[j].voxels] - corner) @ Nrm[k]) @ vox.n[faces[j].voxels]) for j in range(3) if j != k
        )
        if side > 0:
            Nrm[k] = -Nrm[k]
    # how far each face reaches from the corner: its farthest planar voxel, plus the
    # voxels lost where two faces share one (edges, tips)
    reach = np.array([np.linalg.norm(vox.centroid[f.voxels] - corner, axis=1).max() + 3.0 * voxel_mm for f in faces])
    face_noise = np.full(3, max(noise, 1e-9 * voxel_mm))
    # start from the nearest perpendicular frame (polar decomposition keeps the signs)
    U, _, Vt = np.linalg.svd(Nrm)
    frame = U @ Vt if perpendicular else Nrm
    # the moments are taken about a fixed reference near the corner (no cancellation)
    # (the corner moves by far less than the margin in `reach` while fitting, so the
    # distances from this first corner decide once which points can belong to a face)
    ref = corner.copy()
    Qr = Q - ref
    r2 = np.einsum("ij,ij->i", Qr, Qr)
    cand = r2 <= reach.max() ** 2
    U, r2 = Qr[cand], r2[cand]
    e = np.zeros(3)
    face = np.full(U.shape[0], -1)
    cov = np.full((3, 3), np.nan)
    for _ in range(max_rounds):
        D = (U - e) @ frame.T  # signed distances to the three planes
        k = np.argmin(np.abs(D), axis=1)
        dk = np.take_along_axis(D, k[:, None], axis=1)[:, 0]
        inside = (D <= gate_sigmas * face_noise).all(axis=1)
        new_face = np.where((np.abs(dk) <= gate_sigmas * face_noise[k]) & inside & (r2 <= reach[k] ** 2), k, -1)
        n, s1, s2 = _face_moments(U, new_face)
        if (n < 4).any():
            raise InsufficientDataError(f"a face kept fewer than 4 points after gating ({n.astype(int).tolist()})")
        var = face_noise**2
        if perpendicular:
            frame, e, H, ssr = _gauss_newton(frame, e, n, s1, s2, var)
            cov = np.linalg.inv(H)[3:, 3:]
        else:
            frame, c_abs, cov, ssr = _independent_planes(n, s1, s2, var, ref + origin, frame)
            e = c_abs - origin - ref
        # face noise from the gated residuals, undoing the truncation at the gate
        dof = n - (2.0 if perpendicular else 3.0)
        new_noise = np.sqrt(ssr / np.maximum(dof, 1.0) / _truncated_variance(gate_sigmas))
        # settled: hardly a point changed face and the noise is steady (the next round would agree)
        changed = int(np.count_nonzero(new_face != face))
        settled = changed <= 1e-4 * n.sum() and np.allclose(new_noise, face_noise, rtol=1e-2)
        face, face_noise = new_face, np.maximum(new_noise, 1e-12)
        if settled:
            break
    # the last fit weighted the faces by the noise it started from; rescale to the noise found
    if perpendicular:
        frame, e, H, ssr = _gauss_newton(frame, e, n, s1, s2, face_noise**2)
        cov = np.linalg.inv(H)[3:, 3:]
    else:
        frame, c_abs, cov, ssr = _independent_planes(n, s1, s2, face_noise**2, ref + origin, frame)
        e = c_abs - origin - ref
    indep = frame if not perpendicular else _independent_planes(n, s1, s2, face_noise**2, ref + origin, frame)[0]
    total = float(n.sum())
    return JigFeature(
        point_mm=origin + ref + e,
        sigma_mm=np.sqrt(np.diag(cov)),
        covariance_mm2=cov,
        normals=frame.copy(),
        inliers=tuple(int(x) for x in n),
        rms_mm=float(math.sqrt(ssr.sum() / total)),
        method="perpendicular-planes" if perpendicular else "independent-planes",
        noise_mm=face_noise.copy(),
        face_angles_deg=_angles_deg(indep),
    )
