"""Render what a calibrated camera sees of a planar board: synthetic calibration images
with exact ground truth (K, distortion, pose), for tests, demos and the synthetic studio.

Each camera pixel is traced back (lens distortion removed) to its world ray, the ray is
intersected with the board plane, and the board image is sampled there (``cv2.remap``).
Rendering at ``supersample`` times the resolution and averaging blocks (``INTER_AREA``)
keeps the printed squares' edges free of aliasing.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from mocap_rt.geometry.board import BoardSpec
from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.lens import dist8, undistort_point

__all__ = ["render_board_view"]


def _scaled_camera(camera: Camera, factor: int) -> Camera:
    """The same lens at ``factor`` x resolution (pixel-centre convention kept)."""
    S = np.array([[factor, 0.0, (factor - 1) / 2], [0.0, factor, (factor - 1) / 2], [0.0, 0.0, 1.0]])
    size = (camera.width * factor, camera.height * factor)
    return Camera(camera.name, size, S @ camera.K, camera.dist, camera.R, camera.t)


def render_board_view(camera: Camera, spec: BoardSpec, world_from_board: np.ndarray,
                      px_per_square: int = 40, background: int = 160, supersample: int = 2) -> np.ndarray:
    """(H, W) uint8 image of the board (see :meth:`BoardSpec.image`) seen by ``camera``.

    world_from_board : (4, 4) rigid transform, ``p_world = T[:3, :3] p_board + T[:3, 3]``
    (metres). Pixels whose ray misses the printed sheet (or hits its back) get
    ``background``.
    """
    margin = px_per_square // 2
    sheet = spec.image(px_per_square, margin).astype(np.float32)
    T = np.asarray(world_from_board, dtype=np.float64)
    B, c = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
    hi = _scaled_camera(camera, max(1, int(supersample)))
    w, h = hi.size
    x0, y0, x1, y1 = _sheet_bbox(hi, spec, T, sheet.shape, px_per_square, margin)
    out = np.full((h, w), float(background), np.float32)
    if x1 <= x0 or y1 <= y0:
        return _finish(out, camera, supersample)
    map_x = np.empty((y1 - y0, x1 - x0), np.float32)
    map_y = np.empty_like(map_x)
    dist = dist8(hi.dist)
    to_sheet = np.array([px_per_square / spec.square_m, margin - 0.5])   # metres -> sheet pixels
    _sheet_maps(x0, y0, np.linalg.inv(hi.K), dist, hi.R, hi.center, B, c, to_sheet, map_x, map_y)
    out[y0:y1, x0:x1] = cv2.remap(sheet, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                  borderValue=float(background))
    return _finish(out, camera, supersample)


@njit(cache=True, nogil=True)
def _sheet_maps(x0: int, y0: int, kinv: np.ndarray, dist: np.ndarray, R: np.ndarray, origin: np.ndarray,
                B: np.ndarray, c: np.ndarray, to_sheet: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> None:
    """For each pixel of the box: undistort, world ray R^T [x, y, 1], hit the board plane
    (point c, normal B[:, 2]) from the front, board (x, y) -> sheet pixel; -1e6 = miss."""
    n0, n1, n2 = B[0, 2], B[1, 2], B[2, 2]
    num = (c[0] - origin[0]) * n0 + (c[1] - origin[1]) * n1 + (c[2] - origin[2]) * n2
    for i in range(map_x.shape[0]):
        for j in range(map_x.shape[1]):
            x, y = undistort_point(float(x0 + j), float(y0 + i), kinv, dist)
            d0 = R[0, 0] * x + R[1, 0] * y + R[2, 0]
            d1 = R[0, 1] * x + R[1, 1] * y + R[2, 1]
            d2 = R[0, 2] * x + R[1, 2] * y + R[2, 2]
            den = d0 * n0 + d1 * n1 + d2 * n2
            s = num / den if den > 0.0 else -1.0      # den > 0: the printed face is seen
            if s <= 0.0:
                map_x[i, j] = map_y[i, j] = -1e6
                continue
            p0 = origin[0] + s * d0 - c[0]
            p1 = origin[1] + s * d1 - c[1]
            p2 = origin[2] + s * d2 - c[2]
            map_x[i, j] = (p0 * B[0, 0] + p1 * B[1, 0] + p2 * B[2, 0]) * to_sheet[0] + to_sheet[1]
            map_y[i, j] = (p0 * B[0, 1] + p1 * B[1, 1] + p2 * B[2, 1]) * to_sheet[0] + to_sheet[1]


def _finish(img: np.ndarray, camera: Camera, supersample: int) -> np.ndarray:
    if supersample > 1:
        img = cv2.resize(img, camera.size, interpolation=cv2.INTER_AREA)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _sheet_bbox(camera: Camera, spec: BoardSpec, T: np.ndarray, sheet_shape: tuple[int, int],
                px_per_square: int, margin: int) -> tuple[int, int, int, int]:
    """Pixel box (x0, y0, x1, y1) holding the sheet's image; the whole image if the
    sheet reaches behind the camera. Only this box is traced (the speed of small boards)."""
    h_px, w_px = sheet_shape
    scale = spec.square_m / px_per_square
    t = np.linspace(0.0, 1.0, 33)
    edge_x, edge_y = (w_px * t - margin) * scale, (h_px * t - margin) * scale
    lo_x, hi_x = -margin * scale, (w_px - margin) * scale
    lo_y, hi_y = -margin * scale, (h_px - margin) * scale
    border = np.concatenate([
        np.stack([edge_x, np.full_like(t, lo_y)], 1), np.stack([edge_x, np.full_like(t, hi_y)], 1),
        np.stack([np.full_like(t, lo_x), edge_y], 1), np.stack([np.full_like(t, hi_x), edge_y], 1)])
    pts = np.hstack([border, np.zeros((len(border), 1))]) @ T[:3, :3].T + T[:3, 3]
    uv, in_front = camera.project(pts)
    if not in_front.all():
        return 0, 0, camera.width, camera.height
    pad = 3  # pixels: bilinear footprint and the curvature of distorted edges between samples
    x0 = int(np.clip(np.floor(uv[:, 0].min()) - pad, 0, camera.width))
    x1 = int(np.clip(np.ceil(uv[:, 0].max()) + pad + 1, 0, camera.width))
    y0 = int(np.clip(np.floor(uv[:, 1].min()) - pad, 0, camera.height))
    y1 = int(np.clip(np.ceil(uv[:, 1].max()) + pad + 1, 0, camera.height))
    return x0, y0, x1, y1
