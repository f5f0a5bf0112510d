"""Person silhouette by background subtraction robust to shadows and flicker (digest A.1, B.8).

Background model: per-pixel mean colour ``E`` (H, W, 3) and a per-pixel noise level of
the colour distortion, from a few frames of the empty scene.

Change test per pixel ``I`` (colour vector, BGR, 0..255). B.8 observes that shadows and
lighting changes scale brightness but keep colour, and compares hue. Hue is undefined and
very noisy on low-saturation pixels (grey floors, white walls), so we test the same idea
in the form of Horprasert et al. (ICCV'99 FRAME-RATE workshop): split ``I`` into a
brightness ratio along the background colour and a colour distortion across it::

    alpha = (I . E) / (E . E)            brightness ratio (1 = unchanged, < 1 shadow)
    cd    = || I - alpha E ||            colour (chromaticity) distortion, grey levels

A pixel is foreground when its colour changed (``cd > k * noise``) or its brightness left
the band that shadows and flicker can explain (``alpha < alpha_min`` or
``alpha > alpha_max``). Then (B.8) the largest 8-connected component is kept and its holes are
filled (``components.py``). Everything runs inside a
region of interest (the previous person box plus a margin) for speed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from mocap_rt.perception.components import largest_component_box

log = logging.getLogger(__name__)

# Floor of the per-pixel colour-distortion noise, grey levels (sensor + compression).
MIN_NOISE_GREY = 1.5
# Guard against division by a black background pixel, (grey levels)^2.
_EPS_E2 = 1.0


@dataclass(frozen=True)
class ChangeThresholds:
    """Thresholds of the change test (see the module docstring)."""

    cd_sigmas: float = 3.0           # colour distortion threshold in noise sigmas
    cd_min_grey: float = 5.0         # ... and at least this many grey levels
    alpha_min: float = 0.42          # darker than this ratio is not a shadow: foreground
    alpha_max: float = 1.35          # brighter than this is not flicker: foreground
    edge_strength: float = 2.5       # silhouette-boundary pixels must exceed this x the thresholds


class BackgroundModel:
    """Per-pixel statistics of the empty scene.

    mean_bgr : (H, W, 3) float32 mean colour, BGR 0..255.
    noise : (H, W) float32 RMS colour distortion of the background frames, grey levels.
    """

    def __init__(self, mean_bgr: np.ndarray, noise: np.ndarray) -> None:
        mean_bgr = np.ascontiguousarray(mean_bgr, dtype=np.float32)
        noise = np.ascontiguousarray(noise, dtype=np.float32)
        if mean_bgr.ndim != 3 or mean_bgr.shape[2] != 3 or noise.shape != mean_bgr.shape[:2]:
            raise ValueError(f"background mean (H,W,3) and noise (H,W) disagree: {mean_bgr.shape}, {noise.shape}")
        self.mean_bgr = mean_bgr
        self.noise = noise
        self._derived: tuple | None = None

    def derived(self, thresholds: ChangeThresholds) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel (1 / (E.E) (H, W) f32, squared colour-distortion threshold (H, W) f32), cached."""
        if self._derived is None or self._derived[0] != thresholds:
            ee = (self.mean_bgr * self.mean_bgr).sum(axis=2) + _EPS_E2
            thr = np.maximum(thresholds.cd_sigmas * self.noise, thresholds.cd_min_grey)
            self._derived = (thresholds, (1.0 / ee).astype(np.float32), (thr * thr).astype(np.float32))
        return self._derived[1], self._derived[2]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) pixels."""
        return self.mean_bgr.shape[1], self.mean_bgr.shape[0]

    @classmethod
    def from_frames(cls, frames: np.ndarray) -> "BackgroundModel":
        """Model from empty-scene frames (B, H, W, 3) uint8 BGR, B >= 1."""
        f = np.asarray(frames)
        if f.ndim == 3:
            f = f[None]
        if f.ndim != 4 or f.shape[3] != 3 or f.shape[0] < 1:
            raise ValueError(f"background frames must be (B, H, W, 3) BGR, got {f.shape}")
        ff = f.astype(np.float32)
        mean = ff.mean(axis=0)                                         # (H, W, 3)
        if f.shape[0] == 1:
            noise = np.full(mean.shape[:2], MIN_NOISE_GREY, np.float32)
        else:
            e2 = (mean * mean).sum(axis=2) + _EPS_E2                   # (H, W)
            alpha = (ff * mean).sum(axis=3) / e2                       # (B, H, W)
            cd2 = ((ff - alpha[..., None] * mean) ** 2).sum(axis=3)    # (B, H, W)
            noise = np.sqrt(cd2.mean(axis=0))
            # few frames give a noisy per-pixel estimate: never below the image median
            noise = np.maximum(noise, max(MIN_NOISE_GREY, float(np.median(noise))))
        return cls(mean, noise.astype(np.float32))

    def update(self, image_bgr: np.ndarray, foreground: np.ndarray, rate: float) -> None:
        """Slow update for long sessions: blend ``image`` into the mean where not foreground.

        rate : blend weight per call in [0, 1] (e.g. 0.01 at 30 fps ~ 3 s time constant).
        """
        keep = (~np.asarray(foreground, dtype=bool)).view(np.uint8)
        cv2.accumulateWeighted(np.asarray(image_bgr), self.mean_bgr, float(rate), mask=keep)
        self._derived = None


@numba.njit(cache=True, nogil=True, fastmath=True)
def _change_kernel(img, mean, inv_ee, thr2, x0, y0, w, h, a_min, a_max, strong2, out, ox, oy):  # pragma: no cover
    """Change test on the box [x0, x0+w) x [y0, y0+h) of full-size arrays, written to
    out[oy:oy+h, ox:ox+w] (uint8; a full-size buffer takes the box in place with ox, oy = x0, y0).

    out: 0 unchanged, 128 changed, 255 changed with ``strong2`` times the squared threshold
    (the pipeline keeps silhouette-boundary pixels only when strongly changed).

    img (H,W,3) uint8, mean (H,W,3) f32, inv_ee (H,W) f32 = 1/(E.E), thr2 (H,W) f32 squared
    colour-distortion threshold, out: all C-contiguous. A brightness ratio outside
    [a_min, a_max] is a change only if the plain colour distance also exceeds the threshold
    (dark pixels have noisy ratios).
    """
    W = img.shape[1]
    # flat rows with unit stride: the loop vectorises (~4x faster than 3D indexing)
    img_f = img.reshape(-1)
    mean_f = mean.reshape(-1)
    inv_ee_f = inv_ee.reshape(-1)
    thr2_f = thr2.reshape(-1)
    for yy in range(h):
        p0 = (y0 + yy) * W + x0                  # first pixel of the row
        img_r = img_f[3 * p0:3 * (p0 + w)]
        mean_r = mean_f[3 * p0:3 * (p0 + w)]
        inv_ee_r = inv_ee_f[p0:p0 + w]
        thr2_r = thr2_f[p0:p0 + w]
        out_r = out[oy + yy, ox:ox + w]
        for xx in range(w):
            i0 = np.float32(img_r[3 * xx])
            i1 = np.float32(img_r[3 * xx + 1])
            i2 = np.float32(img_r[3 * xx + 2])
            e0 = mean_r[3 * xx]
            e1 = mean_r[3 * xx + 1]
            e2 = mean_r[3 * xx + 2]
            dot = i0 * e0 + i1 * e1 + i2 * e2
            a = dot * inv_ee_r[xx]
            t2 = thr2_r[xx]
            # |I - a E|^2 = |I|^2 - (I.E)^2 / (E.E)
            cd2 = i0 * i0 + i1 * i1 + i2 * i2 - dot * a
            d0 = i0 - e0
            d1 = i1 - e1
            d2 = i2 - e2
            dd2 = d0 * d0 + d1 * d1 + d2 * d2
            out_band = (a < a_min) | (a > a_max)
            fg = (cd2 > t2) | (out_band & (dd2 > t2))
            strong = (cd2 > strong2 * t2) | (out_band & (dd2 > strong2 * t2))
            out_r[xx] = np.uint8(128) * np.uint8(fg) + np.uint8(127) * np.uint8(strong & fg)


def change_mask(image_bgr: np.ndarray, model: BackgroundModel, roi: tuple[int, int, int, int] | None = None,
                thresholds: ChangeThresholds = ChangeThresholds(), out: np.ndarray | None = None) -> np.ndarray:
    """Raw change mask (h, w) uint8 of ``image_bgr`` (H, W, 3) uint8 inside ``roi``.

    0 = unchanged, 128 = changed, 255 = changed by more than ``thresholds.edge_strength``
    times the thresholds. roi : (x, y, w, h) pixels, None = whole image. No clean-up.
    """
    img = checked_image(image_bgr, model)
    x, y, w, h = roi if roi is not None else (0, 0, img.shape[1], img.shape[0])
    if out is None:
        out = np.empty((h, w), np.uint8)
    elif out.shape != (h, w) or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous ({h}, {w}) uint8 array, got {out.shape} {out.dtype}")
    change_into(img, model, thresholds, (x, y, w, h), out, 0, 0)
    return out


def checked_image(image_bgr: np.ndarray, model: BackgroundModel) -> np.ndarray:
    """``image_bgr`` as a C-contiguous (H, W, 3) uint8 array of the background's size, or ValueError."""
    img = np.ascontiguousarray(image_bgr)
    if img.shape[:2] != model.mean_bgr.shape[:2] or img.ndim != 3 or img.dtype != np.uint8:
        raise ValueError(f"image {img.shape} {img.dtype} does not match background {model.mean_bgr.shape} uint8")
    return img


def change_into(img: np.ndarray, model: BackgroundModel, thresholds: ChangeThresholds,
                roi: tuple[int, int, int, int], out: np.ndarray, ox: int, oy: int) -> None:
    """``change_mask``'s codes of ``roi`` (x, y, w, h) written to out[oy:oy+h, ox:ox+w] (a
    C-contiguous uint8 array holding it); img as ``checked_image`` returns it."""
    inv_ee, thr2 = model.derived(thresholds)
    x, y, w, h = roi
    _change_kernel(img, model.mean_bgr, inv_ee, thr2, x, y, w, h, np.float32(thresholds.alpha_min),
                   np.float32(thresholds.alpha_max), np.float32(thresholds.edge_strength ** 2), out, ox, oy)


@numba.njit(cache=True, nogil=True)
def keep_strong_boundary(sil, change):  # pragma: no cover - numba
    """Silhouette (h, w) uint8 {0, 255} whose boundary pixels stay only where ``change``
    (h, w) (``change_mask`` codes) is 255, i.e. strongly changed: the silhouette eroded by
    the 3x3 cross (border replicated) plus its strongly changed pixels. New (h, w) array.
    """
    h, w = sil.shape
    out = np.zeros((h, w), np.uint8)
    for y in range(h):
        for x in range(w):
            if sil[y, x] == 0:
                continue
            interior = ((x == 0 or sil[y, x - 1] != 0) and (x == w - 1 or sil[y, x + 1] != 0)
                        and (y == 0 or sil[y - 1, x] != 0) and (y == h - 1 or sil[y + 1, x] != 0))
            if interior or change[y, x] == 255:
                out[y, x] = 255
    return out


def largest_component_filled(mask: np.ndarray, min_area_px: int = 0) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Largest 8-connected component of ``mask`` (h, w) uint8, holes filled (B.8), from the rows'
    pixel runs (``components.largest_component_box``; what ``cv2.findContours`` RETR_EXTERNAL +
    ``cv2.drawContours`` FILLED of the largest outer boundary gave, ~3x faster on a person ROI).

    Returns (filled (h, w) uint8 {0, 255}, bbox (x, y, w, h) in mask pixels); an all-zero
    mask and (0, 0, 0, 0) when no component has ``min_area_px`` pixels.
    """
    out = np.zeros_like(mask)
    box, (x, y, w, h) = largest_component_box(mask, min_area_px)
    out[y:y + h, x:x + w] = box
    return out, (x, y, w, h)
