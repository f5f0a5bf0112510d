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

**Where the legs meet the shoes: the heel end** (seed digest A.6). The axis cannot tell heel
from toe; the leg can: it stands on the heel. Perception measures where each leg's silhouette
meets its shoe blob (``CameraCues.leg_xy``, ``perception.leg_attach``); ``foot_axes`` keeps its
offset ``t`` (px) along the measured axis from the blob's centre, with the weight ``w_leg``
(the cue's). A candidate body predicts it twice per foot and view: ``t_model``, its own ankle
projected onto the axis from its shoe's centre, and ``t_turned``, the ankle of the same foot
turned round by 180 deg about the body's up (what a body facing the other way would put
there). With ``D = t_turned - t_model`` and ``lam`` = (t - t_model) / D clipped to [0, 1], a
view costs ``lam * min(|D| z / f, LEG_CAP_M)^2``: nothing where the leg meets the shoe at the
body's ankle or beyond it, the whole squared distance between the two ankles' places where it
meets it at the turned ankle's, and nothing from a view that cannot tell the two apart (D = 0,
a foot seen end-on from above). Comparing the measurement with the body's own two predictions,
not with one point, keeps the term free of the model's ankle geometry (its ankle sits lower
and further back than a real one, docs/body.md). Per foot, averaged over the views that
measure it, summed over the feet, cm^2. The tracker's pose fit scores only the axes
(``axes_only``); the identity only the legs (``legs_only``, ``fusion.identity``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from mocap_rt.body.silhouette import _ANKLES, _AUX, _P, _project
from mocap_rt.cues import CameraCues
from mocap_rt.names import C_FOOT_L, C_FOOT_R, N_CUES
from mocap_rt.perception.blob_kernels import ellipse_frame
from mocap_rt.perception.leg_attach import MIN_BLOB_AREA_PX

# A blob with fewer pixels than this gives no axis (its moments are a few pixels' noise); the
# same bound perception uses for the legs' attachments
MIN_AXIS_AREA_PX = MIN_BLOB_AREA_PX
FOOT_CUES = (C_FOOT_L, C_FOOT_R)   # the cues whose blobs are shoes
N_FOOT_COLS = 5                    # foot_axes' columns: a_u, a_v, w, t, w_leg
# The legs' term of one view is at most this squared (m): the ankle and the turned ankle's
# places lie about 10-14 cm apart in a side view (the ankle 5-7 cm behind the shoe's centre)
LEG_CAP_M = 0.1
_NECK, _PELVIS = _P["neck"], _P["pelvis"]
M2_TO_CM2 = 1e4


def foot_axes(cues: Mapping[str, CameraCues], camera_names: Sequence[str], weights: np.ndarray | None = None,
              min_area_px: float = MIN_AXIS_AREA_PX) -> np.ndarray:
    """The measured shoe axes of one frame: (6, C, N_FOOT_COLS) rows (a_u, a_v, w, t, w_leg) per
    cue and camera (``camera_names`` order); only the foot cues can have w > 0 (hands and head are
    round, the torso's ellipse is the body's).

    cues : camera name -> CameraCues (cameras missing from it measure nothing).
    weights : (C, 6) the cue weights fusion uses (``views.cue_pixels``: confidence, 0 where
        dropped), else each cue's ``confidence``.
    The weight w = elongation * weight, 0 for a blob under ``min_area_px`` pixels or one whose
    one-sigma major axis reaches the other foot's centre in that view. ``t`` (px) is where the
    leg meets the shoe (``CameraCues.leg_xy``) along (a_u, a_v) from the blob's centre, and
    ``w_leg`` its weight: the cue's weight where it was measured and w's conditions hold but
    the elongation (a round blob's axis is any direction: the attachment along it is still a
    measurement), else 0.
    """
    C = len(camera_names)
    feet = list(FOOT_CUES)
    cov = np.full((C, 2, 2, 2), np.nan)
    xy = np.full((C, 2, 2), np.nan)
    leg = np.full((C, 2, 2), np.nan)
    area = np.zeros((C, 2))
    conf = np.zeros((C, 2))
    for c, name in enumerate(camera_names):
        cc = cues.get(name)
        if cc is not None:
            cov[c], xy[c], area[c] = cc.cov[feet], cc.xy[feet], cc.area[feet]
            conf[c] = cc.confidence[feet] if weights is None else weights[c, feet]
            if cc.leg_xy is not None:
                leg[c] = cc.leg_xy
    out = np.zeros((N_CUES, C, N_FOOT_COLS))
    out[..., :2] = np.nan
    measured = np.empty((2, C, N_FOOT_COLS))
    _measure(cov, xy, leg, area, conf, float(min_area_px), measured)
    out[feet] = measured
    return out


@njit(cache=True, nogil=True)
def _measure(cov, xy, leg, area, conf, min_area_px, out):
    """``foot_axes`` of the feet: cov (C, 2, 2, 2) px^2, xy (C, 2, 2) px, leg (C, 2, 2) px,
    area (C, 2) px, conf (C, 2) per camera and foot (left, right) -> out (2, C, 5)
    (a_u, a_v, w, t, w_leg)."""
    for c in range(cov.shape[0]):
        sd = np.zeros(2)
        for k in range(2):
            out[k, c, 0] = np.nan
            out[k, c, 1] = np.nan
            out[k, c, 2] = 0.0
            out[k, c, 3] = 0.0
            out[k, c, 4] = 0.0
            if not (conf[c, k] > 0.0 and area[c, k] >= min_area_px and np.isfinite(xy[c, k, 0])
                    and np.isfinite(xy[c, k, 1]) and np.all(np.isfinite(cov[c, k]))):
                continue
            sd1, sd2, u, v = ellipse_frame(cov[c, k])
            sign = 1.0 if (u > 0.0 or (u == 0.0 and v >= 0.0)) else -1.0
            out[k, c, 0] = sign * u
            out[k, c, 1] = sign * v
            out[k, c, 2] = max(0.0, 1.0 - (sd2 / sd1) ** 2) * conf[c, k]
            if np.isfinite(leg[c, k, 0]) and np.isfinite(leg[c, k, 1]):
                out[k, c, 3] = sign * (u * (leg[c, k, 0] - xy[c, k, 0]) + v * (leg[c, k, 1] - xy[c, k, 1]))
                out[k, c, 4] = conf[c, k]
            sd[k] = sd1
        if sd[0] > 0.0 and sd[1] > 0.0:
            gap = np.sqrt((xy[c, 0, 0] - xy[c, 1, 0]) ** 2 + (xy[c, 0, 1] - xy[c, 1, 1]) ** 2)
            if gap < sd[0] + sd[1]:
                for k in range(2):
                    out[k, c, 2] = 0.0
                    out[k, c, 4] = 0.0


def follow_relabelling(axes: np.ndarray, uv_before: np.ndarray, uv_after: np.ndarray) -> np.ndarray:
    """The per-cue axes (6, C, 3) of ``foot_axes`` relabelled as a view's 2D cues were
    (``labels.fix_left_right`` exchanges a view's left/right pixels (C, 6, 2)): in each view the
    two feet's rows are exchanged where the feet's pixels were."""
    out = axes.copy()
    same = (uv_before == uv_after) | (np.isnan(uv_before) & np.isnan(uv_after))    # (C, 6, 2)
    moved = ~same[:, list(FOOT_CUES)].all(axis=(1, 2))                             # (C,)
    a, b = FOOT_CUES
    out[a, moved], out[b, moved] = axes[b, moved], axes[a, moved]
    return out


def axes_only(feet: np.ndarray | None) -> np.ndarray | None:
    """``foot_axes`` rows with the legs' attachments left out (their weights 0): what the pose fit
    scores (docs/body.md, "Foot direction: the heel end")."""
    if feet is None:
        return None
    out = feet.copy()
    out[..., 4] = 0.0
    return out


def legs_only(feet: np.ndarray | None, weight: float = 1.0) -> np.ndarray | None:
    """``foot_axes`` rows with the axes left out and the legs' weights times ``weight``: what the
    identity scores; None for None or a weight of 0."""
    if feet is None or not weight > 0:
        return None
    out = feet.copy()
    out[..., 2] = 0.0
    out[..., 4] *= weight
    return out


@njit(cache=True, nogil=True)
def foot_axis_cost(points, P, f, feet):
    """Foot-axis cost (cm^2, see the module doc) of a body's points: the shoes' axes, plus
    where the legs meet the shoes.

    points (len(POINT_NAMES), 3) metres, world (``silhouette.pose_points``: the joints, heel
    and toe); P (C, 3, 4) pinhole matrices, f (C,) focal lengths px
    (``silhouette.rig_projection``); feet (2, C, 5) float64, the measured (a_u, a_v, w, t,
    w_leg) of the left and right foot per camera (``foot_axes``).
    """
    total = 0.0
    up = points[_NECK] - points[_PELVIS]          # the body's up, for the turned feet
    up = up / max(np.sqrt(up @ up), 1e-9)
    for side in range(2):
        s = 0.0
        n = 0
        s_leg = 0.0
        n_leg = 0
        for c in range(P.shape[0]):
            w = feet[side, c, 2]
            w_leg = feet[side, c, 4]
            if not (w > 0.0 or w_leg > 0.0):
                continue
            ut, vt, zt = _project(P[c], points[_AUX[side, 0]])
            uh, vh, zh = _project(P[c], points[_AUX[side, 1]])
            if not (np.isfinite(ut) and np.isfinite(uh)):
                continue
            m_per_px = 0.5 * (zt + zh) / f[c]
            au, av = feet[side, c, 0], feet[side, c, 1]
            if w > 0.0:
                h = 0.5 * (au * (vt - vh) - av * (ut - uh)) * m_per_px
                s += w * h * h / 3.0
                n += 1
            if w_leg > 0.0:
                s_leg += w_leg * _leg_cost(P[c], points, side, up, au, av, feet[side, c, 3], m_per_px)
                n_leg += 1
        if n > 0:
            total += s / n
        if n_leg > 0:
            total += s_leg / n_leg
    return total * M2_TO_CM2


@njit(cache=True, nogil=True)
def _leg_cost(P, points, side, up, au, av, t_meas, m_per_px):
    """Where the leg meets one shoe in one view (m^2, see the module doc): 0 when the measured
    attachment ``t_meas`` (px along (au, av) from the blob's centre) is where this body's ankle
    projects, the squared distance (capped at ``LEG_CAP_M``) between that place and the one of
    the ankle of the same foot turned round when it is there, linear in between."""
    foot = 0.5 * (points[_AUX[side, 0]] + points[_AUX[side, 1]])
    ankle = points[_ANKLES[side]]
    v = ankle - foot
    turned = foot + 2.0 * (v @ up) * up - v       # the ankle's place for the foot turned by 180 deg
    uf, vf, _ = _project(P, foot)
    ua, va, _ = _project(P, ankle)
    ur, vr, _ = _project(P, turned)
    if not (np.isfinite(uf) and np.isfinite(ua) and np.isfinite(ur)):
        return 0.0
    t_model = au * (ua - uf) + av * (va - vf)
    t_turned = au * (ur - uf) + av * (vr - vf)
    d = t_turned - t_model
    if abs(d) < 1e-9:
        return 0.0
    lam = min(max((t_meas - t_model) / d, 0.0), 1.0)
    r = min(abs(d) * m_per_px, LEG_CAP_M)
    return lam * r * r
