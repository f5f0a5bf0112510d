"""Render the studio subject: ``StudioRenderer`` turns a scene's capsules into each camera's
image, silhouette mask and cue visibility, frame by frame (the kernels: ``render_kernels``).

Cue visibility = pixels where the cue's capsule is hit and the nearest surface is of
its own part (the trunk's capsules do not hide the torso cue) / all pixels of the
capsule (in or out of the image, occluded or not).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mocap_rt.geometry.rig import Rig
from mocap_rt.studio.body_shape import DEFAULT_ALBEDO_BGR, MATERIALS, BodyPrimitives
from mocap_rt.studio.render_kernels import cast_shadows, compose, raster_capsules, splitmix
from mocap_rt.studio.scene import CameraBackground, StudioScene, camera_background

# A capsule whose bounding box corner is closer than this to the image plane (m, camera
# z) gets the whole image as its box.
NEAR_PLANE_M = 0.05
# Cap on how far outside the image (fraction of its size) visibility counting goes.
OFF_IMAGE_MARGIN_FRAC = 1.0
# Extra pixels around each projected bounding box.
BBOX_MARGIN_PX = 2


@dataclass(frozen=True)
class RenderConfig:
    """Camera and lighting effects (units in names). Zeros give a clean render.

    noise_sigma_levels : sensor noise, standard deviation in grey levels (0-255).
    flicker_amplitude : global illumination flicker, fraction (0.05 = +-5 %).
    flicker_hz : frequency of its slow part; a random per-frame part adds a third.
    gain_jitter : per-camera gain drawn from 1 +- this (uniform).
    white_balance_jitter : per-camera, per-channel factor 1 +- this (uniform).
    shadows : cast the body's shadow on the floor.
    albedo_bgr : material colours, BGR in [0, 1], overriding DEFAULT_ALBEDO_BGR.
    """

    noise_sigma_levels: float = 2.0
    flicker_amplitude: float = 0.0
    flicker_hz: float = 0.5
    gain_jitter: float = 0.05
    white_balance_jitter: float = 0.03
    shadows: bool = True
    albedo_bgr: dict = field(default_factory=dict)

    def material_albedo(self) -> np.ndarray:
        """(len(MATERIALS), 3) float64 BGR albedo."""
        unknown = set(self.albedo_bgr) - set(MATERIALS)
        if unknown:
            raise ValueError(f"albedo_bgr: unknown materials {sorted(unknown)}; known {MATERIALS}")
        table = {**DEFAULT_ALBEDO_BGR, **self.albedo_bgr}
        out = np.array([table[m] for m in MATERIALS], dtype=np.float64)
        if out.shape != (len(MATERIALS), 3) or (out < 0).any() or (out > 1).any():
            raise ValueError("albedo_bgr values must be 3 numbers in [0, 1]")
        return out


@dataclass(frozen=True)
class RenderResult:
    """One rendered image.

    image : (H, W, 3) uint8 BGR; mask : (H, W) bool, the person's pixels;
    visibility : (P,) float64 visible fraction of each capsule in [0, 1];
    cue_visibility : (6,) float64 visible fraction of each cue's capsule, where only other
        parts occlude (CUE_NAMES order; see the module docstring).
    """

    image: np.ndarray
    mask: np.ndarray
    visibility: np.ndarray
    cue_visibility: np.ndarray


def _plane_basis(normal: np.ndarray) -> np.ndarray:
    """(2, 3) orthonormal vectors spanning the plane normal to ``normal``."""
    n = normal / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(n, e1)])


def _mix_key(*ints: int) -> np.uint64:
    x = 0x243F6A8885A308D3
    for i in ints:
        x = int(splitmix(np.uint64(x ^ (int(i) & 0xFFFFFFFFFFFFFFFF))))
    return np.uint64(x)


class StudioRenderer:
    """Renders body capsules into every camera of a rig.

    One instance per rig; ``render`` may be called from several threads for different
    cameras (each camera has its own buffers; the kernels release the GIL).
    """

    def __init__(self, rig: Rig, scene: StudioScene | None = None, config: RenderConfig | None = None,
                 seed: int = 0, fps: float = 30.0) -> None:
        self.rig = rig
        self.scene = StudioScene() if scene is None else scene
        self.config = RenderConfig() if config is None else config
        self.seed = int(seed)
        self.fps = float(fps)
        self._albedo = self.config.material_albedo()
        self._light_dirs = np.ascontiguousarray(self.scene.light_dirs())
        self._light_int = self.scene.light_intensities()
        shadow_lights = np.flatnonzero(self.scene.light_shadows()) if self.config.shadows else np.zeros(0, int)
        self._shadow_dirs = np.ascontiguousarray(self._light_dirs[shadow_lights])
        self._shadow_index = shadow_lights.astype(np.int64)
        self._shadow_basis = np.array([_plane_basis(d) for d in self._shadow_dirs]).reshape(-1, 2, 3)
        rng = np.random.default_rng(self.seed)
        cj, wj = self.config.gain_jitter, self.config.white_balance_jitter
        self.camera_gain_bgr = (rng.uniform(1 - cj, 1 + cj, (len(rig), 1))
                                * rng.uniform(1 - wj, 1 + wj, (len(rig), 3)))
        self.backgrounds: list[CameraBackground] = [camera_background(c, self.scene) for c in rig.cameras]
        self._rt_kinv = [np.ascontiguousarray(c.R.T @ np.linalg.inv(c.K)) for c in rig.cameras]
        self._buffers = [self._new_buffers(c.height, c.width) for c in rig.cameras]

    @staticmethod
    def _new_buffers(h: int, w: int) -> dict:
        return {"z": np.empty((h, w), np.float32), "id": np.empty((h, w), np.int16),
                "shadow": np.zeros((h, w), np.uint8), "cuehit": np.zeros((h, w), np.uint8)}

    def flicker(self, frame: int) -> float:
        """Global illumination factor of a frame (1.0 without flicker)."""
        amp = self.config.flicker_amplitude
        if amp <= 0:
            return 1.0
        slow = math.sin(2 * math.pi * self.config.flicker_hz * frame / self.fps)
        fast = float(_mix_key(self.seed, 0xF11C, frame) & np.uint64(0xFFFF)) / 32767.5 - 1.0
        return 1.0 + amp * ((2.0 / 3.0) * slow + (1.0 / 3.0) * fast)

    def _bboxes(self, ci: int, prims: BodyPrimitives) -> np.ndarray:
        cam = self.rig.cameras[ci]
        w, h = cam.width, cam.height
        lo = np.minimum(prims.a, prims.b) - prims.radius[:, None]
        hi = np.maximum(prims.a, prims.b) + prims.radius[:, None]
        sel = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])   # (8, 3)
        corners = np.where(sel[None] == 0, lo[:, None], hi[:, None])                     # (P, 8, 3)
        z = cam.to_camera(corners.reshape(-1, 3))[:, 2].reshape(-1, 8)
        uv = cam.project(corners.reshape(-1, 3))[0].reshape(-1, 8, 2)
        mu, mv = OFF_IMAGE_MARGIN_FRAC * w, OFF_IMAGE_MARGIN_FRAC * h
        box = np.empty((len(lo), 4), np.int64)
        with np.errstate(invalid="ignore"):
            box[:, 0] = np.floor(np.nanmin(uv[..., 0], axis=1)) - BBOX_MARGIN_PX
            box[:, 1] = np.ceil(np.nanmax(uv[..., 0], axis=1)) + BBOX_MARGIN_PX
            box[:, 2] = np.floor(np.nanmin(uv[..., 1], axis=1)) - BBOX_MARGIN_PX
            box[:, 3] = np.ceil(np.nanmax(uv[..., 1], axis=1)) + BBOX_MARGIN_PX
        near = (z < NEAR_PLANE_M).any(axis=1)
        behind = (z < NEAR_PLANE_M).all(axis=1)
        box[near] = (0, w - 1, 0, h - 1)
        box[behind] = (0, -1, 0, -1)  # empty
        box[:, 0:2] = np.clip(box[:, 0:2], -mu, w - 1 + mu)
        box[:, 2:4] = np.clip(box[:, 2:4], -mv, h - 1 + mv)
        return box

    def _shadow_box(self, ci: int, prims: BodyPrimitives) -> np.ndarray | None:
        """Image box (u0, u1, v0, v1) around the body's floor shadow; None if off-image."""
        cam = self.rig.cameras[ci]
        ends = np.concatenate([prims.a, prims.b])
        pts = [ends * (1, 1, 0)]
        for d in self._shadow_dirs:
            pts.append(ends - (ends[:, 2:3] / d[2]) * d)
        pts = np.concatenate(pts)
        grow = float(prims.radius.max()) / max(float(self._shadow_dirs[:, 2].min()), 0.05) + 0.05
        lo, hi = pts[:, :2].min(axis=0) - grow, pts[:, :2].max(axis=0) + grow
        corners = np.array([[lo[0], lo[1], 0], [lo[0], hi[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0]])
        w, h = cam.width, cam.height
        if (cam.to_camera(corners)[:, 2] < NEAR_PLANE_M).any():
            return np.array([0, w - 1, 0, h - 1], np.int64)
        uv = cam.project(corners)[0]
        box = np.array([np.floor(uv[:, 0].min()), np.ceil(uv[:, 0].max()),
                        np.floor(uv[:, 1].min()), np.ceil(uv[:, 1].max())])
        box = np.clip(box, [0, 0, 0, 0], [w - 1, w - 1, h - 1, h - 1]).astype(np.int64)
        if box[0] >= box[1] or box[2] >= box[3]:
            return None
        return box

    def render(self, camera: int, prims: BodyPrimitives | None, frame: int) -> RenderResult:
        """Render one camera (index in the rig) at one frame; ``prims`` None = empty studio."""
        cam = self.rig.cameras[camera]
        bg = self.backgrounds[camera]
        buf = self._buffers[camera]
        zbuf, idbuf, shadow, cuehit = buf["z"], buf["id"], buf["shadow"], buf["cuehit"]
        np.copyto(zbuf, bg.depth)
        idbuf.fill(-1)
        shadow.fill(0)
        cuehit.fill(0)
        if prims is None:
            a = b = np.zeros((0, 3))
            rad = np.zeros(0)
            mat = group = np.zeros(0, np.int64)
            cue_index = np.zeros(0, np.int64)
        else:
            a = np.ascontiguousarray(prims.a, dtype=np.float64)
            b = np.ascontiguousarray(prims.b, dtype=np.float64)
            rad = np.ascontiguousarray(prims.radius, dtype=np.float64)
            mat = np.ascontiguousarray(prims.material, dtype=np.int64)
            group = np.ascontiguousarray(prims.group, dtype=np.int64)
            cue_index = np.ascontiguousarray(prims.cue_index, dtype=np.int64)
        total = np.zeros(len(rad), np.int64)
        visible = np.zeros(len(rad), np.int64)
        cue_visible = np.zeros(len(cue_index), np.int64)
        if len(rad):
            cue_of = np.full(len(rad), -1, np.int64)
            cue_of[cue_index] = np.arange(len(cue_index))
            raster_capsules(bg.rays, bg.origin, self._rt_kinv[camera], a, b, rad,
                             self._bboxes(camera, prims), cue_of, zbuf, idbuf, cuehit, total)
            if len(self._shadow_dirs):
                box = self._shadow_box(camera, prims)
                if box is not None:
                    seg2d = np.concatenate([np.einsum("kij,pj->kpi", self._shadow_basis, a),
                                            np.einsum("kij,pj->kpi", self._shadow_basis, b)], axis=2)
                    cast_shadows(bg.point, bg.kind, idbuf, box, self._shadow_basis, self._shadow_index,
                                  np.ascontiguousarray(seg2d), rad, shadow)
        image = np.empty((cam.height, cam.width, 3), np.uint8)
        mask = np.empty((cam.height, cam.width), np.bool_)
        scale = self.camera_gain_bgr[camera] * self.flicker(frame)
        key = _mix_key(self.seed, camera, frame)
        compose(bg.albedo, bg.cos_light, bg.rays, bg.origin, zbuf, idbuf, shadow, a, b, mat, self._albedo,
                 self._light_dirs, self._light_int, float(self.scene.ambient), scale,
                 float(self.config.noise_sigma_levels), key, image, mask, visible,
                 cuehit, cue_index, group, cue_visible)
        vis = np.minimum(np.where(total > 0, visible / np.maximum(total, 1), 0.0), 1.0)
        if prims is None:
            return RenderResult(image, mask, vis, np.zeros(6))
        cue_total = total[cue_index]
        cue_vis = np.minimum(np.where(cue_total > 0, cue_visible / np.maximum(cue_total, 1), 0.0), 1.0)
        return RenderResult(image, mask, vis, cue_vis)
