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

**Loops the body makes.** The silhouette's holes are filled (seed digest B.8): a person pixel
the change test missed is a hole too. But a hand behind the head, on it or on the hip closes a
loop of arm around background, and filled, that loop is the thickest part of the silhouette:
the ridge moved onto the shoulder and the head's torso cue (``scene.torso_from_head``) 46 px
off in a view (the hand behind the head, 640x480). So the background seen through a hole of
at least ``HOLE_HEAD_AREAS`` of the head's image area is taken out again before the distance
transform (``components.clear_large_holes``); the change test's missed pixels make holes of
under 0.05 of it.

**Head and arms in one blob.** Hands on the head seen from the side show no background between
arm and head: head, forearms and upper arms make one blob thicker than the trunk, and the
torso cue landed 80-100 px off beside the shoulder (the hands on the head s1007, camera 4). The
trunk's middle lies 3.5-4 head radii from the head (``scene.TORSO_HEAD_RADII``); a ridge
centroid within ``RIDGE_MIN_HEAD_RADII`` of it is the head's blob, and the ridge is measured
again without the silhouette within that distance of the head (``torso_point``'s ``head``).
Left out in every frame instead, the bent trunk of a crouch lost its top (docs/perception.md).
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

from mocap_rt.perception.components import clear_large_holes

# Fraction of the distance-transform maximum that defines the trunk's ridge band.
DEFAULT_RIDGE_FRAC = 0.85
# A hole of the filled silhouette of at least this fraction of the head's image area is
# background seen through a loop of the body (module doc); 0.08-0.3 measured alike
HOLE_HEAD_AREAS = 0.15
# A ridge centroid nearer the head than this many head radii is not the trunk's middle (module doc)
RIDGE_MIN_HEAD_RADII = 2.5


def torso_point(silhouette: np.ndarray, ridge_frac: float = DEFAULT_RIDGE_FRAC, step: int = 1,
                loops: tuple[np.ndarray, np.ndarray, float] | None = None,
                head: tuple[float, float, float] | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Torso point of ``silhouette`` (h, w) uint8 {0, 255} (one person, in its box).

    step : evaluate on every ``step``-th pixel (2 at 640x480 quarters the distance
        transform's cost; the ridge centroid still averages many pixels).
    loops : (member, change, min_area_px): the filled component and the change codes (h, w)
        of the box and the least hole area (px) to take out as a loop of the body
        (``components.clear_large_holes``, module doc); None: the silhouette as it is.
    head : (x, y, radius) px of the head blob in the array; a ridge centroid within
        ``RIDGE_MIN_HEAD_RADII`` radii of it is measured again without the silhouette that
        near the head (module doc). None: no head.
    Returns (xy (2,) float64 pixels of the array, cov (2, 2) px^2 of the ridge band,
    thickness_px = the distance-transform maximum, i.e. the trunk's half width). xy is NaN
    when the silhouette is empty.
    """
    sil = np.ascontiguousarray(silhouette[::step, ::step]) if step > 1 else silhouette
    if loops is not None:
        member, change, min_area_px = loops
        sil = clear_large_holes(sil, member, change, step, min_area_px / (step * step))
    out = _ridge(sil, ridge_frac, step)
    if head is not None and math.isfinite(head[0]) and math.isfinite(head[1]) and math.isfinite(head[2]) \
            and head[2] > 0:
        near = RIDGE_MIN_HEAD_RADII * head[2]
        if math.hypot(out[0][0] - head[0], out[0][1] - head[1]) < near:
            yy, xx = np.ogrid[:sil.shape[0], :sil.shape[1]]
            away = sil * ((xx * step - head[0]) ** 2 + (yy * step - head[1]) ** 2 >= near * near)
            again = _ridge(away.astype(np.uint8), ridge_frac, step)
            if np.isfinite(again[0]).all():
                out = again
    return out


def _ridge(sil: np.ndarray, ridge_frac: float, step: int) -> tuple[np.ndarray, np.ndarray, float]:
    """``torso_point``'s measurement of the sampled silhouette ``sil`` (coordinates times ``step``)."""
    if sil.size == 0:
        return np.full(2, np.nan), np.full((2, 2), np.nan), 0.0
    dist = cv2.distanceTransform(sil, cv2.DIST_L2, cv2.DIST_MASK_5)     # (h, w) float32 px / step
    return ridge_point(ridge_moments(dist, ridge_frac), step)


@numba.njit(cache=True, nogil=True)
def ridge_point(m, step):  # pragma: no cover - numba
    """(xy (2,) px, cov (2, 2) px^2 + a pixel's extent, peak px) of the ridge band from its
    moments ``m`` (``ridge_moments``) on a grid of every ``step``-th pixel; NaN and 0 when
    the band is empty. In numba: built with NumPy, the small arrays cost ~25 us a frame."""
    n = m[0]
    if n == 0:
        return np.full(2, np.nan), np.full((2, 2), np.nan), 0.0
    xy = np.empty(2)
    xy[0] = m[1] / n * step
    xy[1] = m[2] / n * step
    cov = np.empty((2, 2))
    cov[0, 0] = (m[3] / n + 1.0 / 12.0) * step * step
    cov[0, 1] = (m[4] / n + 0.0) * step * step
    cov[1, 0] = cov[0, 1]
    cov[1, 1] = (m[5] / n + 1.0 / 12.0) * step * step
    return xy, cov, m[6] * step


@numba.njit(cache=True, nogil=True)
def ridge_moments(dist, ridge_frac):  # pragma: no cover - numba
    """Moments of the ridge band ``dist >= ridge_frac * max(dist)`` of a distance map (h, w) float32
    (>= 0, as ``cv2.distanceTransform`` gives).

    Returns (n, sum x, sum y, mu20, mu11, mu02, max): pixel count, coordinate sums and
    central second moments (as ``cv2.moments``, binaryImage=True, computes them), and the
    maximum; n = 0 when the maximum is not positive.

    Both passes are loops the compiler vectorises (15 -> 4.5 us on a 640x480 person's map at
    step 2): the maximum over the values' bits as int32 (a non-negative float's bits order as
    its value; a float maximum is not vectorised), and the band's sums row by row, the row's
    in the inner loop without a branch.
    """
    h, w = dist.shape
    bits = dist.view(np.int32)
    top = np.int32(0)
    for y in range(h):
        row = bits[y]
        for x in range(w):
            v = row[x]
            top = v if v > top else top
    peak = np.array([top], np.int32).view(np.float32)[0]
    out = np.zeros(7)
    out[6] = peak
    if peak <= 0:
        return out
    thr = np.float32(ridge_frac * np.float64(peak))      # the band test in float32, as NumPy does it
    n = 0
    sx = 0
    sy = 0
    sxx = 0
    sxy = 0
    syy = 0
    for y in range(h):
        row = dist[y]
        rn = 0
        rx = 0
        rxx = 0
        for x in range(w):
            b = np.int64(row[x] >= thr)
            rn += b
            rx += b * x
            rxx += b * (x * x)
        n += rn
        sx += rx
        sxx += rxx
        sy += rn * y
        sxy += rx * y
        syy += rn * (y * y)
    cx = sx * (1.0 / n)
    cy = sy * (1.0 / n)
    out[0] = n
    out[1] = sx
    out[2] = sy
    out[3] = sxx - sx * cx
    out[4] = sxy - sx * cy
    out[5] = syy - sy * cy
    return out
