"""The shoe blob's long axis as a cue to each foot's direction (issue 10, item 4).

Perception sends, with every cue, the covariance of its blob (``CameraCues.cov``, px^2).
A shoe is a capsule from heel to toe (``studio.body_shape``: 0.22 m long, 0.045 m radius),
so the major axis of its blob is the projection of the heel->toe axis, known modulo 180 deg,
and well defined only when the blob is elongated (a shoe seen end-on is round). Six cue
points leave the pan and the legs' swivel free (seed digest A.5); the feet's directions
constrain both: the analytic body's foot is rigid on its shank, so its heading is the knee's
(``FitConfig.foot_axis_weight``: the tracker's pan and swivel fit). The axis does not tell
the left/right hypotheses apart (``fusion.identity`` scores them without it): known modulo
180 deg it is the same for a mirrored body, and a leg crossed to the other foot points that
foot forward much as the right leg does (docs/body.md, "Foot direction").

Measured axis, per foot cue and camera (``foot_axes``): the unit major eigenvector ``a``
(u, v) of the blob covariance and the weight ``w = elongation * confidence``, elongation
``1 - l2 / l1`` (eigenvalues l1 >= l2); w = 0 where the blob is missing, smaller than
``min_area_px``, or overlaps the other foot's blob in that view (two shoes together give
one blob whose axis is neither's).

Cost of a candidate body (``foot_axis_cost``), per foot and camera with w > 0: project the
body's heel and toe (``silhouette.pose_points``); ``d`` = toe - heel (px). The shoe's axis,
drawn through its centre, leaves the measured axis line by ``t * h`` (t in [-1, 1] along
the shoe) with ``h = (a x d) / 2`` px, i.e. ``h * z / f`` metres at the shoe's depth z. The
mean squared distance of the shoe's axis from the measured axis is therefore

    e = (h z / f)^2 / 3   (m^2)   = (L_proj sin(angle))^2 / 3,  L_proj the projected half-length,

the same quantity the silhouette chamfer averages (a mean squared model-to-image distance,
``body.silhouette``), here for the shoe alone and measured on the blob's ellipse instead of
the coarse silhouette cells. The cost is, per foot, the w-weighted ``e`` averaged over the
views that measure an axis, summed over the two feet, in cm^2: 0 for the truth, growing as
sin^2 of the angle, at most ``1e4 * 0.11^2 / 3 = 40`` cm^2 per foot (a side view, 90 deg off).
``body.fit`` adds it to the fit's cost with ``FitConfig.foot_axis_weight`` (1: a cm^2 of
foot axis counts as a cm^2 of silhouette and as a degree of limit violation).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from mocap_rt.body.silhouette import _AUX, _project
from mocap_rt.cues import CameraCues
from mocap_rt.names import C_FOOT_L, C_FOOT_R, N_CUES
from mocap_rt.perception.blob_kernels import ellipse_frame

# A blob with fewer pixels than this gives no axis (its moments are a few pixels' noise).
MIN_AXIS_AREA_PX = 20.0
FOOT_CUES = (C_FOOT_L, C_FOOT_R)   # the cues whose blobs are shoes
M2_TO_CM2 = 1e4


def foot_axes(cues: Mapping[str, CameraCues], camera_names: Sequence[str], weights: np.ndarray | None = None,
              min_area_px: float = MIN_AXIS_AREA_PX) -> np.ndarray:
    """The measured shoe axes of one frame: (6, C, 3) rows (a_u, a_v, w) per cue and camera
    (``camera_names`` order); only the foot cues can have w > 0 (hands and head are round, the
    torso's ellipse is the body's).

    cues : camera name -> CameraCues (cameras missing from it measure nothing).
    weights : (C, 6) the cue weights fusion uses (``BodyTracker._gather``: confidence, 0 where
        dropped), else each cue's ``confidence``.
    The weight w = elongation * weight, 0 for a blob under ``min_area_px`` pixels or one whose
    one-sigma major axis reaches the other foot's centre in that view.
    """
    C = len(camera_names)
    feet = list(FOOT_CUES)
    cov = np.full((C, 2, 2, 2), np.nan)
    xy = np.full((C, 2, 2), np.nan)
    area = np.zeros((C, 2))
    conf = np.zeros((C, 2))
    for c, name in enumerate(camera_names):
        cc = cues.get(name)
        if cc is not None:
            cov[c], xy[c], area[c] = cc.cov[feet], cc.xy[feet], cc.area[feet]
            conf[c] = cc.confidence[feet] if weights is None else weights[c, feet]
    out = np.zeros((N_CUES, C, 3))
    out[..., :2] = np.nan
    measured = np.empty((2, C, 3))
    _measure(cov, xy, area, conf, float(min_area_px), measured)
    out[feet] = measured
    return out


@njit(cache=True, nogil=True)
def _measure(cov, xy, area, conf, min_area_px, out):
    """``foot_axes`` of the feet: cov (C, 2, 2, 2) px^2, xy (C, 2, 2) px, area (C, 2) px,
    conf (C, 2) per camera and foot (left, right) -> out (2, C, 3) (a_u, a_v, w)."""
    for c in range(cov.shape[0]):
        sd = np.zeros(2)
        for k in range(2):
            out[k, c, 0] = np.nan
            out[k, c, 1] = np.nan
            out[k, c, 2] = 0.0
            if not (conf[c, k] > 0.0 and area[c, k] >= min_area_px and np.isfinite(xy[c, k, 0])
                    and np.isfinite(xy[c, k, 1]) and np.all(np.isfinite(cov[c, k]))):
                continue
            sd1, sd2, u, v = ellipse_frame(cov[c, k])
            sign = 1.0 if (u > 0.0 or (u == 0.0 and v >= 0.0)) else -1.0
            out[k, c, 0] = sign * u
            out[k, c, 1] = sign * v
            out[k, c, 2] = max(0.0, 1.0 - (sd2 / sd1) ** 2) * conf[c, k]
            sd[k] = sd1
        if sd[0] > 0.0 and sd[1] > 0.0:
            gap = np.sqrt((xy[c, 0, 0] - xy[c, 1, 0]) ** 2 + (xy[c, 0, 1] - xy[c, 1, 1]) ** 2)
            if gap < sd[0] + sd[1]:
                out[0, c, 2] = 0.0
                out[1, c, 2] = 0.0


def follow_relabelling(axes: np.ndarray, uv_before: np.ndarray, uv_after: np.ndarray) -> np.ndarray:
    """The per-cue axes (6, C, 3) of ``foot_axes`` relabelled as a view's 2D cues were
    (``views.fix_left_right`` exchanges a view's left/right pixels (C, 6, 2)): in each view the
    two feet's rows are exchanged where the feet's pixels were."""
    out = axes.copy()
    same = (uv_before == uv_after) | (np.isnan(uv_before) & np.isnan(uv_after))    # (C, 6, 2)
    moved = ~same[:, list(FOOT_CUES)].all(axis=(1, 2))                             # (C,)
    a, b = FOOT_CUES
    out[a, moved], out[b, moved] = axes[b, moved], axes[a, moved]
    return out


@njit(cache=True, nogil=True)
def foot_axis_cost(points, P, f, feet):
    """Foot-axis cost (cm^2, see the module doc) of a body's points.

    points (len(POINT_NAMES), 3) metres, world (``silhouette.pose_points``: heel and toe);
    P (C, 3, 4) pinhole matrices, f (C,) focal lengths px (``silhouette.rig_projection``);
    feet (2, C, 3) float64, the measured (a_u, a_v, w) of the left and right foot per camera.
    """
    total = 0.0
    for side in range(2):
        s = 0.0
        n = 0
        for c in range(P.shape[0]):
            w = feet[side, c, 2]
            if not w > 0.0:
                continue
            ut, vt, zt = _project(P[c], points[_AUX[side, 0]])
            uh, vh, zh = _project(P[c], points[_AUX[side, 1]])
            if not (np.isfinite(ut) and np.isfinite(uh)):
                continue
            h = 0.5 * (feet[side, c, 0] * (vt - vh) - feet[side, c, 1] * (ut - uh)) * 0.5 * (zt + zh) / f[c]
            s += w * h * h / 3.0
            n += 1
        if n > 0:
            total += s / n
    return total * M2_TO_CM2
