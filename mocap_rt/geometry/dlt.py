"""Camera calibration by the Direct Linear Transform (seed digest B.1).

From N >= 6 non-coplanar 3D points (metres, world frame: right-handed, +Z up) and
their pixels, the 3x4 projection matrix ``P ~ K [R | t]`` is the least-squares null
vector of the 2N x 12 DLT system, computed on Hartley-normalised coordinates
(Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., §4.4 and §7.1). ``P`` is
then split into intrinsics and pose by an RQ decomposition (H&Z §6.2.4) with positive
focal lengths and a proper rotation. Lens distortion is not modelled (pixels should
be undistorted, or the lens close to a pinhole).
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.linalg

from mocap_rt.geometry.camera import Camera

logger = logging.getLogger(__name__)

MIN_POINTS = 6
# A point set whose smallest principal spread is below this fraction of its largest
# is coplanar (or collinear) for the DLT: the 12 unknowns are then not determined.
COPLANAR_RATIO = 1e-6
# Second-smallest to largest singular value of the normalised DLT matrix below which
# the null space is more than one-dimensional (degenerate configuration).
RANK_RATIO = 1e-10

__all__ = [
    "CalibrationError",
    "dlt_projection_matrix",
    "decompose_projection",
    "calibrate_dlt",
    "projection_residuals",
]


class CalibrationError(ValueError):
    """Calibration input that cannot give a camera (too few, coplanar, degenerate, NaN)."""


def _check_correspondences(X: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise CalibrationError(f"3D points must have shape (N, 3), got {X.shape}")
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise CalibrationError(f"pixels must have shape (N, 2), got {uv.shape}")
    if X.shape[0] != uv.shape[0]:
        raise CalibrationError(f"{X.shape[0]} 3D points but {uv.shape[0]} pixels")
    bad = ~(np.isfinite(X).all(1) & np.isfinite(uv).all(1))
    if np.any(bad):
        rows = np.flatnonzero(bad)[:5].tolist()
        raise CalibrationError(f"NaN or inf in correspondences (rows {rows}, 0-based)")
    if X.shape[0] < MIN_POINTS:
        raise CalibrationError(f"DLT needs at least {MIN_POINTS} correspondences, got {X.shape[0]}")
    return X, uv


def _similarity(points: np.ndarray) -> np.ndarray:
    """Hartley normalisation: (D+1, D+1) transform moving the centroid to 0 and the
    mean distance to sqrt(D)."""
    dim = points.shape[1]
    centroid = points.mean(axis=0)
    mean_dist = np.linalg.norm(points - centroid, axis=1).mean()
    s = np.sqrt(dim) / mean_dist
    T = np.eye(dim + 1)
    T[:dim, :dim] *= s
    T[:dim, dim] = -s * centroid
    return T


def dlt_projection_matrix(X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """3x4 projection matrix from 3D-2D correspondences (normalised DLT).

    X : (N, 3) float64 world points, metres; uv : (N, 2) float64 pixels; N >= 6,
    points not coplanar.
    Returns (3, 4) float64 P with ``|P| = 1`` (Frobenius) and ``det(P[:, :3]) > 0``, so
    that points in front of the camera have positive depth ``P[2] . [X, 1]``.
    Raises :class:`CalibrationError` for too few points, NaN/inf, coplanar or
    otherwise degenerate sets.
    """
    X, uv = _check_correspondences(X, uv)
    spread = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)   # (3,) principal spreads
    if not spread[2] > COPLANAR_RATIO * spread[0]:
        raise CalibrationError(
            "3D points are coplanar or collinear (smallest/largest spread "
            f"{spread[2] / max(spread[0], 1e-300):.2e}); the DLT needs non-coplanar points")
    if not np.ptp(uv, axis=0).max() > 0:
        raise CalibrationError("all pixels are identical: degenerate correspondences")
    T3 = _similarity(X)
    T2 = _similarity(uv)
    Xn = (np.hstack([X, np.ones((len(X), 1))]) @ T3.T)               # (N, 4) homogeneous
    un = (np.hstack([uv, np.ones((len(uv), 1))]) @ T2.T)[:, :2]     # (N, 2)
    n = len(X)
    A = np.zeros((2 * n, 12))
    # u: p1.X - u p3.X = 0 ; v: p2.X - v p3.X = 0   (H&Z eq. 7.2)
    A[0::2, 0:4] = Xn
    A[0::2, 8:12] = -un[:, :1] * Xn
    A[1::2, 4:8] = Xn
    A[1::2, 8:12] = -un[:, 1:2] * Xn
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    if not s[-2] > RANK_RATIO * s[0]:
        raise CalibrationError(
            f"degenerate correspondences: DLT system rank < 11 (s11/s1 = {s[-2] / s[0]:.2e})")
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.inv(T2) @ Pn @ T3
    P /= np.linalg.norm(P)
    if np.linalg.det(P[:, :3]) < 0:
        P = -P
    return P


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split a projection matrix into ``K [R | t]``.

    P : (3, 4) float64, any non-zero scale and sign, ``P[:, :3]`` invertible.
    Returns K (3, 3) upper triangular with positive diagonal and ``K[2, 2] = 1``
    (pixels), R (3, 3) proper rotation world -> camera, t (3,) metres world -> camera.
    Raises :class:`CalibrationError` for a non-finite or singular P.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (3, 4):
        raise CalibrationError(f"P must have shape (3, 4), got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise CalibrationError("P has NaN or inf")
    M = P[:, :3]
    det = np.linalg.det(M)
    if not abs(det) > 1e-12 * np.linalg.norm(M) ** 3:
        raise CalibrationError("P[:, :3] is singular: not a finite camera")
    if det < 0:  # the overall sign of P is free; choose the one with det(K R) > 0
        P = -P
        M = -M
    K, R = scipy.linalg.rq(M)
    D = np.diag(np.sign(np.diag(K)))                                 # make diag(K) > 0
    K, R = K @ D, D @ R
    # det(K) > 0 and det(M) > 0 now give det(R) = +1.
    t = np.linalg.solve(K, P[:, 3])
    K /= K[2, 2]
    return K, R, t


def projection_residuals(P: np.ndarray, X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N,) float64 pixel distance between ``P`` applied to X (N, 3) and uv (N, 2)."""
    Xh = np.hstack([np.asarray(X, dtype=np.float64), np.ones((len(X), 1))])
    proj = Xh @ np.asarray(P, dtype=np.float64).T                    # (N, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        pix = proj[:, :2] / proj[:, 2:3]
    return np.linalg.norm(pix - np.asarray(uv, dtype=np.float64), axis=1)


def calibrate_dlt(X: np.ndarray, uv: np.ndarray, size: tuple[int, int], name: str) -> tuple[Camera, np.ndarray]:
    """Calibrate one camera from >= 6 non-coplanar known 3D points.

    X : (N, 3) float64 world points, metres (right-handed, +Z up).
    uv : (N, 2) float64 pixels (OpenCV convention, top-left pixel centre at (0, 0)).
    size : (width, height) pixels; name : camera name for the rig file.
    Returns ``(camera, residuals_px)``: a :class:`Camera` with no distortion (K may
    carry skew) and the (N,) per-point reprojection error in pixels.
    Raises :class:`CalibrationError` for bad input, or if some points fall behind the
    recovered camera (inconsistent correspondences).
    """
    P = dlt_projection_matrix(X, uv)
    depth = np.hstack([np.asarray(X, dtype=np.float64), np.ones((len(X), 1))]) @ P[2]
    if np.any(depth <= 0):
        raise CalibrationError(
            f"{int(np.sum(depth <= 0))} of {len(depth)} points lie behind the recovered camera: "
            "correspondences are inconsistent")
    K, R, t = decompose_projection(P)
    camera = Camera(name=name, size=tuple(int(v) for v in size), K=K, dist=np.zeros(5), R=R, t=t)
    residuals = projection_residuals(camera.P, X, uv)
    logger.debug("DLT %s: RMS %.3f px over %d points", name, np.sqrt(np.mean(residuals**2)), len(residuals))
    return camera, residuals
