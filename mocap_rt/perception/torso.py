"""Torso cue from the silhouette: the centre of the trunk's distance-transform ridge.

The trunk is the thickest part of a person's silhouette, so the maximum of the Euclidean
distance transform (``cv2.distanceTransform``, distance of each silhouette pixel to the
background) lies in it. The maximum alone is unstable along the trunk, whose
distance-transform ridge is nearly flat over its length, so the cue is the centroid of
the ridge: the silhouette pixels whose distance is at least ``ridge_frac`` of the
maximum (the trunk's medial band, which arms, head and single legs are too thin to reach).

Bias against the true torso centre (midpoint of pelvis and neck, ``mocap_rt.names``):
the band spans the trunk between the shoulders' and the hips' widening, so it is centred
near mid-trunk in a front view; in a side view the trunk is thinner and the band
is shorter and noisier; with the legs together the band can extend below the hips and
the cue drops toward the pelvis; arms held against the body widen the chest and raise it.
Measured figures are in ``docs/perception.md``. Fusion should treat the torso cue as a
coarse cue (its covariance is the ridge's spread).
"""

from __future__ import annotations

import cv2
import numpy as np

# Fraction of the distance-transform maximum that defines the trunk's ridge band.
DEFAULT_RIDGE_FRAC = 0.85


def torso_point(silhouette: np.ndarray, ridge_frac: float = DEFAULT_RIDGE_FRAC, step: int = 1
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """Torso point of ``silhouette`` (h, w) uint8 {0, 255} (one person, in its box).

    step : evaluate on every ``step``-th pixel (2 at 640x480 quarters the distance
        transform's cost; the ridge centroid still averages many pixels).
    Returns (xy (2,) float64 pixels of the array, cov (2, 2) px^2 of the ridge band,
    thickness_px = the distance-transform maximum, i.e. the trunk's half width). xy is NaN
    when the silhouette is empty.
    """
    sil = np.ascontiguousarray(silhouette[::step, ::step]) if step > 1 else silhouette
    if sil.size == 0:
        return np.full(2, np.nan), np.full((2, 2), np.nan), 0.0
    dist = cv2.distanceTransform(sil, cv2.DIST_L2, cv2.DIST_MASK_5)     # (h, w) float32 px / step
    _, peak, _, _ = cv2.minMaxLoc(dist)
    if peak <= 0:
        return np.full(2, np.nan), np.full((2, 2), np.nan), 0.0
    band = (dist >= ridge_frac * peak).view(np.uint8)
    m = cv2.moments(band, binaryImage=True)
    n = m["m00"]
    xy = np.array([m["m10"] / n, m["m01"] / n]) * step
    cov = (np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / n + np.eye(2) / 12.0) * step * step
    return xy, cov, float(peak) * step
