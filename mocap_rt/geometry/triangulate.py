"""Triangulation: 3D points and line directions from two or more calibrated views.

Owns the one-call entry for points seen by calibrated cameras (``triangulate_points``, on
the compiled kernel of ``ray_triangulator``), the NumPy solvers for rays and DLT, and 3D
line directions.

Seed digest A.3 (eq. 5, the two-ray closest point in normalised Plücker form),
B.2 (3D line direction from two views) and B.3 (linear N-view point).

Conventions
-----------
* World frame: right-handed, +Z up, metres (see :mod:`mocap_rt.geometry.camera`).
* Every function is vectorised over N points. NaN anywhere in a view's observation
  (pixel, ray origin/direction) or a NaN / zero weight marks that view as missing.
* Outputs are NaN where fewer than two valid views remain, or where the views are
  degenerate (parallel rays, singular normal equations).
* Shapes: ``C`` cameras (views), ``N`` points. Arrays are float64.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from mocap_rt.geometry.camera import MIN_DEPTH_M, Camera, as_points

logger = logging.getLogger(__name__)

# Two unit rays whose cross product is shorter than this (sin of the angle between
# them, i.e. ~1e-7 rad) are treated as parallel: no finite closest point.
PARALLEL_SIN_TOL = 1e-7
# Smallest-to-largest eigenvalue ratio of the 3x3 normal matrix below which an N-view
# system is singular (all rays parallel or fewer than two effective views).
SINGULAR_EIG_RATIO = 1e-14

__all__ = [
    "closest_point_ray1",
    "midpoint_two_rays",
    "triangulate_rays",
    "triangulate_dlt",
    "triangulate_points",
    "triangulate_with_prior",
    "refine_points",
    "reprojection_residuals",
    "line_direction_two_views",
]


# ----------------------------------------------------------------------------- checks
def _views(a: np.ndarray, name: str, last: int) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != last:
        raise ValueError(f"{name} must have shape (C, N, {last}), got {np.shape(a)}")
    return arr


def _weights(weights: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    """(C, N) float64 weights; None -> ones. NaN counts as missing (weight 0)."""
    if weights is None:
        return np.ones(shape)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != shape:
        raise ValueError(f"weights must have shape {shape} (C, N), got {w.shape}")
    if np.any(w < 0):
        raise ValueError("weights must be >= 0")
    if np.any(np.isposinf(w)):
        raise ValueError("weights must be finite")
    return np.where(np.isnan(w), 0.0, w)


def _unit(d: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- two rays
def closest_point_ray1(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Point on ray 1 closest to ray 2 (seed digest A.3, eq. 5).

    o1, d1, o2, d2 : (N, 3) float64; ray origins (metres, world) and directions
        (any length, normalised here).
    Returns (N, 3) float64 metres; NaN for parallel rays or NaN input.

    Uses the paper's normalised Plücker form
    ``T = o1 - ((d1 x m2).(o1 x m2 - n2)) / |d1 x m2|^2 d1`` with
    ``m = d / sqrt(1 + |o x d|^2)``, ``n = (o x d) / sqrt(1 + |o x d|^2)``.
    """
    o1, d1, o2, d2 = (as_points(v, 3, n) for v, n in ((o1, "o1"), (d1, "d1"), (o2, "o2"), (d2, "d2")))
    d1, d2 = _unit(d1), _unit(d2)
    moment2 = np.cross(o2, d2)                                      # (N, 3)
    scale2 = np.sqrt(1.0 + np.einsum("ij,ij->i", moment2, moment2))[:, None]
    m2, n2 = d2 / scale2, moment2 / scale2                           # normalised Plücker
    d1xm2 = np.cross(d1, m2)                                         # (N, 3)
    denom = np.einsum("ij,ij->i", d1xm2, d1xm2)                      # (N,)
    numer = np.einsum("ij,ij->i", d1xm2, np.cross(o1, m2) - n2)
    # |d1 x m2|^2 = sin^2(angle) / scale2^2 for unit d1, d2
    parallel = ~(denom * scale2[:, 0] ** 2 > PARALLEL_SIN_TOL**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        T = o1 - (numer / denom)[:, None] * d1
    T[parallel] = np.nan
    return T


def midpoint_two_rays(o1: np.ndarray, d1: np.ndarray, o2: np.ndarray,
                      d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric midpoint of the two mutually closest points of two rays.

    o1, d1, o2, d2 : (N, 3) float64 (see :func:`closest_point_ray1`).
    Returns ``(points (N, 3) metres, gap_m (N,) metres)``: the midpoint and the
    distance between the rays (their common perpendicular); NaN where parallel.
    """
    p1 = closest_point_ray1(o1, d1, o2, d2)
    p2 = closest_point_ray1(o2, d2, o1, d1)
    return 0.5 * (p1 + p2), np.linalg.norm(p1 - p2, axis=1)


# ----------------------------------------------------------------------------- N rays
def _solve_normal(A: np.ndarray, b: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Solve batched 3x3 symmetric systems A x = b where ``ok`` and well conditioned."""
    out = np.full(b.shape, np.nan)
    if not np.any(ok):
        return out
    eig = np.linalg.eigvalsh(A[ok])                                  # (M, 3) ascending
    good = eig[:, 0] > SINGULAR_EIG_RATIO * np.maximum(eig[:, 2], np.finfo(float).tiny)
    idx = np.flatnonzero(ok)[good]
    if idx.size:
        out[idx] = np.linalg.solve(A[idx], b[idx][..., None])[..., 0]
    return out


def triangulate_rays(origins: np.ndarray, dirs: np.ndarray, weights: np.ndarray | None = None,
                     prior: np.ndarray | None = None, prior_weight: float = 0.0) -> np.ndarray:
    """Weighted least-squares point closest to C rays, for N points at once.

    origins : (C, N, 3) float64 ray origins, metres, world frame.
    dirs : (C, N, 3) float64 ray directions (normalised here).
    weights : (C, N) float64 >= 0 or None (all 1); 0/NaN = view missing.
    prior, prior_weight : (N, 3) points (NaN rows: none) each point is also drawn to, with
        ``lam = prior_weight * sum_c w_c`` (its views' summed weight): where the rays meet near
        parallel the prior decides the point along them and the rays the rest; where they are
        well conditioned it moves the point by about ``prior_weight`` of its distance.
    Returns (N, 3) float64 metres minimising ``sum_c w_c |(I - d d^T)(X - o_c)|^2`` (``+ lam
    |X - prior|^2``); NaN where fewer than two valid views or the rays are (nearly) parallel.
    """
    o = _views(origins, "origins", 3)
    d = _views(dirs, "dirs", 3)
    if o.shape != d.shape:
        raise ValueError(f"origins {o.shape} and dirs {d.shape} must have the same shape")
    C, N, _ = o.shape
    w = _weights(weights, (C, N))
    d = _unit(d)
    valid = np.isfinite(o).all(-1) & np.isfinite(d).all(-1) & (w > 0)  # (C, N)
    w = np.where(valid, w, 0.0)
    o = np.where(valid[..., None], o, 0.0)
    d = np.where(valid[..., None], d, 0.0)
    # A = sum w (I - d d^T); b = sum w (o - d (d.o))
    ddT = d[..., :, None] * d[..., None, :]                          # (C, N, 3, 3)
    A = np.einsum("cn,cnij->nij", w, np.eye(3) - ddT)                # (N, 3, 3)
    proj = o - d * np.einsum("cni,cni->cn", d, o)[..., None]         # (C, N, 3)
    b = np.einsum("cn,cni->ni", w, proj)                             # (N, 3)
    if prior is not None and prior_weight > 0:
        prior = np.asarray(prior, np.float64).reshape(N, 3)
        lam = np.where(np.isfinite(prior).all(-1), prior_weight * w.sum(axis=0), 0.0)   # (N,)
        A = A + lam[:, None, None] * np.eye(3)
        b = b + lam[:, None] * np.nan_to_num(prior)
    return _solve_normal(A, b, valid.sum(axis=0) >= 2)


def triangulate_dlt(P: np.ndarray, uv: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Linear N-view triangulation (seed digest B.3), weighted, vectorised.

    P : (C, 3, 4) float64 projection matrices (pixels from world metres).
    uv : (C, N, 2) float64 *undistorted* pixels; NaN = not seen.
    weights : (C, N) float64 >= 0 or None; 0/NaN = view missing.
    Returns (N, 3) float64 metres, world frame; NaN where < 2 valid views or degenerate.

    Each view gives the two plane equations ``(u p3 - p1) . [X, 1] = 0`` and
    ``(v p3 - p2) . [X, 1] = 0``; the stacked system ``M V = b`` is solved by least
    squares, ``V = (M^T M)^-1 M^T b``. Each P is first scaled so that ``|p3[:3]| = 1``:
    then each residual is (depth x pixel error), independent of P's arbitrary scale.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (3, 4):
        raise ValueError(f"P must have shape (C, 3, 4), got {P.shape}")
    uv = _views(uv, "uv", 2)
    C, N, _ = uv.shape
    if P.shape[0] != C:
        raise ValueError(f"P has {P.shape[0]} views but uv has {C}")
    if not np.all(np.isfinite(P)):
        raise ValueError("P has NaN or inf")
    row_norm = np.linalg.norm(P[:, 2, :3], axis=1)
    if np.any(row_norm <= 0):
        raise ValueError("P has a zero third row: not a projection matrix")
    P = P / row_norm[:, None, None]
    w = _weights(weights, (C, N))
    valid = np.isfinite(uv).all(-1) & (w > 0)                        # (C, N)
    w = np.where(valid, w, 0.0)
    uv = np.where(valid[..., None], uv, 0.0)
    # rows (C, N, 2, 4): u p3 - p1, v p3 - p2
    rows = uv[..., :, None] * P[:, None, 2:3, :] - P[:, None, :2, :]
    M, b = rows[..., :3], -rows[..., 3]                              # (C,N,2,3), (C,N,2)
    A = np.einsum("cn,cnki,cnkj->nij", w, M, M)                      # (N, 3, 3)
    rhs = np.einsum("cn,cnki,cnk->ni", w, M, b)                      # (N, 3)
    return _solve_normal(A, rhs, valid.sum(axis=0) >= 2)


# ----------------------------------------------------------------------------- cameras
def _check_cameras(cameras: Sequence[Camera], uv: np.ndarray) -> np.ndarray:
    uv = _views(uv, "uv", 2)
    if len(cameras) != uv.shape[0]:
        raise ValueError(f"{len(cameras)} cameras but uv has {uv.shape[0]} views")
    return uv


def triangulate_points(cameras: Sequence[Camera], uv: np.ndarray, weights: np.ndarray | None = None,
                       refine: bool = False) -> np.ndarray:
    """3D points from distorted pixel observations in C calibrated cameras.

    cameras : C cameras, in the order of ``uv``'s first axis.
    uv : (C, N, 2) float64 pixels as seen in the images (distorted); NaN = not seen.
    weights : (C, N) float64 >= 0 or None; 0/NaN = view missing.
    refine : also minimise the reprojection error (:func:`refine_points`).
    Returns (N, 3) float64 metres, world frame; NaN where < 2 valid views.

    The one entry point for points seen by calibrated cameras: pixels are undistorted into
    world rays and intersected by weighted least squares in the compiled kernel of
    :class:`~mocap_rt.geometry.ray_triangulator.RayTriangulator` (build that once instead
    for a fixed rig called every frame; :func:`triangulate_rays` is the same least squares
    in NumPy for rays from anywhere).
    """
    from mocap_rt.geometry.ray_triangulator import RayTriangulator

    uv = _check_cameras(cameras, uv)
    X = RayTriangulator(cameras)(uv, _weights(weights, uv.shape[:2]))
    if refine:
        X = refine_points(cameras, uv, X, weights)
    return X


def triangulate_with_prior(cameras: Sequence[Camera], uv: np.ndarray, weights: np.ndarray, prior: np.ndarray,
                           prior_weight: float) -> np.ndarray:
    """``triangulate_rays`` with a prior (module doc; its ``prior``, ``prior_weight``) for points
    seen by calibrated cameras: uv (C, N, 2) distorted pixels (NaN: not seen), weights (C, N),
    prior (N, 3). Returns (N, 3) metres. NumPy: for the few points a prior is wanted for (the
    tracker's near-parallel cues, ``ray_triangulator.ill_conditioned``)."""
    uv = _check_cameras(cameras, uv)
    rays = [cam.rays(p) for cam, p in zip(cameras, uv)]
    return triangulate_rays(np.stack([o for o, _ in rays]), np.stack([d for _, d in rays]),
                            _weights(weights, uv.shape[:2]), prior, prior_weight)


def _project_clamped(cam: Camera, X: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 2) distorted pixels, depth clamped positive (for the optimiser)."""
    pc = X @ cam.R.T + cam.t
    z = np.maximum(pc[:, 2:3], MIN_DEPTH_M)
    xy = cam.distort_normalized(pc[:, :2] / z)
    return xy @ cam.K[:2, :2].T + cam.K[:2, 2]


def refine_points(cameras: Sequence[Camera], uv: np.ndarray, X0: np.ndarray,
                  weights: np.ndarray | None = None, *, max_nfev: int = 50) -> np.ndarray:
    """Refine 3D points by minimising weighted reprojection error (scipy least squares).

    cameras : C cameras; uv : (C, N, 2) float64 distorted pixels, NaN = not seen.
    X0 : (N, 3) float64 metres, starting points (e.g. from :func:`triangulate_points`).
    weights : (C, N) float64 >= 0 or None; the cost is ``sum_c w_c |proj_c(X) - uv_c|^2``.
    max_nfev : evaluation budget of the optimiser.
    Returns (N, 3) float64 metres; NaN where X0 is NaN or fewer than two valid views.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    uv = _check_cameras(cameras, uv)
    C, N, _ = uv.shape
    X0 = as_points(X0, 3, "X0")
    if X0.shape[0] != N:
        raise ValueError(f"X0 has {X0.shape[0]} points but uv has {N}")
    w = _weights(weights, (C, N))
    valid = np.isfinite(uv).all(-1) & (w > 0)
    todo = np.isfinite(X0).all(-1) & (valid.sum(axis=0) >= 2)
    out = np.full((N, 3), np.nan)
    idx = np.flatnonzero(todo)
    if idx.size == 0:
        return out
    sw = np.sqrt(np.where(valid, w, 0.0))[:, idx]                    # (C, M)
    target = np.where(valid[..., None], uv, 0.0)[:, idx]             # (C, M, 2)
    M = idx.size

    def residuals(x: np.ndarray) -> np.ndarray:
        X = x.reshape(M, 3)
        r = np.stack([_project_clamped(cam, X) for cam in cameras]) - target  # (C, M, 2)
        return (r * sw[..., None]).transpose(1, 0, 2).ravel()                 # point-major

    # Each point's residuals depend only on its own 3 coordinates.
    sparsity = lil_matrix((M * C * 2, M * 3), dtype=int)
    for m in range(M):
        sparsity[m * C * 2:(m + 1) * C * 2, m * 3:(m + 1) * 3] = 1
    result = least_squares(residuals, X0[idx].ravel(), jac_sparsity=sparsity, method="trf",
                           x_scale="jac", max_nfev=max_nfev)
    out[idx] = result.x.reshape(M, 3)
    return out


def reprojection_residuals(cameras: Sequence[Camera], X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Per-view reprojection error in pixels.

    cameras : C cameras; X : (N, 3) float64 metres, world; uv : (C, N, 2) distorted pixels.
    Returns (C, N) float64 pixel distances; NaN where the observation or the point is
    missing or the point is behind that camera.
    """
    uv = _check_cameras(cameras, uv)
    X = as_points(X, 3, "X")
    if X.shape[0] != uv.shape[1]:
        raise ValueError(f"X has {X.shape[0]} points but uv has {uv.shape[1]}")
    out = np.empty(uv.shape[:2])
    for c, cam in enumerate(cameras):
        proj, _ = cam.project(X)
        out[c] = np.linalg.norm(proj - uv[c], axis=1)
    return out


# ----------------------------------------------------------------------------- lines
def _pixel_ray(P: np.ndarray, u: float, v: float) -> np.ndarray:
    """Direction (3,) of the ray through pixel (u, v) of P, pointing in front of the camera.

    Seed digest B.2: the two planes ``(p1 - u p3).[X,1] = 0`` and ``(p2 - v p3).[X,1] = 0``
    meet in the ray; its direction is the cross product of their normals.
    """
    n_u = P[0, :3] - u * P[2, :3]
    n_v = P[1, :3] - v * P[2, :3]
    ray = np.cross(n_u, n_v)
    # In front: the depth p3[:3].ray has the sign of det(P[:, :3]) (positive for K R).
    if np.dot(P[2, :3], ray) * np.linalg.det(P[:, :3]) < 0:
        ray = -ray
    return ray / np.linalg.norm(ray)


def line_direction_two_views(P1: np.ndarray, a1: np.ndarray, b1: np.ndarray,
                             P2: np.ndarray, a2: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Unit 3D direction of a line seen in two views (seed digest B.2).

    P1, P2 : (3, 4) float64 projection matrices; a1, b1 : (2,) two undistorted pixels on
    the line's image in view 1, a2, b2 : (2,) likewise in view 2.
    Returns (3,) float64 unit vector ``N1 x N2`` with ``N_k`` the normal of the plane
    through camera k's centre and its image segment; oriented so that it points from
    a1's side towards b1's side as seen in view 1. NaN if any input is NaN or the line
    lies in an epipolar plane (the two planes coincide).
    """
    Ps = []
    for name, P in (("P1", P1), ("P2", P2)):
        P = np.asarray(P, dtype=np.float64)
        if P.shape != (3, 4):
            raise ValueError(f"{name} must have shape (3, 4), got {P.shape}")
        if abs(np.linalg.det(P[:, :3])) == 0 or not np.all(np.isfinite(P)):
            raise ValueError(f"{name} is not a finite projection matrix with invertible left 3x3")
        Ps.append(P)
    pts = []
    for name, p in (("a1", a1), ("b1", b1), ("a2", a2), ("b2", b2)):
        p = np.asarray(p, dtype=np.float64).ravel()
        if p.shape != (2,):
            raise ValueError(f"{name} must have shape (2,), got {np.shape(p)}")
        pts.append(p)
    if not all(np.all(np.isfinite(p)) for p in pts):
        return np.full(3, np.nan)
    ra1, rb1 = _pixel_ray(Ps[0], *pts[0]), _pixel_ray(Ps[0], *pts[1])
    ra2, rb2 = _pixel_ray(Ps[1], *pts[2]), _pixel_ray(Ps[1], *pts[3])
    n1 = np.cross(ra1, rb1)
    n2 = np.cross(ra2, rb2)
    direction = np.cross(n1, n2)
    norm = np.linalg.norm(direction)
    if not norm > PARALLEL_SIN_TOL * np.linalg.norm(n1) * np.linalg.norm(n2):
        return np.full(3, np.nan)
    direction /= norm
    # Orientation: moving along the line from a towards b, the viewing ray sweeps from
    # ra1 towards rb1, so the direction's part orthogonal to ra1 agrees with rb1's.
    if np.dot(direction, rb1 - np.dot(rb1, ra1) * ra1) < 0:
        direction = -direction
    return direction
