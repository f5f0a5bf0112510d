"""Planar YUV 4:2:0 -> BGR exactly as OpenCV's FFmpeg backend converts decoded video.

``cv2.VideoCapture`` (FFmpeg backend, ``modules/videoio/src/cap_ffmpeg_impl.hpp``) turns every
decoded frame into BGR24 with ``sws_getCachedContext(..., AV_PIX_FMT_BGR24, SWS_BICUBIC)``.
For a same-size 4:2:0 frame (MJPEG's ``yuvj420p``) swscale takes its unscaled "yuv2rgb" path,
on x86 the SIMD one (``libswscale/x86/yuv_2_rgb.asm``): each chroma sample is used for its
2 x 2 luma block (no interpolation), and every term is 16-bit fixed point::

    Y' = pmulhw((Y << 3) - y_offset, y_coeff)
    B = sat8(Y' + pmulhw((U << 3) - 1024, ub))
    G = sat8(Y' + pmulhw((U << 3) - 1024, ug) + pmulhw((V << 3) - 1024, vg))
    R = sat8(Y' + pmulhw((V << 3) - 1024, vr))

with ``pmulhw(a, b) = (a * b) >> 16`` and the coefficients of ``ff_yuv2rgb_c_init_tables``
(``libswscale/yuv2rgb.c``) for the colour matrix and range. Decoding a recording's MJPEG with
FFmpeg's decoder (GStreamer's ``avdec_mjpeg``) and converting here gives the very pixels of
``cv2.VideoCapture`` (tested bit for bit), where GStreamer's ``videoconvert`` (interpolated
chroma, other rounding) differs by 1-5 levels on most pixels.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# ff_yuv2rgb_coeffs (libswscale/yuv2rgb.c): V->R, U->B, U->G, V->G, 16.16, limited-range scale
SWS_COEFFS = {"bt601": (104597, 132201, 25675, 53279), "bt709": (117489, 138438, 13975, 34925)}


def _round16(x: int) -> int:
    """swscale's ``roundToInt16`` of a 16.16 value scaled by 2^13: (x + 2^15) >> 16."""
    return (int(x) + (1 << 15)) >> 16


def swscale_coefficients(matrix: str = "bt601", full_range: bool = True) -> np.ndarray:
    """(6,) int64: y_offset, y_coeff, vr, ug, vg, ub as swscale's SIMD yuv2rgb uses them
    (``ff_yuv2rgb_c_init_tables`` with contrast = saturation = 1, brightness 0)."""
    if matrix not in SWS_COEFFS:
        raise ValueError(f"YUV matrix {matrix!r}: expected one of {sorted(SWS_COEFFS)}")
    crv, cbu, cgu, cgv = SWS_COEFFS[matrix]
    cgu, cgv = -cgu, -cgv
    cy, oy = 1 << 16, 0
    if full_range:                       # C integer division truncates towards zero
        crv, cbu = crv * 224 // 255, cbu * 224 // 255
        cgu, cgv = -(-cgu * 224 // 255), -(-cgv * 224 // 255)
    else:
        cy, oy = cy * 255 // 219, 16 << 16
    return np.array([_round16(oy * 8), _round16(cy * 8192), _round16(crv * 8192), _round16(cgu * 8192),
                     _round16(cgv * 8192), _round16(cbu * 8192)], np.int64)


@njit(cache=True, nogil=True)
def _i420_to_bgr(y, u, v, k, out):
    y_off, y_k, vr, ug, vg, ub = k[0], k[1], k[2], k[3], k[4], k[5]
    h, w = y.shape
    for i in range(h):
        for j in range(w):
            yy = (((np.int64(y[i, j]) << 3) - y_off) * y_k) >> 16
            uu = (np.int64(u[i >> 1, j >> 1]) << 3) - 1024
            vv = (np.int64(v[i >> 1, j >> 1]) << 3) - 1024
            b = yy + ((uu * ub) >> 16)
            g = yy + (((uu * ug) >> 16) + ((vv * vg) >> 16))
            r = yy + ((vv * vr) >> 16)
            out[i, j, 0] = min(max(b, 0), 255)
            out[i, j, 1] = min(max(g, 0), 255)
            out[i, j, 2] = min(max(r, 0), 255)


def i420_to_bgr(y: np.ndarray, u: np.ndarray, v: np.ndarray, matrix: str = "bt601", full_range: bool = True,
                out: np.ndarray | None = None) -> np.ndarray:
    """BGR image of a planar 4:2:0 frame, converted as swscale (OpenCV's FFmpeg backend) does.

    y : (H, W) uint8; u, v : (ceil(H/2), ceil(W/2)) uint8 (Cb, Cr); ``matrix`` "bt601"
    (swscale's default, what OpenCV gets) or "bt709"; ``full_range`` True for JPEG levels
    (0-255), False for video levels (Y 16-235). Returns (H, W, 3) uint8 BGR (``out`` if given).
    """
    y, u, v = (np.ascontiguousarray(a, np.uint8) for a in (y, u, v))
    h, w = y.shape
    if u.shape != ((h + 1) // 2, (w + 1) // 2) or v.shape != u.shape:
        raise ValueError(f"i420_to_bgr: chroma planes {u.shape}/{v.shape} do not fit a {w}x{h} luma plane")
    if out is None:
        out = np.empty((h, w, 3), np.uint8)
    elif out.shape != (h, w, 3) or out.dtype != np.uint8:
        raise ValueError(f"i420_to_bgr: out must be ({h}, {w}, 3) uint8, got {out.shape} {out.dtype}")
    _i420_to_bgr(y, u, v, swscale_coefficients(matrix, full_range), out)
    return out


def i420_to_bgr_reference(y: np.ndarray, u: np.ndarray, v: np.ndarray, matrix: str = "bt601",
                          full_range: bool = True) -> np.ndarray:
    """``i420_to_bgr`` in plain NumPy (the slow reference of the kernel)."""
    y_off, y_k, vr, ug, vg, ub = swscale_coefficients(matrix, full_range).tolist()
    h, w = y.shape
    U = np.repeat(np.repeat(u.astype(np.int64), 2, 0), 2, 1)[:h, :w] * 8 - 1024
    V = np.repeat(np.repeat(v.astype(np.int64), 2, 0), 2, 1)[:h, :w] * 8 - 1024
    Y = ((y.astype(np.int64) * 8 - y_off) * y_k) >> 16
    bgr = np.stack([Y + ((U * ub) >> 16), Y + (((U * ug) >> 16) + ((V * vg) >> 16)), Y + ((V * vr) >> 16)], -1)
    return np.clip(bgr, 0, 255).astype(np.uint8)
