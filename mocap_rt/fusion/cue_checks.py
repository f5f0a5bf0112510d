"""The 3D cues of a frame that cannot be what they claim, dropped before the filter.

* ``beyond_reach`` — a hand or foot farther from the torso cue than the limb reaches
  (``torso_reach_m``): two views that paired different limbs;
* ``reject_duplicates`` — a hand or foot on the head that the prediction did not put there (the
  face taken for it), and one of a left/right pair on the same point as the other;
* ``seen_twice`` — a hand or foot coming back on the other one of its pair, the two labels' blobs
  covering one limb's area (``blob_areas``, ``pair_areas``, ``pair_area_reference``): perception
  split one limb's pixels between both labels.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.cues import CameraCues
from mocap_rt.fusion.views import RigProjector
from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HAND_L, C_HAND_R, C_HEAD, C_TORSO, LIMB_CUES, LR_PAIRS, N_CUES

# two cues of a left/right pair closer than this (m) are one hand or foot labelled twice
SAME_POINT_M = 0.03
# A hand or foot farther from the torso cue than this many times the limb's reach (``torso_reach_m``
# of the subject's lengths, or the default adult's before the calibration) is no measurement: in
# the studio's truth no cue lies farther than 1.05 times the subject's reach.
REACH_MARGIN = 1.3


def torso_reach_m(lengths: BoneLengths) -> np.ndarray:
    """(6,) how far each cue can lie from the torso cue (metres): a hand the arm's length
    straight from the shoulder, a foot the leg's from the hip (the torso cue within
    ``torso_cue_up_m`` of the trunk's middle); no bound (inf) on the head and the torso."""
    up = abs(lengths.torso_cue_up_m)
    arm = np.hypot(lengths.trunk_m / 2, lengths.shoulder_half_width_m) + lengths.upper_arm_m + lengths.forearm_m
    leg = np.hypot(lengths.trunk_m / 2, lengths.hip_half_width_m) + lengths.leg_reach_m()
    reach = np.full(N_CUES, np.inf)
    reach[[C_HAND_L, C_HAND_R]] = arm + lengths.hand_m + up
    reach[[C_FOOT_L, C_FOOT_R]] = leg + up
    return reach


def beyond_reach(X: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """A copy of the 3D cues X (6, 3) without a hand or foot farther than ``REACH_MARGIN`` times
    its ``reach`` (6,) from the torso cue (``torso_reach_m``): two views that paired different
    limbs triangulate one far off the body (a cold start whose hand only one view kept: 2.4 m)."""
    if not np.isfinite(X[C_TORSO]).all():
        return X
    far = np.linalg.norm(X - X[C_TORSO], axis=1) > REACH_MARGIN * reach
    return np.where(far[:, None], np.nan, X)


def reject_duplicates(X: np.ndarray, valid: np.ndarray, used: np.ndarray, pred: np.ndarray,
                      duplicate_m: float) -> np.ndarray:
    """A copy of the 3D cues X (6, 3) without a hand/foot measured within ``duplicate_m`` of
    the head unless the prediction ``pred`` (6, 3) put it there, and without one of a
    left/right pair measured on top of the other.

    Perception re-acquiring a lost hand can take the face blob in every view; the
    triangulated "hand" is then the head. A real hand at the face was predicted near it.
    A pair within ``SAME_POINT_M`` is one hand (foot) that different views labelled
    differently (e.g. a cold start while the other is hidden everywhere): the label seen
    by fewer views (``used`` (C, 6) bool) goes. ``valid`` (6,) bool: the rows of X measured.
    """
    X = X.copy()
    for a, b in LR_PAIRS:
        if valid[a] and valid[b] and np.linalg.norm(X[a] - X[b]) < SAME_POINT_M:
            X[b if used[:, a].sum() >= used[:, b].sum() else a] = np.nan
    if not valid[C_HEAD]:
        return X
    for c in LIMB_CUES:
        if valid[c] and np.linalg.norm(X[c] - X[C_HEAD]) < duplicate_m:
            p = pred[c]
            if not (np.isfinite(p).all() and np.linalg.norm(p - X[C_HEAD]) < 2 * duplicate_m):
                X[c] = np.nan
    return X


# A left/right pair measured within ``duplicate_m`` whose two blobs, in the median view that
# found both, cover less than this many times one limb's blob (``pair_area_reference``) is one
# limb labelled twice: one hand whose pixels perception split between both labels (the other
# hand hidden) covers one hand's area, two hands held together two.
SEEN_TWICE_RATIO = 1.4
PAIR_AREA_RATE = 0.1       # the reference follows each frame of the limbs apart at this rate
RETURN_S = 0.2             # a track (re)started this recently (s) is a hand or foot coming back
_PAIR_A, _PAIR_B = np.array(LR_PAIRS).T


def blob_areas(cues: Mapping[str, CameraCues], index: Mapping[str, int], w: np.ndarray) -> np.ndarray:
    """(C, 6) each view's blob area (pixels) of a cue it measures (``w`` (C, 6) > 0), else (or
    with no area given) NaN."""
    area = np.full(w.shape, np.nan)
    for name, cc in cues.items():
        c = index.get(name)
        if c is not None:
            area[c] = cc.area
    area[~((w > 0) & (area > 0))] = np.nan
    return area


def pair_areas(proj: RigProjector, area: np.ndarray, uv: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(C, 2) per view, the area (m^2, at the depth of the pair's 3D middle) that each left/right
    pair's two blobs cover together, NaN where the view lacks either; two labels on the same
    pixels (within a pixel) count once."""
    a, b = _PAIR_A, _PAIR_B
    z = proj.R[:, 2] @ (0.5 * (X[a] + X[b])).T + proj.t[:, 2:]          # (C, 2) the pairs' middles' depths
    d = uv[:, a] - uv[:, b]
    same = d[..., 0] ** 2 + d[..., 1] ** 2 < 1.0
    px = np.where(same, np.fmax(area[:, a], area[:, b]), area[:, a] + area[:, b])
    return px * z ** 2 / (proj.K[:, 0, 0] * proj.K[:, 1, 1])[:, None]


def pair_area_reference(ref: np.ndarray, areas: np.ndarray, X: np.ndarray, duplicate_m: float) -> np.ndarray:
    """The reference ``ref`` (C, 2) of one limb's blob area per view and pair (m^2, NaN: none
    yet) followed by this frame's ``pair_areas`` (C, 2) halved where the pair's 3D cues X (6, 3)
    lie more than twice ``duplicate_m`` apart (two limbs, each its own blob)."""
    apart = np.linalg.norm(X[_PAIR_A] - X[_PAIR_B], axis=1) > 2 * duplicate_m       # (2,), False if missing
    one = np.where(apart, areas / 2, np.nan)
    return np.where(np.isnan(one), ref, np.where(np.isnan(ref), one, ref + PAIR_AREA_RATE * (one - ref)))


def seen_twice(X: np.ndarray, used: np.ndarray, returning: np.ndarray, areas: np.ndarray, ref: np.ndarray,
               duplicate_m: float) -> np.ndarray:
    """A copy of the 3D cues X (6, 3) without a hand or foot coming back (``returning`` (6,) bool:
    its track not alive or (re)started within ``RETURN_S``) on the other one of its pair: the two
    within ``duplicate_m`` and their blobs (``pair_areas`` (C, 2)) covering less than
    ``SEEN_TWICE_RATIO`` times one limb's (``pair_area_reference`` ``ref`` (C, 2)) in the median
    of at least two views. Both coming back: the label seen by fewer views (``used`` (C, 6) bool)
    goes. Distance alone cannot tell this from two hands held together; nor can the area two
    tracked hands that clap (one hides the other in most views): both kept."""
    X = X.copy()
    for p, (a, b) in enumerate(LR_PAIRS):
        back = [c for c in (a, b) if returning[c]]
        if not (back and np.isfinite(X[[a, b]]).all() and np.linalg.norm(X[a] - X[b]) < duplicate_m):
            continue
        r = areas[:, p] / ref[:, p]
        r = r[np.isfinite(r)]
        if r.size >= 2 and np.median(r) < SEEN_TWICE_RATIO:
            X[back[0] if len(back) == 1 else b if used[:, a].sum() >= used[:, b].sum() else a] = np.nan
    return X
