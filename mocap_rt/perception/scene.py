"""Scene-level checks of one camera's cues: the torso from the head and the trunk axis, and
the head kept on top of the trunk (issue 12, items 1 and 4).

Both use the silhouette's trunk: the centroid ``R`` of the distance-transform ridge band
(``torso.torso_point``), which lies on the trunk's medial axis, and the head blob ``H``.

**Torso.** The torso cue is the midpoint of pelvis and neck (``mocap_rt.names``). On the
studio's truth its image position lies on the line from the head through ``R`` (across it
a median 0.0 head radii, inter-quartile +-0.3) at a distance from the head that is a nearly
constant multiple of the head's image radius ``r`` (the head is a sphere: its image size
gives the scale at the person's depth in every view): 3.96 r (inter-quartile 3.90-4.04) on
the CMU skeleton, 3.46 r (3.38-3.52) on the Bandai-Namco one, measured over 6 cameras on
cmu_02_01 and the Bandai kick. So ``torso = H + k r (R - H) / |R - H|`` with
``k = TORSO_HEAD_RADII`` (3.7, between the two subjects' proportions) and ``r`` the median
of the head blob's recent equivalent radii. With fusion's prediction each of those radii is
first scaled to this frame's depth, by the ratio of this frame's predicted head radius to the
one predicted when it was measured (``SceneState.head_radius``): a person walking towards a
camera grows 2-3 % a frame, and the plain median of ``HISTORY_FRAMES`` lagged by 10-50 % (the
Bandai walk, one view: 109 px against 95 predicted, the torso 84-120 px off). The ridge
centroid itself slides along the trunk with the arms and legs (arms overhead lengthen the
band: 9-19 px median error at 640x480). Without a head, the ridge centroid is the cue.

**Head on the trunk.** In the 2D-only loop a hand passing over the face, or hands held
above the head at a cold start, can carry the head label away, and nothing brought it back.
The head is the skin region on top of the trunk's axis: on the truth above, the head lies
along the axis from ``R`` at 3.3-4.3 of its own radii (inter-quartile ranges over four
clips, arms overhead up to 5.8) and across it within +-0.35 radii. A blob passes as the
head when, measured in its own equivalent radius ``sqrt(area / pi)``, it lies
``HEAD_ALONG_RADII`` along and within ``HEAD_ACROSS_RADII`` across the axis (a hand is half
the head's size, so at the head's place it is twice as many of its own radii away; a hand
overhead is farther still, hands at the chest nearer). A head label that fails the test
for ``HEAD_CHECK_FRAMES`` frames in a row (at once if it never passed it: a cold start can take
a hand raised above the head for it) moves to the skin region that passes it best, of
those at least ``RESEAT_MIN_AREA_FRAC`` of the head's recent area (a hand is about a quarter of
it). The axis is the ridge band's principal axis pointing up the image (the image vertical
when the band is not elongated); an arm raised beside the head tilts it (37 deg on the
Bandai bye-bye, one view), the head then fails the test and a hand beside the face passes
it: without the size condition the head label went to that hand for 0.7 s.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from mocap_rt.perception.region_kernels import colour_regions

TORSO_HEAD_RADII = 3.7       # head -> torso distance in head image radii (module docstring)
HISTORY_FRAMES = 15          # recent head radii kept (px), for the torso's scale
HEAD_ALONG_RADII = (2.3, 6.5)    # a head lies this far along the trunk axis from the ridge centroid, own radii ...
HEAD_ACROSS_RADII = 1.2          # ... and at most this far across it
HEAD_CHECK_FRAMES = 3        # a head label failing the test this many frames in a row is re-seated
MIN_HEAD_AREA_PX = 30.0      # smallest skin region considered as a head
RESEAT_MIN_AREA_FRAC = 0.5   # ... and, once the head's size is known, at least this fraction of its area
ELONGATED = 1.5              # ridge band axis used when its two standard deviations differ by this ratio


@dataclass
class SceneState:
    """What persists between frames: recent head radii (px) and the frames the head label
    has failed the head test."""

    radii: deque = field(default_factory=lambda: deque(maxlen=HISTORY_FRAMES))
    pred_radii: deque = field(default_factory=lambda: deque(maxlen=HISTORY_FRAMES))  # predicted then (NaN: none)
    suspect_frames: int = 0
    confirmed: bool = False      # the head label has passed the head test once
    measured: int = 0            # head radii appended so far (the median changes only then)

    def head_radius(self, pred_radius: float = float("nan")) -> float:
        """Median recent head radius, px (NaN before any). With this frame's predicted head
        radius ``pred_radius`` (px), the radii measured with a prediction are scaled to this
        frame's depth first (each times ``pred_radius`` over the radius predicted then; module
        doc). ``statistics.median``, not ``np.median`` (its per-call overhead was ~20 us, once a
        frame)."""
        if math.isfinite(pred_radius) and pred_radius > 0:
            scaled = [r * pred_radius / p for r, p in zip(self.radii, self.pred_radii) if math.isfinite(p) and p > 0]
            if scaled:
                return float(statistics.median(scaled))
        return float(statistics.median(self.radii)) if self.radii else float("nan")


def trunk_up(ridge_cov: np.ndarray) -> tuple[float, float]:
    """Unit image direction (x, y) up the trunk from the ridge band's covariance (2, 2) px^2.
    Floats, not an array: a small array's cost is most of this function's in the pipeline."""
    (a, b), (_, d) = ridge_cov.tolist()
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(d)):
        return 0.0, -1.0
    # eigenvalues and the major axis of the symmetric 2x2 in closed form (np.linalg.eigh
    # cost ~30 us a frame)
    half_tr, disc = 0.5 * (a + d), math.hypot(0.5 * (a - d), b)
    if half_tr + disc < ELONGATED ** 2 * max(half_tr - disc, 1e-9):
        return 0.0, -1.0
    ang = 0.5 * math.atan2(2.0 * b, a - d)
    c, s = math.cos(ang), math.sin(ang)
    return (c, s) if s <= 0 else (-c, -s)


def head_score(xy: np.ndarray, area: float, ridge_xy: np.ndarray, up: tuple[float, float]) -> float:
    """How far a blob at ``xy`` (2,) px of ``area`` px^2 is from the head's place on the trunk,
    in its own radii (0 = the median head place; inf = fails the head test). Scalar arithmetic:
    NumPy's per-call overhead on (2,) arrays was most of this function's time."""
    r = math.sqrt(max(float(area), 0.0) / math.pi)
    x, y = float(xy[0]), float(xy[1])
    if not (math.isfinite(x) and math.isfinite(y) and r > 0):
        return math.inf
    dx, dy = x - float(ridge_xy[0]), y - float(ridge_xy[1])
    ux, uy = float(up[0]), float(up[1])
    along = (dx * ux + dy * uy) / r
    across = abs(dx * uy - dy * ux) / r
    if not (HEAD_ALONG_RADII[0] <= along <= HEAD_ALONG_RADII[1] and across <= HEAD_ACROSS_RADII):
        return math.inf
    return abs(along - TORSO_HEAD_RADII) + across


def torso_from_head(head_xy: np.ndarray, head_r: float, ridge_xy: np.ndarray,
                    k: float = TORSO_HEAD_RADII) -> tuple[float, float] | None:
    """Torso (x, y) px on the line head -> ridge centroid, ``k * head_r`` from the head; None
    when the head, its radius or the direction is unknown. Floats: NumPy's small arrays were
    most of this function's cost in the pipeline."""
    hx, hy, rx, ry = float(head_xy[0]), float(head_xy[1]), float(ridge_xy[0]), float(ridge_xy[1])
    if not (math.isfinite(hx) and math.isfinite(hy) and math.isfinite(head_r) and math.isfinite(rx)
            and math.isfinite(ry)):
        return None
    dx, dy = rx - hx, ry - hy
    n = float(np.hypot(dx, dy))                             # (not math.hypot: NumPy's last bit)
    if n < 1e-6:
        return None
    kr = k * head_r
    return hx + kr * dx / n, hy + kr * dy / n               # NumPy's order: (k r d) / n


def check_head(state: SceneState, head_xy: np.ndarray, head_area: float, head_conf: float,
               ridge_xy: np.ndarray, ridge_cov: np.ndarray, skin: np.ndarray,
               origin: tuple[int, int], pred_radius: float = float("nan")) -> tuple[np.ndarray, float] | None:
    """Update ``state`` with this frame's head; return a re-seated head ((2,) px, area px^2)
    or None. ``pred_radius``: the head's radius (px) fusion predicted for this frame, kept with
    the measured one (``SceneState.head_radius``; NaN: no prediction).

    head_xy (2,) px (NaN = not found), head_area px^2 and head_conf of the head blob;
    ridge_xy (2,) px, ridge_cov (2, 2) px^2 the ridge band (NaN = none); skin (h, w) colour map
    (uint8 {0, 1} or float, >= 0.5 = skin) of the person box whose top-left is ``origin`` (x, y) px.
    """
    if not (math.isfinite(ridge_xy[0]) and math.isfinite(ridge_xy[1])):
        return None
    up = trunk_up(ridge_cov)
    found = math.isfinite(head_xy[0]) and math.isfinite(head_xy[1]) and head_conf > 0
    if found and math.isfinite(head_score(head_xy, head_area, ridge_xy, up)):
        state.suspect_frames = 0
        state.confirmed = True
        if head_conf >= 0.9:                 # a full, visible blob: its size scales the torso
            state.radii.append(math.sqrt(head_area / math.pi))
            state.pred_radii.append(pred_radius)
            state.measured += 1
        return None
    state.suspect_frames += 1
    # a label that never passed has no evidence to keep: re-seated at once (a cold start took
    # a hand raised above the head for it, "the region nearest the silhouette's top")
    if state.confirmed and state.suspect_frames < HEAD_CHECK_FRAMES:
        return None
    r = state.head_radius()
    min_area = MIN_HEAD_AREA_PX
    if math.isfinite(r):
        min_area = max(min_area, RESEAT_MIN_AREA_FRAC * math.pi * r * r)
    best = _best_head_region(skin, ridge_xy - origin, up, min_area)
    if best is None:
        return None
    state.suspect_frames = 0
    return best[0] + origin, best[1]


def _best_head_region(skin: np.ndarray, ridge_xy: np.ndarray, up: tuple[float, float],
                      min_area: float) -> tuple[np.ndarray, float] | None:
    """(centroid (2,) array px, area px^2) of the connected skin region of ``skin`` (h, w) of
    at least ``min_area`` px^2 that passes the head test best (``head_score``), or None. The
    regions are the blob stage's (``region_kernels.colour_regions``: ``cv2.connectedComponents``'
    order, so ties go the same way)."""
    h, w = skin.shape
    n, stats = colour_regions(skin, 0, 0, w, h)
    best, best_score = None, np.inf
    for i in range(1, n):
        area = float(stats[i, 4])
        if area >= min_area:
            cent = stats[i, 5:7] / area
            score = head_score(cent, area, ridge_xy, up)
            if score < best_score:
                best, best_score = (cent, area), score
    return best
