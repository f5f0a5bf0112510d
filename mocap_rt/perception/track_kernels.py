"""Numba kernels of a blob tracker's 2D track state (seed digest A.2, A.4): each frame's
labelling centres and gates from the track or the prediction, and its end (the cues in
image pixels, their confidences, the updated tracks) in one call each.

Coordinates: ``roi`` pixels where a name says so, else image pixels; speeds px / frame.
"""

from __future__ import annotations

import math

import numba
import numpy as np

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


@numba.njit(cache=True, nogil=True)
def predict_gates(xy, vel, coast, radius, max_coast, pred_xy, pred_radius, use_pred, ox, oy, gp,
                  centers, gate):  # pragma: no cover - numba
    """Labelling centres (ROI px) and gate radii of one tracker for a frame.

    Own prediction: constant velocity, NaN after ``max_coast`` lost frames. With
    ``use_pred`` the given prediction (image px) wins where finite, and the radius is the
    larger of the predicted one and the blob's own semi-major axis. gp: (1,) ``GATE_PARAMS`` record.
    """
    q = gp[0]
    for k in range(xy.shape[0]):
        if coast[k] > max_coast:
            cx = np.nan
            cy = np.nan
        else:
            cx = xy[k, 0] + vel[k, 0] * (1 + coast[k])
            cy = xy[k, 1] + vel[k, 1] * (1 + coast[k])
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
                 last_seen, max_coast):  # pragma: no cover - numba
    """The end of a tracker's frame, for its K blobs.

    n_px (K,) labelled pixels, found / visible / acquired (K,) bool (visible: predicted
    visible; acquired: re-acquired this frame), full_px: pixels of a full-confidence blob;
    roi_xy (K, 2) cues in ROI px whose top-left is image pixel (ox, oy), cov (K, 2, 2) px^2.
    Writes xy_img (K, 2) the cues in image px and conf (K,) =
    min(1, n_px / full_px) x (0.5 if occluded) x (0.5 if acquired) x found, as
    ``BlobTracker.step`` computed them in NumPy (same operations, same order); then the track
    state (``update_tracks``).
    """
    for k in range(found.shape[0]):
        xy_img[k, 0] = roi_xy[k, 0] + ox
        xy_img[k, 1] = roi_xy[k, 1] + oy
        conf[k] = (min(1.0, n_px[k] / full_px) * (1.0 if visible[k] else 0.5) * (0.5 if acquired[k] else 1.0)
                   * (1.0 if found[k] else 0.0))
    update_tracks(found, xy_img, cov, xy, vel, radius, coast, last_seen, max_coast)
