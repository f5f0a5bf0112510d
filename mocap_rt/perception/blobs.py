"""Colour-blob tracking in one camera (seed digest A.2, A.4).

One ``BlobTracker`` follows the blobs of one colour model: the skin tracker follows head,
hand_l and hand_r, the shoe tracker foot_l and foot_r. Per frame:

1. **Initial labelling** (A.2): every colour pixel inside the person box goes to the blob
   whose predicted centre is nearest (within a gate); the pixels give the Gaussian blob
   (mean mu', covariance Sigma').
2. **Deformable ellipse** (A.2, eq. 3-4): for a blob predicted visible the ellipse boundary
   is moved along its normals to where a window is half colour (maximum separability J);
   the cue is the centroid of the region inside the deformed contour. A blob predicted
   occluded (``CuePrediction.visible`` False, A.4) keeps its initial ellipse: the cue is mu'.
3. **Loss and re-acquisition**: a blob with too few pixels is lost for this frame; its 2D
   track coasts on constant velocity for ``max_coast_frames``. Lost or never-seen blobs are
   (re)acquired from the connected colour regions no tracked blob claims: the head is the
   region nearest the top of the silhouette, hands/feet the largest remaining regions.

Identity (left/right) through crossings comes from the predictions: while two hands
overlap both are labelled from the same region by proximity, and they separate again
along their predicted paths. With the fusion's 3D prediction (A.4) identities are those of
the body model; with the 2D-only prediction a cold start assumes the person faces the
camera (image-left = person's right), which the 3D tracker later corrects.

Coordinates: pixels of the full image unless a name says ``roi``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from mocap_rt.perception.blob_kernels import N_MOMENTS, REFINE_PARAMS, label_and_refine, params_record
from mocap_rt.perception.region_kernels import acquire_regions
from mocap_rt.perception.track_kernels import GATE_PARAMS, expected_blobs, finish_frame, label_frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BlobParams:
    """Tuning of one colour-blob tracker (pixels at the camera's resolution)."""

    min_area_px: float = 6.0            # fewer labelled pixels: blob lost this frame
    acquire_min_area_px: float = 10.0   # smallest region a lost blob is re-acquired from
    gate_radius_factor: float = 1.5     # labelling gate = factor * blob semi-major axis ...
    gate_min_px: float = 8.0            # ... but at least this
    gate_unknown_px: float = 30.0       # gate while the blob's size is unknown
    gate_speed_factor: float = 1.0      # ... plus this times the 2D speed (px/frame)
    max_coast_frames: int = 3           # coast a lost blob this long before re-acquiring
    ellipse_scale: float = 2.0          # initial ellipse at 2 sigma (edge of a uniform ellipse)
    n_contour_pts: int = 32             # perimeter points of the deformable ellipse
    search_frac: float = 0.4            # boundary search range, fraction of the local radius
    search_min_px: float = 3.0          # ... at least this
    window_half_px: int = 2             # J(p) window half length along the normal
    max_refine_shift_frac: float = 0.6  # deformed centroid may move this * radius from mu'
    mirror_iters: int = 20              # occlusion completion rounds (converges; blob_kernels.deform_ellipse)
    exclusive_pixels: bool = True       # boundary search ignores colour pixels of the other blobs
    facing_camera: bool = True          # cold-start convention: image-left = person's right
    snap_to_regions: bool = True        # label around the blobs' own colour regions when each has one
    acquire_lone_region: bool = True    # one region for a missing left/right pair: acquire it for one of them
    label_by_shape: bool = False        # label by each blob's covariance when last apart (Gaussian discriminant),
                                        # not its size; apart is told by snap_to_regions (off: by size)


@dataclass
class BlobFrame:
    """One frame of a tracker: arrays over the tracker's K cues, full-image pixels."""

    xy: np.ndarray          # (K, 2) float64, NaN where lost
    cov: np.ndarray         # (K, 2, 2) float64 px^2, Gaussian blob covariance
    area: np.ndarray        # (K,) float64 px^2 (deformed region, or pixel count if occluded)
    confidence: np.ndarray  # (K,) float64 in [0, 1]


_NO_SIL = np.zeros((1, 1), np.uint8)
# Region snap (``BlobParams.snap_to_regions``, ``track_kernels.label_frame``): the prediction
# guides, the evidence decides. When every predicted blob of a tracker has its own connected
# colour region within reach (gate + the region's half size), the regions are assigned to the
# blobs by the least total distance (all one-to-one assignments, K <= 3) and each blob is
# labelled around its region's centre. Only for blobs within SNAP_NEAR_GATES x their two gates
# of each other (elsewhere proximity cannot mix them up, and a missing blob is re-acquired). A
# fast limb makes the prediction lag (a swinging foot moves ~0.1 m a frame), and labelling
# pixels by proximity to lagging predictions splits one shoe between both feet or hands the
# swing foot to the standing one. Merged regions (touching shoes) are too few: then the
# predictions stay the centres.
SNAP_WINDOW_GATES = 2.5     # region snap: search window around the predicted blobs, in gate radii
SNAP_MAX_REGIONS = 5        # ... and at most this many candidate regions (nearest first)
SNAP_NEAR_GATES = 2.0       # ... only for blobs nearer each other than this many times their two gates
ACQUIRE_MAX_REGIONS = 4     # re-acquisition considers the largest this many unclaimed regions
# Relative image sizes of the blobs (the 3D cue radii of A.4: head 0.10 m, hand 0.05 m, shoe
# 0.06 m): initial labelling splits a region shared by two blobs where their discs touch
# (``blob_kernels.label_moments``): a hand on the head no longer takes half the face.
ROLE_SIZE = {"head": 2.0, "hand_l": 1.0, "hand_r": 1.0, "foot_l": 1.0, "foot_r": 1.0}
_NAN_K2 = np.full((8, 2), np.nan)       # "no prediction" placeholders (K <= 8)
_NAN_K = np.full(8, np.nan)
_NO_SHAPE = np.zeros((0, 2, 2))


class BlobTracker:
    """Tracks the K blobs ``roles`` of one colour in one camera."""

    def __init__(self, roles: tuple[str, ...], params: BlobParams = BlobParams()) -> None:
        self.roles = tuple(roles)
        self.params = params
        K = len(self.roles)
        self._xy = np.full((K, 2), np.nan)       # last measured position (full image px)
        self._vel = np.zeros((K, 2))             # px / frame
        self._radius = np.full(K, np.nan)        # px
        self._coast = np.zeros(K, np.int64)      # frames since last measurement
        self._last_seen = np.full((K, 2), np.nan)  # last measured position, kept while lost
        self._sums = np.zeros((K, N_MOMENTS))
        self._out_xy = np.zeros((K, 2))
        self._out_cov = np.zeros((K, 2, 2))
        self._apart_cov = np.zeros((K, 2, 2))   # each blob's covariance when last apart from the others
        self._out_area = np.zeros(K)
        self._out_contours = np.zeros((K, params.n_contour_pts, 2))
        self._has_contour = np.zeros(K, np.bool_)
        self._offset = (0, 0)                     # last frame's ROI top-left, image px
        self._all_visible = np.ones(K, np.bool_)
        self._none_acquired = np.zeros(K, np.bool_)
        self._size = np.array([ROLE_SIZE.get(r, 1.0) for r in self.roles])
        self._acq_cand = np.empty((ACQUIRE_MAX_REGIONS, 4))   # acquire_candidates' output
        self._kp = params_record(REFINE_PARAMS, params)
        self._kp_nomirror = params_record(REFINE_PARAMS, params, mirror_iters=0)
        self._gate_params = params_record(GATE_PARAMS, params)
        self._shape_arg = self._apart_cov if params.label_by_shape else _NO_SHAPE
        self._centers = np.empty((K, 2))         # this frame's labelling centres (ROI px) and gates
        self._gate = np.empty(K)
        self._found = np.empty(K, np.bool_)

    def reseat(self, k: int, xy: np.ndarray, radius_px: float) -> None:
        """Put blob k's track at ``xy`` (2,) image px, at rest, with semi-major axis
        ``radius_px`` (a scene-level correction); another blob tracked on that spot loses its
        track (it is re-acquired from the regions left)."""
        for j in range(len(self.roles)):
            if j != k and np.hypot(*(self._xy[j] - xy)) < radius_px:
                self._xy[j] = np.nan
                self._coast[j] = self.params.max_coast_frames + 1
        self._xy[k] = xy
        self._last_seen[k] = xy
        self._vel[k] = 0.0
        self._coast[k] = 0
        self._radius[k] = radius_px

    def expected(self, out: np.ndarray) -> None:
        """Where the blobs' own tracks expect them in the coming frame and their semi-major axes:
        ``out`` (K, 3) x, y, radius, image px (constant velocity; NaN once lost longer than
        ``max_coast_frames``)."""
        expected_blobs(self._xy, self._vel, self._coast, self._radius, self.params.max_coast_frames, out)

    # ------------------------------------------------------------------ per frame
    def step(self, skin_roi: np.ndarray, roi_xy: tuple[int, int], person_box_roi: tuple[int, int, int, int],
             top_roi: tuple[float, float] | None, pred_xy: np.ndarray | None = None,
             pred_visible: np.ndarray | None = None, pred_radius: np.ndarray | None = None,
             sil_roi: np.ndarray | None = None, pred_shape: np.ndarray | None = None,
             out: BlobFrame | None = None) -> BlobFrame:
        """Track one frame.

        skin_roi : (h, w) colour map of the region of interest, float32 (>= 0.5 = colour pixel) or
            uint8 {0, 1} (the pipeline's: 1 = colour pixel)
            (already restricted to the silhouette).
        roi_xy : (x, y) of the ROI's top-left pixel in the image.
        person_box_roi : (x, y, w, h) of the silhouette in ROI pixels.
        top_roi : (x, y) ROI pixels of the silhouette's top (head acquisition), or None.
        pred_xy, pred_visible, pred_radius : (K, 2), (K,), (K,) prediction for this frame in
            image pixels (from fusion, A.4); None = use the tracker's own 2D prediction.
        sil_roi : (h, w) uint8 silhouette of the ROI (> 0 = person) for occlusion completion;
            None = no completion.
        pred_shape : (K, 2, 2) predicted covariance of each blob, px^2 (not finite: none), for
            ``label_by_shape``: it replaces the shape when last apart (one that is not positive
            definite turns the shapes off for the frame, ``label_moments``).
        out : the frame's arrays to write (e.g. views of a camera's cue arrays) and return;
            None: new ones.
        """
        p = self.params
        K = len(self.roles)
        ox, oy = roi_xy
        bx, by, bw, bh = person_box_roi
        res = out if out is not None else BlobFrame(np.empty((K, 2)), np.empty((K, 2, 2)), np.empty(K), np.empty(K))
        if bw <= 0 or bh <= 0:
            self._coast += 1
            self._has_contour[:] = False
            res.xy[:], res.cov[:], res.area[:], res.confidence[:] = np.nan, np.nan, 0.0, 0.0
            return res
        use_pred = pred_xy is not None
        visible = self._all_visible if pred_visible is None else np.asarray(pred_visible, np.bool_)
        sil = sil_roi if sil_roi is not None else _NO_SIL
        kp = self._kp if sil_roi is not None and p.mirror_iters else self._kp_nomirror
        box = (bx, by, bx + bw, by + bh)
        centers, gate, found = self._centers, self._gate, self._found
        shape = self._shape_arg
        if pred_shape is not None and p.label_by_shape:
            shape = np.where(np.isfinite(pred_shape).all(axis=(1, 2))[:, None, None], pred_shape, self._apart_cov)
        apart, n_found = label_frame(
            skin_roi, sil, *box, self._xy, self._vel, self._coast, self._radius, p.max_coast_frames,
            np.asarray(pred_xy, np.float64) if use_pred else _NAN_K2,
            np.asarray(pred_radius, np.float64) if use_pred and pred_radius is not None else _NAN_K,
            use_pred, float(ox), float(oy), self._gate_params, p.snap_to_regions, SNAP_NEAR_GATES, SNAP_WINDOW_GATES,
            p.acquire_min_area_px, SNAP_MAX_REGIONS, self._size, visible, kp,
            self._sums, self._out_xy, self._out_cov, self._out_area, self._out_contours, self._has_contour,
            shape, centers, gate, found)
        acquired = self._none_acquired
        got = self._acquire(skin_roi, box, centers, found, top_roi, ox, oy) if n_found < K else None
        if got is not None and got.any():
            acquired = got
            centers = np.where(acquired[:, None], self._acq_centers, centers)
            gate = np.where(acquired, np.maximum(gate, self._acq_gate), gate)
            found = self._run(skin_roi, sil, box, centers, gate, visible, kp, shape)
        # with label_by_shape and the blobs apart (each blob's pixels its own region): their shapes
        # are kept for the frames they touch
        finish_frame(self._sums[:, 0], found, visible, acquired, 4.0 * p.min_area_px, float(ox), float(oy),
                     self._out_xy, self._out_cov, res.xy, res.confidence, self._xy, self._vel, self._radius,
                     self._coast, self._last_seen, int(p.max_coast_frames), self._has_contour,
                     p.label_by_shape and apart, self._apart_cov, self._out_area, res.cov, res.area)
        self._offset = roi_xy
        return res

    def last_contours(self) -> list:
        """The last frame's deformed contours, K entries: (n_pts, 2) float64 image px, or None
        (occluded, lost, or the refinement rejected)."""
        offset = np.array(self._offset, np.float64)
        return [c + offset if has else None for c, has in zip(self._out_contours, self._has_contour.tolist())]

    def _run(self, skin_roi, sil, box, centers, gate, visible, kp, shape) -> np.ndarray:
        label_and_refine(skin_roi, sil, box[0], box[1], box[2], box[3], np.ascontiguousarray(centers, np.float64),
                         np.ascontiguousarray(gate, np.float64), self._size, visible,
                         kp, self._sums, self._out_xy,
                         self._out_cov, self._out_area, self._out_contours, self._has_contour, shape)
        return self._sums[:, 0] >= self.params.min_area_px

    # ------------------------------------------------------------------ internals
    def _acquire(self, skin_roi, box, centers, found, top_roi, ox, oy) -> np.ndarray | None:
        """Assign unclaimed colour regions to the blobs not found (``found`` False); sets
        ``_acq_centers``/``_acq_gate`` and returns which were acquired (None: no candidate)."""
        p = self.params
        x0, y0, x1, y1 = box
        n_cand = acquire_regions(skin_roi, x0, y0, x1, y1, self._sums, found, p.acquire_min_area_px, self._acq_cand)
        if n_cand == 0:
            return None
        K = len(self.roles)
        missing = ~found
        last_seen = self._last_seen - (ox, oy)
        self._acq_centers = np.full((K, 2), np.nan)
        self._acq_gate = np.zeros(K)
        acquired = np.zeros(K, bool)
        cand = [(area, np.array([cx, cy]), half) for area, cx, cy, half in self._acq_cand[:n_cand].tolist()]

        def take(k: int, i: int) -> None:
            _, c, half = cand.pop(i)
            self._acq_centers[k] = c
            self._acq_gate[k] = half * 1.5
            acquired[k] = True

        # 1) a recently seen blob takes the candidate nearest its predicted position
        for k in np.flatnonzero(missing):
            if cand and np.isfinite(centers[k]).all():
                d = [np.hypot(*(c - centers[k])) for _, c, _ in cand]
                i = int(np.argmin(d))
                if d[i] <= 3.0 * max(cand[i][2], p.gate_min_px):
                    take(k, i)

        # 2) the head: the candidate nearest the silhouette's top
        roles = self.roles
        if "head" in roles:
            k = roles.index("head")
            if missing[k] and not acquired[k] and cand and top_roi is not None:
                big = [i for i, t in enumerate(cand) if t[0] >= 0.3 * cand[0][0]]
                d = [np.hypot(*(cand[i][1] - top_roi)) for i in big]
                take(k, big[int(np.argmin(d))])
        # 3) left/right pairs: the largest remaining regions, by image x
        pairs = [(roles.index(a), roles.index(b)) for a, b in (("hand_l", "hand_r"), ("foot_l", "foot_r"))
                 if a in roles and b in roles]
        for kl, kr in pairs:
            need = [k for k in (kl, kr) if missing[k] and not acquired[k]]
            if len(need) == 2 and len(cand) >= 2:
                i_left, i_right = (0, 1) if cand[0][1][0] <= cand[1][1][0] else (1, 0)
                if np.isfinite(last_seen[[kl, kr]]).all():
                    # both were seen before: the pairing nearest their last positions
                    c_l, c_r = cand[i_left][1], cand[i_right][1]
                    keep = (np.hypot(*(c_l - last_seen[kl])) + np.hypot(*(c_r - last_seen[kr])) <=
                            np.hypot(*(c_l - last_seen[kr])) + np.hypot(*(c_r - last_seen[kl])))
                    k_imgleft, k_imgright = (kl, kr) if keep else (kr, kl)
                else:
                    # cold start, person facing the camera: their right hand is on the image's left
                    k_imgleft, k_imgright = (kr, kl) if p.facing_camera else (kl, kr)
                c_left, c_right = cand[i_left], cand[i_right]
                cand[:] = [t for i, t in enumerate(cand) if i not in (0, 1)]
                cand.insert(0, c_right)
                cand.insert(0, c_left)
                take(k_imgleft, 0)
                take(k_imgright, 0)
            elif len(need) == 2 and len(cand) == 1 and p.acquire_lone_region:
                # one region for two blobs (the other hidden, out of the image, or too
                # small): it goes to the nearer last-seen one, or on a cold start to the side
                # it is on (person facing the camera: image-left = their right); fusion's
                # cross-view left/right agreement corrects the guess
                c = cand[0][1]
                if np.isfinite(last_seen[[kl, kr]]).all():
                    k = kl if np.hypot(*(c - last_seen[kl])) <= np.hypot(*(c - last_seen[kr])) else kr
                else:
                    on_left = c[0] < 0.5 * (x0 + x1)
                    k = (kr if on_left else kl) if p.facing_camera else (kl if on_left else kr)
                take(k, 0)
            elif len(need) == 1 and cand:
                take(need[0], 0)
        return acquired
