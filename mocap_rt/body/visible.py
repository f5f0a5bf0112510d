"""Where a camera sees each blob cue's body part: the offset of its visible centre.

A camera finds the head, a hand or a shoe as the centre of the skin or shoe pixels it sees.
The cue is the centre of the part (``studio.body_shape``: head centre, hand centre, shoe
centre), but the part's end at the next one is covered: the collar over the chin, the
sleeve's end over the hand's wrist end, the trouser leg over the heel. What is seen is
centred towards the free end, 1-1.5 px at 640x480 (docs/perception.md, "Where the medians'
error lies"). No image shows how much is covered; the body model does. ``visible_parts``
casts each view's rays over each part (the capsule body of ``body.silhouette``, the one the
studio draws), a ray seeing the capsule it meets first, and returns the offset of the centre
of what is seen of the part from the projection of its cue point, and the covariance of what
is seen. Fusion sends the offsets of the head and the hands with its prediction (A.4); a
camera reports the centre it measured less the offset. The shoes' covariances, sent when
``FusionConfig.shoe_shapes_max_speed_mps`` allows (both feet standing), split shoes that touch
(docs/perception.md, Blobs, step 9).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.silhouette import (CAPSULE_NAMES, CAPSULE_RADII_M, N_CAPSULES, NEAR_Z_M, body_capsules,
                                      pose_points)
from mocap_rt.names import CUE_NAMES
from mocap_rt.studio.body_map import POINT_NAMES

# the cues whose capsule's offset is predicted on the tracker's state: the head and the hands.
# Not the shoes: the state's ankle, where the trouser leg ends over the shoe, sits ~2 cm below
# the skeleton's on the CMU walk (the leg's split is the subject's convention, docs/body.md),
# and its shoe offsets were 3.2 px against the truth body's 0.9-1.7 (the hands': 2.1 against
# 1.9). The shoes' offsets are cast on the published feet instead, pitched as the subject's
# (``shoe_offsets``, ``SHOE_CAPSULES``; the tracker, while the feet stand)
OFFSET_CUES = ("head", "hand_l", "hand_r")
# the cues whose visible shape (covariance) is predicted: the shoes, which touch side by side
# when the person stands, and are split along the seam the shapes predict (perception.blobs)
SHAPE_CUES = ("foot_l", "foot_r")
# each blob cue's capsule (-1: the torso, none)
CUE_CAPSULES = np.array([CAPSULE_NAMES.index(n) if n in OFFSET_CUES + SHAPE_CUES else -1 for n in CUE_NAMES],
                        np.int64)
# ... without the shoes (their shapes not wanted: half the cost)
OFFSET_CAPSULES = np.where(np.isin(CUE_NAMES, OFFSET_CUES), CUE_CAPSULES, -1)
# ... the shoes alone (their offsets on the published feet: ``shoe_offsets``)
SHOE_CAPSULES = np.where(np.isin(CUE_NAMES, SHAPE_CUES), CUE_CAPSULES, -1)
# each cue's covering capsule (collar, sleeve, trouser leg): what it hides of the part is the
# body's own geometry; another part in front (the other hand, an arm across the face) depends
# on where the fit put two limbs, and when it hides more than this fraction no offset is predicted
COVER_CAPSULES = np.array([CAPSULE_NAMES.index(c) if k >= 0 else -1 for k, c in
                           zip(CUE_CAPSULES, ("neck", "forearm_l", "forearm_r", "shin_l", "shin_r", "torso"))],
                          np.int64)
OTHER_HIDDEN_FRAC = 0.1
# samples across a part's window (its projected extent), at least 1 px apart
WINDOW_SAMPLES = 24
# fewer visible samples than this: nothing predicted (the part is hidden; the prediction says so too)
MIN_VISIBLE_SAMPLES = 4
# ``visible_parts`` columns: the visible centre's offset (x, y), its covariance (xx, xy, yy),
# the fraction of the part that a capsule other than its own cover hides
N_PART_STATS = 6


@njit(cache=True, nogil=True)
def visible_parts(A, B, radii, K, Rt, size, cue_caps, cover, out):
    """out (C, len(cue_caps), N_PART_STATS): per camera (intrinsics ``K`` (C, 3, 3), ``Rt``
    (C, 3, 4) world -> camera, image ``size`` (C, 2) width, height) and cue, of the image's
    pixels whose ray meets the cue's capsule before any other capsule: their centre less the
    projection of the capsule's centre (the cue point), px; their covariance, px^2; the
    fraction of the part's pixels that a capsule other than ``cover`` hides. NaN where the
    cue has no capsule (``cue_caps`` -1), lies behind the camera or is hardly seen. Capsules
    A, B (N, 3) world m, ``radii`` (N,) m, as ``body_capsules`` gives them. Pixels are
    sampled over the capsule's projected extent, ``WINDOW_SAMPLES`` across."""
    C = K.shape[0]
    N = A.shape[0]
    a_c = np.empty((N, 3))           # capsule ends, camera frame
    u_c = np.empty((N, 3))           # b - a
    for c in range(C):
        fx, fy, sk, cx, cy = K[c, 0, 0], K[c, 1, 1], K[c, 0, 1], K[c, 0, 2], K[c, 1, 2]
        w, h = size[c, 0] - 0.5, size[c, 1] - 0.5        # pixel centres are integers
        for j in range(N):
            for i in range(3):
                pa = Rt[c, i, 0] * A[j, 0] + Rt[c, i, 1] * A[j, 1] + Rt[c, i, 2] * A[j, 2] + Rt[c, i, 3]
                pb = Rt[c, i, 0] * B[j, 0] + Rt[c, i, 1] * B[j, 1] + Rt[c, i, 2] * B[j, 2] + Rt[c, i, 3]
                a_c[j, i] = pa
                u_c[j, i] = pb - pa
        for k in range(cue_caps.shape[0]):
            out[c, k, :] = np.nan
            m = cue_caps[k]
            if m < 0 or min(a_c[m, 2], a_c[m, 2] + u_c[m, 2]) - radii[m] < NEAR_Z_M:
                continue
            uc, vc, _ = _pixel(a_c[m], u_c[m], 0.5, fx, fy, sk, cx, cy)     # the cue point
            # the projected extent: both ends' spheres, a little wider than a circle of r f / z
            x0 = y0 = np.inf
            x1 = y1 = -np.inf
            for e in range(2):
                px, py, Z = _pixel(a_c[m], u_c[m], float(e), fx, fy, sk, cx, cy)
                rr = 1.5 * radii[m] * max(fx, fy) / (Z - radii[m])
                x0, x1 = min(x0, px - rr), max(x1, px + rr)
                y0, y1 = min(y0, py - rr), max(y1, py + rr)
            step = max(1.0, max(x1 - x0, y1 - y0) / WINDOW_SAMPLES)
            x0, y0, x1, y1 = max(x0, -0.5), max(y0, -0.5), min(x1, w), min(y1, h)
            n = 0
            n_other = 0                  # samples of the part that another part than its own hides
            sx = sy = sxx = sxy = syy = 0.0
            py = y0 + 0.5 * step
            while py < y1:
                dy = (py - cy) / fy
                px = x0 + 0.5 * step
                while px < x1:
                    dx = (px - cx - sk * dy) / fx
                    nd = np.sqrt(dx * dx + dy * dy + 1.0)
                    d0, d1, d2 = dx / nd, dy / nd, 1.0 / nd
                    sm = _ray_hit(d0, d1, d2, a_c[m], u_c[m], radii[m])
                    if sm < np.inf:
                        seen = True
                        for j in range(N):
                            if j != m and _ray_hit(d0, d1, d2, a_c[j], u_c[j], radii[j]) < sm:
                                seen = False
                                n_other += j != cover[k]
                                break
                        if seen:
                            n += 1
                            ex, ey = px - uc, py - vc
                            sx += ex
                            sy += ey
                            sxx += ex * ex
                            sxy += ex * ey
                            syy += ey * ey
                    px += step
                py += step
            if n >= MIN_VISIBLE_SAMPLES:
                mx, my = sx / n, sy / n
                out[c, k, 0] = mx
                out[c, k, 1] = my
                out[c, k, 2] = sxx / n - mx * mx
                out[c, k, 3] = sxy / n - mx * my
                out[c, k, 4] = syy / n - my * my
                out[c, k, 5] = n_other / (n + n_other)


@njit(cache=True, nogil=True, inline="always")
def _pixel(a, u, t, fx, fy, sk, cx, cy):
    """Pixel (x, y) and depth of the axis point a + t u (camera frame) under intrinsics
    (fx, fy, skew, cx, cy)."""
    X, Y, Z = a[0] + t * u[0], a[1] + t * u[1], a[2] + t * u[2]
    return cx + (fx * X + sk * Y) / Z, cy + fy * Y / Z, Z


@njit(cache=True, nogil=True, inline="always")
def _ray_hit(d0, d1, d2, a, u, r):
    """Distance along the unit ray (d0, d1, d2) from the camera centre to where it enters the
    capsule with axis a -> a + u (camera frame) and radius r, or inf if it misses: the axis
    point nearest the ray (exact), its sphere's entry point along the ray."""
    ad = a[0] * d0 + a[1] * d1 + a[2] * d2
    ud = u[0] * d0 + u[1] * d1 + u[2] * d2
    uu = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    au = a[0] * u[0] + a[1] * u[1] + a[2] * u[2]
    den = uu - ud * ud
    t = 0.0 if den < 1e-15 else min(max((ad * ud - au) / den, 0.0), 1.0)
    q0, q1, q2 = a[0] + t * u[0], a[1] + t * u[1], a[2] + t * u[2]
    s = q0 * d0 + q1 * d1 + q2 * d2
    dist2 = q0 * q0 + q1 * q1 + q2 * q2 - s * s
    if s <= 0.0 or dist2 >= r * r:
        return np.inf
    return s - np.sqrt(r * r - dist2)


def rig_rays(cameras) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intrinsics (C, 3, 3), world -> camera ``[R | t]`` (C, 3, 4) and image sizes (C, 2) of
    the cameras, for ``visible_parts`` (lens distortion is not modelled: the offsets are
    differences)."""
    return (np.ascontiguousarray(np.stack([c.K for c in cameras]), np.float64),
            np.ascontiguousarray(np.stack([np.column_stack([c.R, c.t]) for c in cameras]), np.float64),
            np.array([[c.width, c.height] for c in cameras], np.float64))


def pose_visible_parts(model, root: np.ndarray, angles: np.ndarray, K: np.ndarray, Rt: np.ndarray,
                       size: np.ndarray, cue_caps: np.ndarray = CUE_CAPSULES) -> np.ndarray:
    """(C, 6, N_PART_STATS) ``visible_parts`` of the capsule body in pose (``root``,
    ``angles``) of ``model`` (a ``BodyModel``) for the cameras ``rig_rays`` gives, for the
    cues of ``cue_caps`` (``CUE_CAPSULES`` or ``OFFSET_CAPSULES``)."""
    pos, rot = forward_kinematics(model, root, angles)
    points = np.empty((len(POINT_NAMES), 3))
    pose_points(pos, rot, float(np.radians(model.lengths.foot_pitch_deg)), points)
    A, B = np.empty((N_CAPSULES, 3)), np.empty((N_CAPSULES, 3))
    body_capsules(points, A, B)
    out = np.empty((K.shape[0], len(CUE_CAPSULES), N_PART_STATS))
    visible_parts(A, B, CAPSULE_RADII_M, K, Rt, size, cue_caps, COVER_CAPSULES, out)
    return out


_OFFSET_ROWS = np.array([n in OFFSET_CUES for n in CUE_NAMES])
_SHAPE_ROWS = np.array([n in SHAPE_CUES for n in CUE_NAMES])


def part_offsets(parts: np.ndarray, rows: np.ndarray = _OFFSET_ROWS) -> np.ndarray:
    """(..., 6, 2) the visible centres' offsets of ``visible_parts`` for the cues of ``rows``
    (6,) bool (``OFFSET_CUES``), NaN for the other cues and where another part hides more than
    ``OTHER_HIDDEN_FRAC``."""
    keep = rows & (parts[..., 5] <= OTHER_HIDDEN_FRAC)          # NaN: False
    return np.where(keep[..., None], parts[..., :2], np.nan)


def shoe_offsets(parts: np.ndarray) -> np.ndarray:
    """``part_offsets`` for the shoes (``SHAPE_CUES``)."""
    return part_offsets(parts, _SHAPE_ROWS)


def part_shapes(parts: np.ndarray) -> np.ndarray:
    """(..., 6, 2, 2) the visible parts' covariances of ``visible_parts`` for ``SHAPE_CUES``
    (NaN for the other cues)."""
    cov = parts[..., [2, 3, 3, 4]].reshape(parts.shape[:-1] + (2, 2))
    return np.where(_SHAPE_ROWS[:, None, None], cov, np.nan)
