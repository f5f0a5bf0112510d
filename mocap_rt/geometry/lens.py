"""The lens model: OpenCV's radial-tangential distortion, forward and inverse, in one place.

Owns the distortion of ideal normalised coordinates (``distort``, NumPy, broadcasting over
any shapes of points and cameras), its inverse (``undistort``, OpenCV's ``undistortPoints``
iteration; ``undistort_point`` is the same iteration as a numba kernel for compiled
callers) and the 8-coefficient layout every caller uses (``dist8``). Coefficients are
OpenCV's order ``k1, k2, p1, p2[, k3[, k4, k5, k6]]``; normalised coordinates are
``(x/z, y/z)`` in the camera frame (OpenCV: +X right, +Y down, +Z forward).
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

# OpenCV's model has 8 coefficients; shorter vectors (0, 4, 5) are zero-padded to it.
N_COEFFS = 8
# Fixed-point undistortion (cv::undistortPoints): at most this many iterations, stopping
# once the normalised coordinates move less than UNDISTORT_EPS between iterations.
UNDISTORT_MAX_ITER = 50
UNDISTORT_EPS = 1e-15
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, UNDISTORT_MAX_ITER, UNDISTORT_EPS)
_EYE3 = np.eye(3)

__all__ = ["N_COEFFS", "dist8", "distort", "undistort", "undistort_point", "undistort_pixels"]


def dist8(dist) -> np.ndarray:
    """(8,) float64: the 0/4/5/8 OpenCV coefficients ``dist`` zero-padded to eight."""
    d = np.zeros(N_COEFFS)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    d[: dist.size] = dist
    return d


def distort(x: np.ndarray, y: np.ndarray, k) -> tuple[np.ndarray, np.ndarray]:
    """Ideal normalised ``(x, y)`` -> distorted normalised ``(xd, yd)``.

    x, y : arrays of any (equal or broadcastable) shape. k : the 8 coefficients as a
    sequence of scalars or of arrays broadcastable against x (e.g. (C, 1) columns for C
    cameras times N points).
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k1 * r2 + k2 * r4 + k3 * r6) / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def undistort(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N, 2) distorted normalised coordinates -> (N, 2) ideal ones (``cv2.undistortPoints``
    with K = I, 50 iterations, tolerance 1e-15). ``dist``: the 0/4/5/8 coefficients."""
    if dist.size == 0 or not np.any(dist):
        return xy
    out = cv2.undistortPoints(xy.reshape(-1, 1, 2), _EYE3, dist, None, None, None, _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


@njit(cache=True, nogil=True)
def undistort_point(u: float, v: float, kinv: np.ndarray, dist: np.ndarray) -> tuple[float, float]:
    """Distorted pixel (u, v) -> ideal normalised (x, y): ``kinv`` (3, 3) = K^-1, ``dist``
    (8,); cv::undistortPoints' iteration (equals ``undistort`` to ~1e-12)."""
    x0 = kinv[0, 0] * u + kinv[0, 1] * v + kinv[0, 2]
    y0 = kinv[1, 0] * u + kinv[1, 1] * v + kinv[1, 2]
    k1, k2, p1, p2, k3, k4, k5, k6 = dist[0], dist[1], dist[2], dist[3], dist[4], dist[5], dist[6], dist[7]
    x, y = x0, y0
    if k1 == 0.0 and k2 == 0.0 and p1 == 0.0 and p2 == 0.0 and k3 == 0.0 and k4 == 0.0 and k5 == 0.0 and k6 == 0.0:
        return x, y
    for _ in range(UNDISTORT_MAX_ITER):
        r2 = x * x + y * y
        icdist = (1.0 + ((k6 * r2 + k5) * r2 + k4) * r2) / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        xn = (x0 - dx) * icdist
        yn = (y0 - dy) * icdist
        if abs(xn - x) < UNDISTORT_EPS and abs(yn - y) < UNDISTORT_EPS:
            return xn, yn
        x, y = xn, yn
    return x, y


@njit(cache=True, nogil=True)
def _undistort_many(uv: np.ndarray, kinv: np.ndarray, dist: np.ndarray, out: np.ndarray) -> None:
    for i in range(uv.shape[0]):
        out[i, 0], out[i, 1] = undistort_point(uv[i, 0], uv[i, 1], kinv, dist)


def undistort_pixels(uv: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) ideal normalised coordinates, compiled (for whole
    images: rendering, maps). K : (3, 3) intrinsics; dist : the 0/4/5/8 coefficients."""
    uv = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 2)
    out = np.empty_like(uv)
    _undistort_many(uv, np.linalg.inv(K), dist8(dist), out)
    return out
