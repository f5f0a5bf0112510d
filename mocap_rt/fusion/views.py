"""Per-frame multi-view geometry of the cues: view selection, triangulation, prediction.

* ``frontal_pair`` — seed digest A.6: with a virtual camera looking straight down,
  compare the feet's left->right vector with each camera's viewing direction and pick
  the *adjacent* pair (cameras ordered by azimuth around the subject) whose directions
  are closest to perpendicular to the feet vector and on the subject's front. We look
  at the subject's torso instead of the world origin (the subject walks around).
* ``triangulate_cues`` — all views that see a cue, weighted least squares of the rays,
  then reprojection-based outlier rejection: when a view reprojects beyond
  ``max_reproj_px``, the cue restarts from the largest consensus set of views (every
  pair triangulates, the views within the threshold of its point are its inliers), then
  the worst view is dropped while its error is above the threshold and >= 3 views remain.
* ``near_parallel_from_prior`` — a cue whose views' rays are near parallel (two cameras facing
  each other across the subject) has no bound on its error along them: a prior point (the
  tracker's: the filter's last estimate) places it there.
* ``cue_pixels`` — the cameras' 2D cues of one frame as per-view arrays, without a hand
  that a view found on the head's blob, unless ``hands_on_head`` says the prediction rests it
  there.
* ``predict_views`` — A.4: project the predicted 3D cues into every camera and test
  visibility with a Z-buffer on the distance from the camera centre: a cue is hidden
  when a nearer cue's disc covers its centre, or when it falls outside the image.

The 3D cues that cannot be what they claim are dropped by ``fusion.cue_checks``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from mocap_rt.cues import CameraCues
from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.lens import dist8, distort
from mocap_rt.geometry.ray_triangulator import RayTriangulator, ill_conditioned
from mocap_rt.geometry.triangulate import triangulate_with_prior
from mocap_rt.names import C_HAND_L, C_HAND_R, C_HEAD, C_TORSO, N_CUES

# Physical cue radii (metres) for the predicted blob size and the Z-buffer discs,
# in CUE_NAMES order: head, hands, feet (shoe), torso.
CUE_RADII_M = np.array([0.10, 0.05, 0.05, 0.06, 0.06, 0.15])
# Head blob radius assumed when perception gives no area (pixels).
MIN_BLOB_RADIUS_PX = 8.0
# A hand whose 2D cue lies within this many head-blob radii of the head's is taken for
# a second detection of the face in that view and dropped there.
SAME_BLOB_RADII = 1.5


def cue_pixels(cues: Mapping[str, CameraCues], index: Mapping[str, int], n_cameras: int,
               min_confidence: float, on_head: tuple[np.ndarray, np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's 2D cues as per-view arrays: pixels (C, 6, 2) (NaN where not measured),
    weights (C, 6) (the cues' confidences; 0 where not measured) and kept (C, 6) bool, of the
    cameras named in ``index`` (name -> row; other cameras are ignored). A cue below
    ``min_confidence`` is not measured, nor is a hand found within ``SAME_BLOB_RADII`` head-blob
    radii of the head in a view (the same blob twice), unless ``on_head`` (``hands_on_head``'
    predicted pixels and views) shows that hand resting on the head in the view and the cue lies
    within one head-blob radius of its predicted pixels: then ``kept`` is True there."""
    uv = np.full((n_cameras, N_CUES, 2), np.nan)
    w = np.zeros((n_cameras, N_CUES))
    head_r = np.zeros(n_cameras)
    for name, cc in cues.items():
        c = index.get(name)
        if c is None:
            continue
        uv[c] = cc.xy
        w[c] = cc.confidence
        head_r[c] = cc.area[C_HEAD]
    ok = np.isfinite(uv).all(-1) & (w >= min_confidence) & (w > 0)
    r = np.maximum(MIN_BLOB_RADIUS_PX, np.sqrt(np.maximum(head_r, 0.0) / np.pi))
    kept = np.zeros((n_cameras, N_CUES), bool)
    for h in (C_HAND_L, C_HAND_R):
        same = ok[:, C_HEAD] & ok[:, h] & (np.linalg.norm(uv[:, h] - uv[:, C_HEAD], axis=1) < SAME_BLOB_RADII * r)
        if on_head is not None:
            kept[:, h] = same & on_head[1][:, h] & (np.linalg.norm(uv[:, h] - on_head[0][:, h], axis=1) < r)
        ok[same & ~kept[:, h], h] = False
    uv[~ok] = np.nan
    w[~ok] = 0.0
    return uv, w, kept


def hands_on_head(proj: RigProjector, pred: np.ndarray, speed: np.ndarray, min_m: float, max_m: float,
                  max_mps: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the prediction ``pred`` (6, 3) (NaN = unknown) shows a hand resting on the head:
    the predicted pixels (C, 6, 2) and, per view, (C, 6) bool, True for a hand whose centre lies
    between ``min_m`` and ``max_m`` of the head's (in contact: the cue spheres' radii add up to
    0.15 m; nearer is inside the head, farther a hand passing in front of the face), whose
    ``speed`` (6,) m/s is below ``max_mps`` (resting, not swinging past), visible in the view
    (``predict_views``' Z-buffer) and outside the head's disc there (colour parts a hand from the
    head only where it sticks out of it). For ``cue_pixels``: such a hand, found on the head's
    blob in the view, is measured there, not taken for the face reported twice."""
    d = np.linalg.norm(pred - pred[C_HEAD], axis=1)                                       # NaN: False below
    resting = (d >= min_m) & (d <= max_m) & (speed < max_mps)
    if not resting[[C_HAND_L, C_HAND_R]].any():          # most frames: no projection needed
        n_cams = proj.K.shape[0]
        return np.full((n_cams, N_CUES, 2), np.nan), np.zeros((n_cams, N_CUES), bool)
    xy, vis, rad = predict_views(proj, pred, CUE_RADII_M)
    outside = np.linalg.norm(xy - xy[:, C_HEAD, None], axis=-1) > rad[:, C_HEAD, None]
    return xy, vis & resting[None, :] & outside


class RigProjector:
    """All cameras' projections at once (vectorised ``Camera.project``, same model).

    ``project(X (N, 3)) -> (uv (C, N, 2) pixels NaN behind, depth (C, N) metres along
    the optical axis, dist (C, N) metres from the centre)``.
    """

    def __init__(self, cameras: Sequence[Camera]) -> None:
        self.R = np.stack([c.R for c in cameras])                    # (C, 3, 3)
        self.t = np.stack([c.t for c in cameras])                    # (C, 3)
        self.K = np.stack([c.K for c in cameras])                    # (C, 3, 3)
        self.centers = np.stack([c.center for c in cameras])         # (C, 3)
        self.size = np.array([c.size for c in cameras], dtype=np.float64)  # (C, 2)
        self.dist = np.stack([dist8(c.dist) for c in cameras])       # (C, 8)
        self._distorted = bool(np.any(self.dist))
        self._Rt = np.ascontiguousarray(np.transpose(self.R, (0, 2, 1)))  # row vectors: X @ R^T
        K = self.K
        self._fx, self._fy = K[:, 0, 0, None], K[:, 1, 1, None]
        self._skew, self._cx, self._cy = K[:, 0, 1, None], K[:, 0, 2, None], K[:, 1, 2, None]

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pc = X[None, :, :] @ self._Rt + self.t[:, None, :]               # (C, N, 3)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = pc[..., 0] / z, pc[..., 1] / z
        if self._distorted:
            x, y = distort(x, y, self.dist.T[:, :, None])                # coefficients (C, 1) each
        uv = np.empty(pc.shape[:2] + (2,))
        uv[..., 0] = self._fx * x + self._skew * y + self._cx
        uv[..., 1] = self._fy * y + self._cy
        uv[~(z > 1e-9)] = np.nan
        d = X[None, :, :] - self.centers[:, None, :]
        return uv, z, np.sqrt(np.einsum("cni,cni->cn", d, d))

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """(C, N) bool: inside the image (pixel centres at integers, half-pixel border)."""
        w, h = self.size[:, 0:1], self.size[:, 1:2]
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)


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


def triangulate_cues(tri: RayTriangulator, proj: RigProjector, uv: np.ndarray, weights: np.ndarray,
                     max_reproj_px: float | np.ndarray, consensus: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted N-view triangulation with reprojection outlier rejection.

    uv : (C, N, 2) distorted pixels, NaN = not seen; weights : (C, N) >= 0 (0 = not used).
    max_reproj_px : scalar or (N,) per-point threshold, pixels.
    consensus : (N,) bool, points that may restart from the largest consensus set of views
        (``_consensus_views``) when a view exceeds the threshold; None = all.
    Returns ``(X (N, 3) metres NaN where < 2 views, used (C, N) bool, residual_px (C, N))``.
    """
    w = np.where(np.isfinite(uv).all(-1), weights, 0.0)
    used = w > 0
    X = tri(uv, w)
    n = uv.shape[1]
    res = _residuals(proj, X, uv, used)
    bad = (np.where(used, res, 0.0) > max_reproj_px).any(axis=0) & (used.sum(axis=0) >= 3)   # (N,)
    if consensus is not None:
        bad &= consensus
    if bad.any():
        # least squares follows a wrong view before it can be dropped (two wrong views in
        # six can make a right one the worst): restart those cues from a consensus
        used = _consensus_views(tri, proj, uv, w, used, bad, max_reproj_px)
        w = np.where(used, w, 0.0)
        X = tri(uv, w)
    for _ in range(max(0, uv.shape[0] - 2)):
        res = _residuals(proj, X, uv, used)
        worst = np.argmax(np.where(used & np.isfinite(res), res, -1.0), axis=0)   # (N,)
        worst_err = res[worst, np.arange(n)]
        drop = (used.sum(axis=0) >= 3) & np.isfinite(worst_err) & (worst_err > max_reproj_px)
        if not drop.any():
            return X, used, res
        used[worst[drop], np.flatnonzero(drop)] = False
        w = np.where(used, w, 0.0)
        X = tri(uv, w)
    return X, used, _residuals(proj, X, uv, used)


def near_parallel_from_prior(cameras: Sequence[Camera], centers: np.ndarray, uv: np.ndarray, w: np.ndarray,
                             X: np.ndarray, used: np.ndarray, prior: np.ndarray | None, min_angle_deg: float,
                             prior_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """``triangulate_cues``' result (X (N, 3), used (C, N)) with each cue whose used views' rays
    meet within ``min_angle_deg`` of parallel (two cameras facing each other across the subject,
    ``ray_triangulator.ill_conditioned``) placed by its rays and ``prior`` (N, 3) at
    ``prior_weight`` (``triangulate.triangulate_with_prior``): along the rays, where they measure
    next to nothing, the prior decides. Such a cue without a prior is not measured. The inputs
    are returned as they are when no cue is near parallel. cameras / centers (C, 3), uv (C, N, 2),
    w (C, N) as ``triangulate_cues`` took them."""
    bad = ill_conditioned(centers, X, used, min_angle_deg)
    if not bad.any():
        return X, used
    placed = bad & (np.isfinite(prior).all(axis=1) if prior is not None else False)
    X, used = X.copy(), used.copy()
    if placed.any():
        X[placed] = triangulate_with_prior(cameras, uv[:, placed], np.where(used[:, placed], w[:, placed], 0.0),
                                           prior[placed], prior_weight)
    X[bad & ~placed] = np.nan
    used[:, bad & ~placed] = False
    return X, used


# a triangulated head farther than this fraction off the body's head - torso distance is not on
# the trunk (the hands clasped above the head: 0.75-0.8 m from the torso for 0.4-0.45 m)
HEAD_TORSO_TOLERANCE = 0.35


def head_on_trunk(tri: RayTriangulator, proj: RigProjector, uv: np.ndarray, weights: np.ndarray,
                  max_reproj_px: float | np.ndarray, X: np.ndarray, used: np.ndarray, head_torso_m: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``triangulate_cues``' result (X (N, 3), used (C, N)) with a head that is off the top of
    the trunk (its distance to the torso more than ``HEAD_TORSO_TOLERANCE`` off
    ``head_torso_m``, the body's half trunk + neck-head) replaced by the head of the largest
    consensus set of views (``_consensus_views``), if that one is on the trunk. Some views
    took a hand for the head, and least squares followed them and dropped the right views."""
    def on_trunk(head: np.ndarray) -> bool:
        d = float(np.linalg.norm(head - X[C_TORSO]))
        return not np.isfinite(d) or abs(d - head_torso_m) <= HEAD_TORSO_TOLERANCE * head_torso_m

    if on_trunk(X[C_HEAD]):
        return X, used
    Xc, used_c, _ = triangulate_cues(tri, proj, uv, weights, max_reproj_px, np.arange(X.shape[0]) == C_HEAD)
    if not on_trunk(Xc[C_HEAD]) or not np.isfinite(Xc[C_HEAD]).all():
        return X, used
    X, used = X.copy(), used.copy()
    X[C_HEAD], used[:, C_HEAD] = Xc[C_HEAD], used_c[:, C_HEAD]
    return X, used


# smallest consensus set of views that replaces the plain least-squares set
MIN_CONSENSUS_VIEWS = 3


def _consensus_views(tri: RayTriangulator, proj: RigProjector, uv: np.ndarray, w: np.ndarray, used: np.ndarray,
                     bad: np.ndarray, max_reproj_px: float | np.ndarray) -> np.ndarray:
    """Views to keep (C, N) for the ``bad`` cues: the largest consensus set (RANSAC over pairs).

    Every pair of views triangulates the cue; the views reprojecting within
    ``max_reproj_px`` of that point are its inliers; the pair with the most inliers (then
    the least capped residual sum) wins. Cues without a consensus of >= 2 views keep
    ``used``. uv (C, N, 2), w (C, N) weights, used/bad boolean (C, N) / (N,).
    """
    C, n = w.shape
    thr = np.broadcast_to(np.asarray(max_reproj_px, dtype=np.float64), (n,))
    best_n = np.zeros(n)
    best_cost = np.full(n, np.inf)
    best_set = used.copy()
    for i in range(C):
        for j in range(i + 1, C):
            pair = used[[i, j]].all(axis=0) & bad
            if not pair.any():
                continue
            wp = np.zeros_like(w)
            wp[[i, j]] = np.where(pair[None, :], w[[i, j]], 0.0)
            X = tri(uv, wp)
            r = _residuals(proj, X, uv, used)
            inl = used & (r <= thr[None, :])
            k = inl.sum(axis=0)
            cost = np.where(inl, r, 0.0).sum(axis=0) + thr * (used.sum(axis=0) - k)
            better = pair & ((k > best_n) | ((k == best_n) & (cost < best_cost)))
            best_n = np.where(better, k, best_n)
            best_cost = np.where(better, cost, best_cost)
            best_set[:, better] = inl[:, better]
    ok = best_n >= MIN_CONSENSUS_VIEWS
    return np.where(ok[None, :], best_set, used)


def _residuals(proj: RigProjector, X: np.ndarray, uv: np.ndarray, used: np.ndarray) -> np.ndarray:
    p, z, _ = proj.project(np.where(np.isfinite(X), X, 0.0))
    r = np.linalg.norm(p - uv, axis=-1)
    r = np.where(z > 1e-9, r, np.inf)
    return np.where(used & np.isfinite(X).all(axis=1)[None, :], r, np.nan)


def predict_views(proj: RigProjector, X: np.ndarray, radii_m: np.ndarray = CUE_RADII_M
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted 2D cues per camera with Z-buffer visibility (A.4).

    X : (N, 3) predicted cues, metres, world (NaN = unknown). radii_m : (N,).
    Returns ``xy (C, N, 2)`` pixels (NaN where unknown or behind), ``visible (C, N)`` bool,
    ``radius_px (C, N)``.
    """
    ok = np.isfinite(X).all(axis=1)                                       # (N,)
    uv, z, dist = proj.project(np.where(ok[:, None], X, 0.0))
    front = (z > 1e-9) & ok[None, :]
    f = 0.5 * (proj.K[:, 0, 0] + proj.K[:, 1, 1])
    rad = np.where(front, f[:, None] * radii_m[None, :] / np.maximum(z, 1e-6), np.nan)
    xy = np.where(front[..., None], uv, np.nan)
    inside = front & proj.in_image(xy)
    # Z-buffer on the distance from the camera centre: hidden when the centre lies
    # inside the disc of a nearer cue
    d2 = np.sum((xy[:, :, None, :] - xy[:, None, :, :]) ** 2, axis=-1)  # (C, N, N) [c, i, k]
    nearer = dist[:, None, :] < dist[:, :, None]                         # k nearer than i
    covered = (d2 < rad[:, None, :] ** 2) & nearer & front[:, None, :]
    vis = inside & ~covered.any(axis=2)
    return xy, vis, rad
