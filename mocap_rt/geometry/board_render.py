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

from mocap_rt.geometry.board import BoardSpec
from mocap_rt.geometry.camera import Camera

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
    B, c = T[:3, :3], T[:3, 3]
    hi = _scaled_camera(camera, max(1, int(supersample)))
    w, h = hi.size
    x0, y0, x1, y1 = _sheet_bbox(hi, spec, T, sheet.shape, px_per_square, margin)
    out = np.full((h, w), float(background), np.float32)
    if x1 <= x0 or y1 <= y0:
        return _finish(out, camera, supersample)
    grid = np.stack(np.meshgrid(np.arange(x0, x1, dtype=np.float64), np.arange(y0, y1, dtype=np.float64)), -1)
    h, w = grid.shape[:2]
    origin = hi.center
    _, dirs = hi.rays(grid.reshape(-1, 2))                            # (h w, 3) world
    normal = B[:, 2]                                                  # board z in world
    denom = dirs @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((c - origin) @ normal) / denom                            # ray parameter
        p_board = (origin + s[:, None] * dirs - c) @ B                # (H W, 3) board frame
    # seen from the front only (the printed face looks towards -z of the board frame)
    visible = (s > 0) & (denom > 0)
    map_x = p_board[:, 0] / spec.square_m * px_per_square + margin - 0.5
    map_y = p_board[:, 1] / spec.square_m * px_per_square + margin - 0.5
    map_x = np.where(visible, map_x, -1e6).astype(np.float32).reshape(h, w)
    map_y = np.where(visible, map_y, -1e6).astype(np.float32).reshape(h, w)
    out[y0:y1, x0:x1] = cv2.remap(sheet, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                  borderValue=float(background))
    return _finish(out, camera, supersample)


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
