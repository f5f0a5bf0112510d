"""Numba kernels of a blob tracker's frame (seed digest A.2, A.4): the labelling centres and
gates from the track or the prediction, the region snap and the labelling up to the cues
(``label_frame``), and the frame's end (the cues in image pixels, their confidences, the
updated tracks: ``finish_frame``), one call each.

Coordinates: ``roi`` pixels where a name says so, else image pixels; speeds px / frame.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mocap_rt.perception.blob_kernels import label_and_refine
from mocap_rt.perception.region_kernels import colour_regions, snap_regions, snap_window

# The settings of ``predict_gates`` (from ``blobs.BlobParams``): a (1,) structured array read by
# field name (``blob_kernels.params_record``).
GATE_PARAMS = np.dtype([("gate_min_px", "f8"), ("gate_radius_factor", "f8"), ("gate_unknown_px", "f8"),
                        ("gate_speed_factor", "f8")])


@numba.njit(cache=True, nogil=True)
def update_tracks(found, new_xy, new_cov, xy, vel, radius, coast, last_seen, max_coast):  # pragma: no cover
    """2D track state after a frame: velocity (px/frame), position, semi-major axis (2 sigma, px)."""
    for k in range(found.shape[0]):
        if not found[k]:
            coast[k] += 1
            continue
        if coast[k] <= max_coast and math.isfinite(xy[k, 0]) and math.isfinite(xy[k, 1]):
            vel[k, 0] = (new_xy[k, 0] - xy[k, 0]) / (1 + coast[k])
            vel[k, 1] = (new_xy[k, 1] - xy[k, 1]) / (1 + coast[k])
        else:
            vel[k, 0] = 0.0
            vel[k, 1] = 0.0
        xy[k, 0] = new_xy[k, 0]
        xy[k, 1] = new_xy[k, 1]
        last_seen[k, 0] = new_xy[k, 0]
        last_seen[k, 1] = new_xy[k, 1]
        tr = 0.5 * (new_cov[k, 0, 0] + new_cov[k, 1, 1])
        l1 = tr + math.sqrt(0.25 * (new_cov[k, 0, 0] - new_cov[k, 1, 1]) ** 2 + new_cov[k, 0, 1] ** 2)
        radius[k] = 2.0 * math.sqrt(max(l1, 0.25))
        coast[k] = 0


@numba.njit(cache=True, nogil=True, inline="always")
def _coasted(xy, vel, coast, max_coast, k):  # pragma: no cover - numba
    """Blob k's own prediction for the coming frame (constant velocity, image px), NaN after
    ``max_coast`` lost frames."""
    if coast[k] > max_coast:
        return np.nan, np.nan
    return xy[k, 0] + vel[k, 0] * (1 + coast[k]), xy[k, 1] + vel[k, 1] * (1 + coast[k])


@numba.njit(cache=True, nogil=True)
def expected_blobs(xy, vel, coast, radius, max_coast, out):  # pragma: no cover - numba
    """``out`` (K, 3): each blob's position expected in the coming frame from its own track
    (``_coasted``, image px) and its semi-major axis ``radius`` (px)."""
    for k in range(xy.shape[0]):
        out[k, 0], out[k, 1] = _coasted(xy, vel, coast, max_coast, k)
        out[k, 2] = radius[k]


@numba.njit(cache=True, nogil=True)
def predict_gates(xy, vel, coast, radius, max_coast, pred_xy, pred_radius, use_pred, ox, oy, gp,
                  centers, gate):  # pragma: no cover - numba
    """Labelling centres (ROI px) and gate radii of one tracker for a frame.

    Own prediction: ``_coasted`` (constant velocity, NaN after ``max_coast`` lost frames). With
    ``use_pred`` the given prediction (image px) wins where finite, and the radius is the
    larger of the predicted one and the blob's own semi-major axis. gp: (1,) ``GATE_PARAMS`` record.
    """
    q = gp[0]
    for k in range(xy.shape[0]):
        cx, cy = _coasted(xy, vel, coast, max_coast, k)
        r = radius[k]
        if use_pred:
            if math.isfinite(pred_xy[k, 0]) and math.isfinite(pred_xy[k, 1]):
                cx = pred_xy[k, 0]
                cy = pred_xy[k, 1]
            if math.isfinite(pred_radius[k]) and (not math.isfinite(r) or pred_radius[k] > r):
                r = pred_radius[k]
        centers[k, 0] = cx - ox
        centers[k, 1] = cy - oy
        g = max(q.gate_min_px, q.gate_radius_factor * r) if math.isfinite(r) else q.gate_unknown_px
        gate[k] = g + q.gate_speed_factor * math.hypot(vel[k, 0], vel[k, 1])


@numba.njit(cache=True, nogil=True)
def finish_frame(n_px, found, visible, acquired, full_px, ox, oy, roi_xy, cov, xy_img, conf, xy, vel, radius, coast,
                 last_seen, max_coast, has_contour, keep_shape, apart_cov, area, out_cov, out_area):  # pragma: no cover
    """The end of a tracker's frame, for its K blobs.

    n_px (K,) labelled pixels, found / visible / acquired (K,) bool (visible: predicted
    visible; acquired: re-acquired this frame), full_px: pixels of a full-confidence blob;
    roi_xy (K, 2) cues in ROI px whose top-left is image pixel (ox, oy), cov (K, 2, 2) px^2.
    Writes xy_img (K, 2) the cues in image px and conf (K,) =
    min(1, n_px / full_px) x (0.5 if occluded) x (0.5 if acquired) x found, as
    ``BlobTracker.step`` computed them in NumPy (same operations, same order); then the track
    state (``update_tracks``). A blob not found loses its contour (``has_contour`` (K,) bool);
    with ``keep_shape`` each found blob's cov is kept in ``apart_cov`` (K, 2, 2) (its shape
    while apart from the others, ``BlobParams.label_by_shape``). cov and area (K,) are copied to
    out_cov and out_area (the frame's outputs).
    """
    for k in range(found.shape[0]):
        has_contour[k] = has_contour[k] and found[k]
        if keep_shape and found[k]:
            apart_cov[k] = cov[k]
        xy_img[k, 0] = roi_xy[k, 0] + ox
        xy_img[k, 1] = roi_xy[k, 1] + oy
        conf[k] = (min(1.0, n_px[k] / full_px) * (1.0 if visible[k] else 0.5) * (0.5 if acquired[k] else 1.0)
                   * (1.0 if found[k] else 0.0))
        out_cov[k] = cov[k]
        out_area[k] = area[k]
    update_tracks(found, xy_img, cov, xy, vel, radius, coast, last_seen, max_coast)


@numba.njit(cache=True, nogil=True)
def snap_centres(skin, x0, y0, x1, y1, centers, gate, near_gates, window_gates, min_area,
                 max_regions):  # pragma: no cover - numba
    """The region snap (``blobs``, SNAP_*) of labelling centres (K, 2) ROI px, in place, in the box
    [x0, x1) x [y0, y1): ``snap_window``, its ``colour_regions``, ``snap_regions``. Returns
    whether the blobs are apart: none near another (no window), or each snapped onto its own region."""
    if centers.shape[0] < 2:
        return False
    wx0, wy0, wx1, wy1 = snap_window(centers, gate, x0, y0, x1, y1, near_gates, window_gates)
    if wx1 <= wx0:
        return True
    n, stats = colour_regions(skin, wx0, wy0, wx1, wy1)
    # in place: snap_regions reads every centre before it writes one
    return snap_regions(stats, n, wx0, wy0, centers, gate, min_area, max_regions, centers)


@numba.njit(cache=True, nogil=True)
def label_frame(skin, sil, x0, y0, x1, y1, xy, vel, coast, radius, max_coast, pred_xy, pred_radius, use_pred,
                ox, oy, gp, snap, near_gates, window_gates, snap_min_area, snap_max_regions, size, visible, kp,
                sums, out_xy, cov, area, contours, has_contour, shape, centers, gate, found):  # pragma: no cover
    """A tracker frame up to its cues, in one call (``blobs.BlobTracker.step``): the labelling
    centres and gates (``predict_gates``), with ``snap`` the centres moved onto the blobs'
    own colour regions (``snap_centres``, settings ``near_gates`` ... ``snap_max_regions``),
    then labelling and deformable ellipses (``label_and_refine``) in the box [x0, x1) x
    [y0, y1) ROI px.

    Writes centers (K, 2) ROI px and gate (K,) as used, ``label_and_refine``'s outputs and
    found (K,) = at least ``kp``'s ``min_area_px`` pixels. Returns (whether the blobs are
    apart: each snapped onto its own region, or none near another; False without ``snap``,
    how many were found).
    """
    predict_gates(xy, vel, coast, radius, max_coast, pred_xy, pred_radius, use_pred, ox, oy, gp, centers, gate)
    apart = False
    if snap:
        apart = snap_centres(skin, x0, y0, x1, y1, centers, gate, near_gates, window_gates, snap_min_area,
                             snap_max_regions)
    label_and_refine(skin, sil, x0, y0, x1, y1, centers, gate, size, visible, kp, sums, out_xy, cov, area,
                     contours, has_contour, shape)
    min_area = kp[0].min_area_px
    n_found = 0
    for k in range(found.shape[0]):
        found[k] = sums[k, 0] >= min_area
        n_found += found[k]
    return apart, n_found
