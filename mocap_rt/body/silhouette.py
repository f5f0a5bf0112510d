"""The body as capsules, and how well a pose agrees with the cameras' silhouettes.

Analysis by synthesis (seed digest A.4, carried to the whole body): the body model's
capsules (the studio's shape, ``mocap_rt.studio.body_shape``, on the model's joints and
bone lengths) are projected into every camera and compared with that camera's
silhouette (``mocap_rt.cues.CompactSilhouette``) by a two-sided chamfer distance:

* model -> image: points along every capsule's axis must lie inside the silhouette; each
  costs its distance to the silhouette (a ``cv2.distanceTransform`` of the background
  cells, padded by ``PAD_CELLS``);
* image -> model: points on the silhouette's outline must be explained by the model;
  each costs its distance to the nearest projected capsule outline (0 inside one).

Only what a camera sees is compared: a model point that projects outside the image is not
scored (the camera cannot tell whether it is the person's), and a silhouette cut by the
image's edge has no outline there (the cells along the edge are not outline points). A
person leaving a camera's field of view used to cost up to 130 cm^2 in that view alone
(feet below the image counted as outside the silhouette), more than a wrong heading.

Distances are converted from pixels to metres at the point's depth (``d_px * z / f``),
capped at ``CAP_M`` and averaged as squares, so the cost is in m^2 and the same for a
near and a far camera. Lens distortion is ignored (pinhole ``K [R | t]``): the cells are
2-4 pixels anyway. Everything per pose runs in numba (analytic pose -> angles -> forward
kinematics -> capsules -> cost, ``body.fit``), so a search can afford ~50 evaluations
per frame at six cameras.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import cv2
import numpy as np
from numba import njit

from mocap_rt.body.skeleton import J
from mocap_rt.cues import CameraCues
from mocap_rt.geometry.camera import Camera
from mocap_rt.studio import body_shape as bs
from mocap_rt.studio.body_map import POINT_NAMES

# Heel to toe of the shoe, metres (the studio's shoes: 0.22 m); the foot cue is its centre.
SHOE_HALF_LENGTH_M = 0.11
# Distance-transform padding around a silhouette's cells (cells), and the cost cap (m).
PAD_CELLS = 4
CAP_M = 0.25
# Samples per capsule axis (model -> image) and outline points per view (image -> model).
AXIS_SAMPLES = 4
MAX_OUTLINE_POINTS = 32
NEAR_Z_M = 0.05

_P = {n: i for i, n in enumerate(POINT_NAMES)}
# capsule order and radii, as ``body_shape.body_primitives`` builds them
CAPSULE_NAMES = ("head", "neck", "torso", "chest", "hips") + tuple(
    f"{k}_{s}" for s in ("l", "r") for k in ("upper_arm", "forearm", "hand", "thigh", "shin", "foot"))
CAPSULE_RADII_M = np.array(
    [bs.HEAD_RADIUS_M, bs.NECK_RADIUS_M, bs.WAIST_RADIUS_M, bs.CHEST_RADIUS_M, bs.HIPS_RADIUS_M]
    + 2 * [bs.UPPER_ARM_RADIUS_M, bs.FOREARM_RADIUS_M, bs.HAND_RADIUS_M, bs.THIGH_RADIUS_M,
           bs.SHIN_RADIUS_M, bs.SHOE_RADIUS_M])
N_CAPSULES = len(CAPSULE_NAMES)
# the capsules each limb swivel (arm_l, arm_r, leg_l, leg_r) moves, and the others
SWIVEL_CAPSULES = np.array([[CAPSULE_NAMES.index(f"{k}_{s}") for k in parts] for parts, s in
                            ((("upper_arm", "forearm", "hand"), "l"), (("upper_arm", "forearm", "hand"), "r"),
                             (("thigh", "shin", "foot"), "l"), (("thigh", "shin", "foot"), "r"))], dtype=np.int64)
SWIVEL_OTHER_CAPSULES = np.array([[k for k in range(N_CAPSULES) if k not in caps] for caps in SWIVEL_CAPSULES],
                                 dtype=np.int64)
# (point a, point b) indices into POINT_NAMES of the limb capsules, per side
_LIMB_CAPS = np.array([[[_P[f"{a}_{s}"], _P[f"{b}_{s}"]] for a, b in
                        (("shoulder", "elbow"), ("elbow", "wrist"), ("wrist", "hand"), ("hip", "knee"),
                         ("knee", "ankle"), ("heel", "toe"))] for s in ("l", "r")], dtype=np.int64)
_CONST = np.array([bs.HEAD_HALF_AXIS_M, bs.HEAD_RADIUS_M, SHOE_HALF_LENGTH_M])
_IDX = np.array([_P["head"], _P["neck"], _P["pelvis"], _P["shoulder_l"], _P["shoulder_r"], _P["hip_l"],
                 _P["hip_r"]], dtype=np.int64)
_ANKLES = np.array([J["ankle_l"], J["ankle_r"]], dtype=np.int64)
_FEET = np.array([J["foot_l"], J["foot_r"]], dtype=np.int64)
_WRISTS = np.array([J["wrist_l"], J["wrist_r"]], dtype=np.int64)
_HANDS = np.array([J["hand_l"], J["hand_r"]], dtype=np.int64)
_AUX = np.array([[_P["toe_l"], _P["heel_l"], _P["fingers_l"]], [_P["toe_r"], _P["heel_r"], _P["fingers_r"]]],
                dtype=np.int64)


@njit(cache=True, nogil=True)
def pose_points(pos, rot, foot_pitch, out):
    """Body points (len(POINT_NAMES), 3) of a pose: the joints (J, 3) ``pos`` plus toe,
    heel (the shoe's axis is the ankle frame's rest-forward direction, ``foot_pitch``
    radians above its Z) and fingers (as far beyond the hand centre as the wrist is before it)."""
    nj = pos.shape[0]
    out[:nj] = pos
    c, s = np.cos(foot_pitch), np.sin(foot_pitch)
    for side in range(2):
        a = _ANKLES[side]
        f = pos[_FEET[side]]
        for i in range(3):
            ax = c * rot[a, i, 2] - s * rot[a, i, 1]
            out[_AUX[side, 0], i] = f[i] + _CONST[2] * ax
            out[_AUX[side, 1], i] = f[i] - _CONST[2] * ax
            out[_AUX[side, 2], i] = 2.0 * pos[_HANDS[side], i] - pos[_WRISTS[side], i]


@njit(cache=True, nogil=True)
def body_capsules(points, A, B):
    """Capsule ends A, B (N_CAPSULES, 3) of ``body_shape.body_primitives`` from body points
    (len(POINT_NAMES), 3); radii are ``CAPSULE_RADII_M``."""
    head, neck, pelvis = points[_IDX[0]], points[_IDX[1]], points[_IDX[2]]
    sl, sr, hl, hr = points[_IDX[3]], points[_IDX[4]], points[_IDX[5]], points[_IDX[6]]
    up = head - neck
    n = np.sqrt(up @ up)
    up = up / max(n, 1e-9)
    A[0] = head - _CONST[0] * up
    B[0] = head + _CONST[0] * up
    A[1] = neck
    B[1] = head - (_CONST[1] + _CONST[0]) * up
    spine = neck - pelvis
    A[2] = pelvis + 0.15 * spine
    B[2] = neck - 0.15 * spine
    A[3] = sl + 0.3 * (sr - sl)
    B[3] = sr + 0.3 * (sl - sr)
    A[4] = hl
    B[4] = hr
    k = 5
    for side in range(2):
        for m in range(6):
            a, b = points[_LIMB_CAPS[side, m, 0]], points[_LIMB_CAPS[side, m, 1]]
            if m == 2:   # the hand: 0.6 of wrist->hand on either side of the hand centre
                A[k] = b - 0.6 * (b - a)
                B[k] = b + 0.6 * (b - a)
            else:
                A[k] = a
                B[k] = b
            k += 1


@njit(cache=True, nogil=True)
def _project(P, X):
    """Pinhole projection (u, v, z) of X (3,) by P (3, 4)."""
    x = P[0, 0] * X[0] + P[0, 1] * X[1] + P[0, 2] * X[2] + P[0, 3]
    y = P[1, 0] * X[0] + P[1, 1] * X[1] + P[1, 2] * X[2] + P[1, 3]
    z = P[2, 0] * X[0] + P[2, 1] * X[1] + P[2, 2] * X[2] + P[2, 3]
    if z < NEAR_Z_M:
        return np.nan, np.nan, z
    return x / z, y / z, z


@njit(cache=True, nogil=True, inline="always")
def _cell(u, v, x0, y0, step, gh, gw):
    """The cell (flat index) of image point (u, v) px in a view's padded grid (x0, y0, step,
    gh x gw cells), and its distance (cells) beyond the grid (0 inside)."""
    gx = (u - x0 - 0.5 * (step - 1)) / step + PAD_CELLS
    gy = (v - y0 - 0.5 * (step - 1)) / step + PAD_CELLS
    ix = min(max(int(np.floor(gx + 0.5)), 0), gw - 1)
    iy = min(max(int(np.floor(gy + 0.5)), 0), gh - 1)
    return iy * gw + ix, np.sqrt((gx - ix) ** 2 + (gy - iy) ** 2) * (
        1.0 if (gx < 0 or gy < 0 or gx > gw - 1 or gy > gh - 1) else 0.0)


@njit(cache=True, nogil=True, inline="always")
def _in_image(u, v, width, height):
    """Whether the image point (u, v) px lies in the image (NaN: no)."""
    return u >= -0.5 and v >= -0.5 and u < width - 0.5 and v < height - 0.5


@njit(cache=True, nogil=True)
def points_cost(X, P, f, grid, dt, dt_off):
    """Mean over the valid views of the mean squared capped distance (m^2) of the points X
    (N, 3) outside the silhouettes (the model -> image half of ``capsules_cost``, for points;
    points outside the image are not scored)."""
    total = 0.0
    n_views = 0
    cap2 = CAP_M * CAP_M
    for c in range(P.shape[0]):
        if grid[c, 0] == 0:
            continue
        s = 0.0
        n = 0
        for i in range(X.shape[0]):
            u, v, z = _project(P[c], X[i])
            if _in_image(u, v, grid[c, 6], grid[c, 7]):
                cell, beyond = _cell(u, v, grid[c, 1], grid[c, 2], grid[c, 3], grid[c, 4], grid[c, 5])
                dm = (dt[dt_off[c] + cell] + beyond) * grid[c, 3] * z / f[c]
                s += min(dm * dm, cap2)
                n += 1
        if n > 0:
            total += s / n
            n_views += 1
    return total / n_views if n_views > 0 else 0.0


@njit(cache=True, nogil=True)
def capsules_cost(A, B, rad, P, f, grid, dt, dt_off, outline, n_outline):
    """Chamfer cost (m^2) of capsules A, B (K, 3), radii (K,) against the views.

    P (C, 3, 4) pinhole matrices; f (C,) focal lengths px; grid (C, 8) int64 rows
    (valid, x0, y0, step, padded height, padded width, image width, image height); dt
    float32 flat distance transforms (cells) of the padded grids at ``dt_off`` (C,);
    outline (C, Q, 2) pixels,
    ``n_outline`` (C,) of them valid. Returns the mean over valid views of
    (mean model->image + mean image->model squared capped distances).
    """
    part = new_partial(P.shape[0], outline.shape[1])
    add_capsules(A, B, rad, np.arange(A.shape[0]), P, f, grid, dt, dt_off, outline, n_outline, part)
    return partial_cost(f, grid, n_outline, part)


@njit(cache=True, nogil=True)
def new_partial(C, Q):
    """An empty partial chamfer sum (``add_capsules``) of C views with Q outline points each."""
    part = np.empty((C, 2 + 2 * Q))
    reset_partial(part)
    return part


@njit(cache=True, nogil=True)
def reset_partial(part):
    """Empty the partial chamfer sum ``part`` (``add_capsules``) in place."""
    Q = (part.shape[1] - 2) // 2
    part[:, :2] = 0.0
    part[:, 2:2 + Q] = 1e30
    part[:, 2 + Q:] = 3.0


@njit(cache=True, nogil=True)
def add_capsules(A, B, rad, caps, P, f, grid, dt, dt_off, outline, n_outline, part):
    """Add the capsules ``caps`` (indices into A, B (K, 3), radii (K,)) to the partial chamfer sum
    ``part`` (C, 2 + 2Q), per view: the model -> image squared capped distances summed, their
    samples counted, then each outline point's nearest capsule surface so far (px) and its depth.
    ``partial_cost`` turns it into ``capsules_cost``'s; a search that moves a few capsules sums
    the others once (``body.fit``). Arguments as ``capsules_cost``."""
    C = P.shape[0]
    K = caps.shape[0]
    ua = np.empty(K)
    va = np.empty(K)
    ub = np.empty(K)
    vb = np.empty(K)
    ra = np.empty(K)
    rb = np.empty(K)
    za = np.empty(K)
    zb = np.empty(K)
    su = np.empty(K * AXIS_SAMPLES)
    sv = np.empty(K * AXIS_SAMPLES)
    sz = np.empty(K * AXIS_SAMPLES)
    cell = np.empty(K * AXIS_SAMPLES, np.int64)
    beyond = np.empty(K * AXIS_SAMPLES)
    Q = outline.shape[1]
    qu = np.empty(Q)
    qv = np.empty(Q)
    cap2 = CAP_M * CAP_M
    for c in range(C):
        if grid[c, 0] == 0:
            continue
        x0, y0, step, gh, gw, width, height = grid[c, 1], grid[c, 2], grid[c, 3], grid[c, 4], grid[c, 5], \
            grid[c, 6], grid[c, 7]
        off = dt_off[c]
        fc = f[c]
        # model -> image: the distance transform at samples along each projected axis
        n_model = 0
        for i in range(K):
            k = caps[i]
            ua[i], va[i], za[i] = _project(P[c], A[k])
            ub[i], vb[i], zb[i] = _project(P[c], B[k])
            ra[i] = fc * rad[k] / max(za[i], NEAR_Z_M)
            rb[i] = fc * rad[k] / max(zb[i], NEAR_Z_M)
            if not (np.isfinite(ua[i]) and np.isfinite(ub[i])):
                continue
            for si in range(AXIS_SAMPLES):
                t = si / (AXIS_SAMPLES - 1)
                su[n_model] = ua[i] + t * (ub[i] - ua[i])
                sv[n_model] = va[i] + t * (vb[i] - va[i])
                sz[n_model] = za[i] + t * (zb[i] - za[i])
                n_model += 1 if _in_image(su[n_model], sv[n_model], width, height) else 0
        for j in range(n_model):       # the samples' cells (vectorised)
            cell[j], beyond[j] = _cell(su[j], sv[j], x0, y0, step, gh, gw)
        s_model = part[c, 0]
        for j in range(n_model):
            dm = (dt[off + cell[j]] + beyond[j]) * step * sz[j] / fc
            s_model += min(dm * dm, cap2)
        part[c, 0] = s_model
        part[c, 1] += n_model
        # image -> model: each outline point's nearest capsule surface (the first of equal
        # ones), capsule by capsule over all the points (a loop the compiler vectorises)
        nq = n_outline[c]
        best = part[c, 2:2 + Q]
        best_z = part[c, 2 + Q:]
        for q in range(nq):
            qu[q] = outline[c, q, 0]
            qv[q] = outline[c, q, 1]
        for i in range(K):
            if not (np.isfinite(ua[i]) and np.isfinite(ub[i])):
                continue
            du, dv = ub[i] - ua[i], vb[i] - va[i]
            L2 = du * du + dv * dv
            a_u, a_v, r0, dr, z0, dz = ua[i], va[i], ra[i], rb[i] - ra[i], za[i], zb[i] - za[i]
            seg = L2 > 1e-12
            for q in range(nq):
                t = min(1.0, max(0.0, ((qu[q] - a_u) * du + (qv[q] - a_v) * dv) / L2)) if seg else 0.0
                eu, ev = qu[q] - a_u - t * du, qv[q] - a_v - t * dv
                d = np.sqrt(eu * eu + ev * ev) - (r0 + t * dr)
                nearer = d < best[q]
                best_z[q] = z0 + t * dz if nearer else best_z[q]
                best[q] = d if nearer else best[q]


@njit(cache=True, nogil=True)
def partial_cost(f, grid, n_outline, part):
    """``capsules_cost`` (m^2) of the capsules summed into ``part`` (``add_capsules``)."""
    Q = (part.shape[1] - 2) // 2
    cap2 = CAP_M * CAP_M
    total = 0.0
    n_views = 0
    for c in range(part.shape[0]):
        if grid[c, 0] == 0 or part[c, 1] == 0:
            continue
        total += part[c, 0] / part[c, 1]
        nq = n_outline[c]
        if nq > 0:
            s_out = 0.0
            for q in range(nq):
                dm = max(part[c, 2 + q], 0.0) * part[c, 2 + Q + q] / f[c]
                s_out += min(dm * dm, cap2)
            total += s_out / nq
        n_views += 1
    return total / n_views if n_views > 0 else 0.0


def rig_projection(cameras: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole matrices ``K [R | t]`` (C, 3, 4) and focal lengths (C,) px of the cameras."""
    P = np.ascontiguousarray(np.stack([c.K @ np.column_stack([c.R, c.t]) for c in cameras]))
    return P, np.array([0.5 * (c.K[0, 0] + c.K[1, 1]) for c in cameras])


@njit(cache=True, nogil=True)
def _prepare(mask, pad, background, outline, x0, y0, step, width, height):
    """Write the padded background mask (1 = not the person) and up to len(outline) outline
    cells (a set cell with a 4-neighbour unset, evenly taken in raster order; not the cells
    on the edge of the ``width`` x ``height`` image) as pixel centres; return the number of
    outline points."""
    h, w = mask.shape
    border = np.empty(h * w, np.int64)      # the outline cells, raster order
    n = 0
    for y in range(h):
        edge_y = y0 + step * y <= 0 or y0 + step * (y + 1) >= height
        for x in range(w):
            m = mask[y, x]
            background[y + pad, x + pad] = 0 if m else 1
            if m and not (edge_y or x0 + step * x <= 0 or x0 + step * (x + 1) >= width) and (
                    x == 0 or y == 0 or x == w - 1 or y == h - 1 or not mask[y, x - 1]
                    or not mask[y, x + 1] or not mask[y - 1, x] or not mask[y + 1, x]):
                border[n] = y * w + x
                n += 1
    q = outline.shape[0]
    every = max(1.0, n / q)
    k = 0
    nxt = 0.0
    for i in range(n):
        if k >= q:
            break
        if i >= nxt:
            y, x = divmod(border[i], w)
            outline[k, 0] = x0 + step * x + 0.5 * (step - 1)
            outline[k, 1] = y0 + step * y + 0.5 * (step - 1)
            k += 1
            nxt += every
    return k


class SilhouetteTargets:
    """One frame's silhouettes of a rig, prepared for ``capsules_cost``.

    Build with ``SilhouetteTargets.from_cues(cameras, cues)``; ``n_views`` views carry a
    non-empty silhouette (the others are skipped). Arrays as ``capsules_cost`` wants them.
    """

    def __init__(self, cameras: Sequence[Camera], projection: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self.P, self.f = rig_projection(cameras) if projection is None else projection
        C = len(cameras)
        self.grid = np.zeros((C, 8), np.int64)
        self.dt = np.zeros(1, np.float32)
        self.dt_off = np.zeros(C, np.int64)
        self.outline = np.zeros((C, MAX_OUTLINE_POINTS, 2))
        self.n_outline = np.zeros(C, np.int64)

    @property
    def n_views(self) -> int:
        return int(self.grid[:, 0].sum())

    @classmethod
    def from_cues(cls, cameras: Sequence[Camera], cues: Mapping[str, CameraCues],
                  projection: tuple[np.ndarray, np.ndarray] | None = None) -> "SilhouetteTargets":
        """The targets of the cameras' silhouettes in ``cues`` (camera name -> CameraCues);
        ``projection`` = ``rig_projection(cameras)``, precomputed by callers that reuse it."""
        out = cls(cameras, projection)
        dts = []
        off = 0
        for c, cam in enumerate(cameras):
            cc = cues.get(cam.name)
            sil = None if cc is None else cc.silhouette
            if sil is None or sil.mask.size == 0 or not sil.mask.any():
                continue
            h, w = sil.mask.shape
            bg = np.ones((h + 2 * PAD_CELLS, w + 2 * PAD_CELLS), np.uint8)
            width, height = cam.size
            out.n_outline[c] = _prepare(sil.mask, PAD_CELLS, bg, out.outline[c], sil.x0, sil.y0, sil.step, width,
                                        height)
            d = cv2.distanceTransform(bg, cv2.DIST_L2, 3)
            dts.append(d.ravel())
            out.grid[c] = (1, sil.x0, sil.y0, sil.step, d.shape[0], d.shape[1], width, height)
            out.dt_off[c] = off
            off += d.size
        if dts:
            out.dt = np.concatenate(dts).astype(np.float32)
        return out

    def args(self) -> tuple:
        """(P, f, grid, dt, dt_off, outline, n_outline) for the numba kernels."""
        return self.P, self.f, self.grid, self.dt, self.dt_off, self.outline, self.n_outline
