"""The compiled N-view triangulation kernel and ``RayTriangulator``, its fixed-rig form.

Owns the weighted least-squares ray intersection run on distorted pixels in one numba
kernel (undistortion by ``mocap_rt.geometry.lens``, back-projection, 3x3 solve);
``RayTriangulator`` precomputes what depends on the rig only, for the real-time path (six
cues x six cameras, every frame). ``ill_conditioned`` finds the points whose views' rays meet
near parallel (two cameras facing each other), where that least squares has no bound along
them (``triangulate.triangulate_with_prior`` places them from a prior point).
``mocap_rt.geometry.triangulate.triangulate_points`` is the
one-call entry on the same kernel. The result equals the NumPy reference
(:func:`~mocap_rt.geometry.triangulate.triangulate_rays` on ``Camera.rays``) to ~1e-12 m.
World frame: right-handed, +Z up, metres.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.lens import dist8, undistort_point

# det(A) / (trace(A) / 3)^3 of the 3x3 normal matrix below which the rays are treated
# as parallel (about 1e-7 rad between two rays).
SINGULAR_DET_RATIO = 1e-14

__all__ = ["RayTriangulator", "ill_conditioned"]


@njit(cache=True, nogil=True)
def _triangulate_kernel(uv: np.ndarray, weights: np.ndarray, kinv: np.ndarray, dist: np.ndarray,
                        rt: np.ndarray, centers: np.ndarray, out: np.ndarray) -> int:
    """uv (C, N, 2), weights (C, N), kinv (C, 3, 3), dist (C, 8), rt (C, 3, 3) = R^T,
    centers (C, 3) -> out (N, 3) (NaN where < 2 valid views or singular).
    Returns 0, or 1 for a negative or infinite weight (checked here: a numpy check of the
    tiny array would cost more than the whole triangulation)."""
    C, N = uv.shape[0], uv.shape[1]
    for n in range(N):
        a00 = a01 = a02 = a11 = a12 = a22 = 0.0
        b0 = b1 = b2 = 0.0
        count = 0
        for c in range(C):
            w = weights[c, n]
            if w < 0.0 or w == np.inf:
                return 1
            u, v = uv[c, n, 0], uv[c, n, 1]
            if not (w > 0.0) or not (np.isfinite(u) and np.isfinite(v)):
                continue
            x, y = undistort_point(u, v, kinv[c], dist[c])
            d0 = rt[c, 0, 0] * x + rt[c, 0, 1] * y + rt[c, 0, 2]
            d1 = rt[c, 1, 0] * x + rt[c, 1, 1] * y + rt[c, 1, 2]
            d2 = rt[c, 2, 0] * x + rt[c, 2, 1] * y + rt[c, 2, 2]
            inv = 1.0 / np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            d0 *= inv
            d1 *= inv
            d2 *= inv
            o0, o1, o2 = centers[c, 0], centers[c, 1], centers[c, 2]
            # A += w (I - d d^T);  b += w (o - d (d.o))
            a00 += w * (1.0 - d0 * d0)
            a01 -= w * d0 * d1
            a02 -= w * d0 * d2
            a11 += w * (1.0 - d1 * d1)
            a12 -= w * d1 * d2
            a22 += w * (1.0 - d2 * d2)
            do = d0 * o0 + d1 * o1 + d2 * o2
            b0 += w * (o0 - d0 * do)
            b1 += w * (o1 - d1 * do)
            b2 += w * (o2 - d2 * do)
            count += 1
        if count < 2:
            out[n, 0] = out[n, 1] = out[n, 2] = np.nan
            continue
        # symmetric 3x3 solve by cofactors
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        det = a00 * c00 + a01 * c01 + a02 * c02
        tr3 = (a00 + a11 + a22) / 3.0
        if not (det > SINGULAR_DET_RATIO * tr3 * tr3 * tr3):
            out[n, 0] = out[n, 1] = out[n, 2] = np.nan
            continue
        inv_det = 1.0 / det
        out[n, 0] = (c00 * b0 + c01 * b1 + c02 * b2) * inv_det
        out[n, 1] = (c01 * b0 + c11 * b1 + c12 * b2) * inv_det
        out[n, 2] = (c02 * b0 + c12 * b1 + c22 * b2) * inv_det
    return 0


class RayTriangulator:
    """Triangulate N points from C fixed cameras in one compiled call.

    cameras : the C cameras (order = ``uv``'s first axis), distortion with 0/4/5/8
        OpenCV coefficients.

    ``tri(uv, weights=None, out=None) -> (N, 3)``:
    uv : (C, N, 2) float64 distorted pixels, NaN = not seen; weights : (C, N) >= 0 or
    None (all 1), 0/NaN = view missing; out : optional (N, 3) float64 C-contiguous.
    Returns (N, 3) float64 metres, world; NaN where < 2 valid views or parallel rays.
    """

    def __init__(self, cameras: Sequence[Camera]) -> None:
        cams = tuple(cameras)
        if not cams:
            raise ValueError("RayTriangulator needs at least one camera")
        self.cameras = cams
        self._kinv = np.ascontiguousarray(np.stack([np.linalg.inv(c.K) for c in cams]))
        self._dist = np.stack([dist8(c.dist) for c in cams])
        self._rt = np.ascontiguousarray(np.stack([c.R.T for c in cams]))
        self._centers = np.ascontiguousarray(np.stack([c.center for c in cams]))
        self._ones: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.cameras)

    def __call__(self, uv: np.ndarray, weights: np.ndarray | None = None,
                 out: np.ndarray | None = None) -> np.ndarray:
        uv = np.ascontiguousarray(uv, dtype=np.float64)
        C = len(self.cameras)
        if uv.ndim != 3 or uv.shape[0] != C or uv.shape[2] != 2:
            raise ValueError(f"uv must have shape ({C}, N, 2), got {uv.shape}")
        N = uv.shape[1]
        if weights is None:
            w = self._ones.get(N)
            if w is None:
                w = self._ones[N] = np.ones((C, N))
        else:
            w = np.ascontiguousarray(weights, dtype=np.float64)
            if w.shape != (C, N):
                raise ValueError(f"weights must have shape ({C}, {N}), got {w.shape}")
        if out is None:
            out = np.empty((N, 3))
        elif out.shape != (N, 3) or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float64 array of shape ({N}, 3)")
        if _triangulate_kernel(uv, w, self._kinv, self._dist, self._rt, self._centers, out):
            raise ValueError("weights must be finite and >= 0")
        return out


@njit(cache=True, nogil=True)
def _least_ray_sine2(centers, X, used, out):
    """out (N,): the largest squared sine between two used views' rays at X (N, 3) (-1: fewer
    than two views or X not finite). centers (C, 3), used (C, N) bool."""
    C, N = used.shape
    d = np.empty((C, 3))
    for n in range(N):
        out[n] = -1.0
        if not (np.isfinite(X[n, 0]) and np.isfinite(X[n, 1]) and np.isfinite(X[n, 2])):
            continue
        for c in range(C):
            if used[c, n]:
                v0, v1, v2 = X[n, 0] - centers[c, 0], X[n, 1] - centers[c, 1], X[n, 2] - centers[c, 2]
                inv = 1.0 / np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                d[c, 0], d[c, 1], d[c, 2] = v0 * inv, v1 * inv, v2 * inv
        for a in range(C):
            if not used[a, n]:
                continue
            for b in range(a + 1, C):
                if used[b, n]:
                    c0 = d[a, 1] * d[b, 2] - d[a, 2] * d[b, 1]
                    c1 = d[a, 2] * d[b, 0] - d[a, 0] * d[b, 2]
                    c2 = d[a, 0] * d[b, 1] - d[a, 1] * d[b, 0]
                    out[n] = max(out[n], c0 * c0 + c1 * c1 + c2 * c2)


def ill_conditioned(centers: np.ndarray, X: np.ndarray, used: np.ndarray, min_angle_deg: float) -> np.ndarray:
    """(N,) bool: cues whose used views' rays all meet at ``X`` (N, 3) within ``min_angle_deg`` of
    parallel (or of antiparallel: two cameras facing each other across the subject). Along
    such rays the intersection is undetermined: its error is the rays' lateral error over the
    sine of their angle (two opposite ring cameras 5-10 deg off a line, 6 px off at 3.5 m:
    0.2-0.4 m). centers (C, 3) metres; used (C, N) bool. A cue without two views is not."""
    sin2 = np.empty(X.shape[0])
    _least_ray_sine2(np.ascontiguousarray(centers, np.float64), np.ascontiguousarray(X, np.float64),
                     np.ascontiguousarray(used, np.bool_), sin2)
    return (sin2 >= 0.0) & (sin2 < np.sin(np.radians(min_angle_deg)) ** 2)
