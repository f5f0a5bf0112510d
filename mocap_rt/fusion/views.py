"""Per-frame multi-view geometry of the cues: view selection, triangulation, prediction.

* ``frontal_pair`` — seed digest A.6: with a virtual camera looking straight down,
  compare the feet's left->right vector with each camera's viewing direction and pick
  the *adjacent* pair (cameras ordered by azimuth around the subject) whose directions
  are closest to perpendicular to the feet vector and on the subject's front. We look
  at the subject's torso instead of the world origin (the subject walks around).
* ``triangulate_cues`` — all views that see a cue, weighted least squares of the rays,
  then reprojection-based outlier rejection (drop the worst view while its error is
  above ``max_reproj_px`` and at least three views remain).
* ``predict_views`` — A.4: project the predicted 3D cues into every camera and test
  visibility with a Z-buffer on the distance from the camera centre: a cue is hidden
  when a nearer cue's disc covers its centre, or when it falls outside the image.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.ray_triangulator import RayTriangulator

# Physical cue radii (metres) for the predicted blob size and the Z-buffer discs,
# in CUE_NAMES order: head, hands, feet (shoe), torso.
CUE_RADII_M = np.array([0.10, 0.05, 0.05, 0.06, 0.06, 0.15])


def camera_azimuth_order(centers: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(C,) camera indices sorted by azimuth of their centres (C, 3) around ``target`` (3,)."""
    d = centers[:, :2] - target[:2]
    return np.argsort(np.arctan2(d[:, 1], d[:, 0]), kind="stable")


def frontal_pair(centers: np.ndarray, foot_l: np.ndarray, foot_r: np.ndarray, target: np.ndarray,
                 forward: np.ndarray | None = None) -> tuple[int, int] | None:
    """Indices of the adjacent camera pair facing the subject (A.6), or None.

    centers : (C, 3) camera centres, metres, world. foot_l, foot_r, target : (3,) the
    feet cues and the subject's position (torso). forward : (3,) the body's facing
    direction, used to prefer the front over the back (both are perpendicular to the feet).
    """
    C = centers.shape[0]
    if C < 2:
        return None
    if C == 2:
        return (0, 1)
    feet = (foot_r - foot_l)[:2]
    n = np.linalg.norm(feet)
    if not np.isfinite(n) or n < 1e-6 or not np.isfinite(target).all():
        return None
    feet = feet / n
    view = target[:2] - centers[:, :2]                     # camera -> subject, top view
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    cos_feet = np.abs(view @ feet)                          # 0 = perpendicular
    front = np.zeros(C)
    if forward is not None and np.isfinite(forward).all():
        f = forward[:2] / max(np.linalg.norm(forward[:2]), 1e-9)
        front = np.maximum(0.0, view @ f)                   # > 0: the camera sees the back
    order = camera_azimuth_order(centers, target)
    best, best_score = None, np.inf
    for k in range(C):
        a, b = int(order[k]), int(order[(k + 1) % C])
        score = cos_feet[a] + cos_feet[b] + 2.0 * (front[a] + front[b])
        if score < best_score:
            best, best_score = (min(a, b), max(a, b)), score
    return best


def triangulate_cues(tri: RayTriangulator, cameras: Sequence[Camera], uv: np.ndarray, weights: np.ndarray,
                     max_reproj_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted N-view triangulation with reprojection outlier rejection.

    uv : (C, N, 2) distorted pixels, NaN = not seen; weights : (C, N) >= 0 (0 = not used).
    Returns ``(X (N, 3) metres NaN where < 2 views, used (C, N) bool, residual_px (C, N))``.
    """
    w = np.where(np.isfinite(uv).all(-1), weights, 0.0)
    used = w > 0
    X = tri(uv, w)
    for _ in range(max(0, len(cameras) - 2)):
        res = _residuals(cameras, X, uv, used)
        worst = np.nanargmax(np.where(used, res, -1.0), axis=0)          # (N,)
        worst_err = res[worst, np.arange(uv.shape[1])]
        drop = (used.sum(axis=0) >= 3) & np.isfinite(worst_err) & (worst_err > max_reproj_px)
        if not drop.any():
            break
        used[worst[drop], np.flatnonzero(drop)] = False
        w = np.where(used, w, 0.0)
        X = tri(uv, w)
    res = _residuals(cameras, X, uv, used)
    return X, used, res


def _residuals(cameras: Sequence[Camera], X: np.ndarray, uv: np.ndarray, used: np.ndarray) -> np.ndarray:
    out = np.full(used.shape, np.nan)
    ok = np.isfinite(X).all(axis=1)
    if not ok.any():
        return out
    for c, cam in enumerate(cameras):
        m = ok & used[c]
        if m.any():
            proj, front = cam.project(X[m])
            out[c, m] = np.where(front, np.linalg.norm(proj - uv[c, m], axis=1), np.inf)
    return out


def predict_views(cameras: Sequence[Camera], X: np.ndarray, radii_m: np.ndarray = CUE_RADII_M
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted 2D cues per camera with Z-buffer visibility (A.4).

    X : (N, 3) predicted cues, metres, world (NaN = unknown). radii_m : (N,).
    Returns ``xy (C, N, 2)`` pixels (NaN where unknown or behind), ``visible (C, N)`` bool,
    ``radius_px (C, N)``.
    """
    C, N = len(cameras), X.shape[0]
    xy = np.full((C, N, 2), np.nan)
    vis = np.zeros((C, N), dtype=bool)
    rad = np.full((C, N), np.nan)
    ok = np.isfinite(X).all(axis=1)
    if not ok.any():
        return xy, vis, rad
    for c, cam in enumerate(cameras):
        uv, front = cam.project(X[ok])
        depth = np.linalg.norm(X[ok] - cam.center, axis=1)
        f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
        r = f * radii_m[ok] / np.maximum(depth, 1e-6)
        idx = np.flatnonzero(ok)
        xy[c, idx] = np.where(front[:, None], uv, np.nan)
        rad[c, idx] = np.where(front, r, np.nan)
        inside = front & cam.in_image(uv)
        # Z-buffer: hidden if the centre lies inside the disc of a nearer cue
        d2 = np.sum((uv[:, None, :] - uv[None, :, :]) ** 2, axis=-1)    # (M, M)
        nearer = depth[None, :] < depth[:, None]                          # [i, k]: k nearer than i
        covered = (d2 < r[None, :] ** 2) & nearer & front[None, :]
        vis[c, idx] = inside & ~covered.any(axis=1)
    return xy, vis, rad
