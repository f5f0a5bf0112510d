"""The compiled N-view triangulation kernel and ``RayTriangulator``, its fixed-rig form.

Owns the weighted least-squares ray intersection run on distorted pixels in one numba
kernel (undistortion by ``mocap_rt.geometry.lens``, back-projection, 3x3 solve);
``RayTriangulator`` precomputes what depends on the rig only, for the real-time path (six
cues x six cameras, every frame). ``mocap_rt.geometry.triangulate.triangulate_points`` is the
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

__all__ = ["RayTriangulator"]


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
