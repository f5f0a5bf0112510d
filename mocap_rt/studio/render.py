"""Render the studio subject: per-pixel z-buffer ray casting of capsules (numba).

Per camera and frame:
1. ``_raster_capsules``: for each capsule, over its projected bounding box only, cast the
   pixel's ray, keep the nearest hit in a z-buffer seeded with the empty studio's depth
   (so the floor hides what is below it), and count the capsule's pixels ignoring
   occlusion (also outside the image, with the undistorted pinhole ray) for visibility.
2. ``_cast_shadows``: for floor pixels inside the bounding box of the body's shadow,
   test the ray towards each shadow-casting light against every capsule.
3. ``_compose``: Lambert shading (ambient + directional lights), the floor shadow,
   global flicker, per-camera gain and white balance, sensor noise from a per-pixel
   hash (deterministic for a seed, whatever the threading), to uint8 BGR.

Cue visibility = pixels where the cue's capsule is hit and the nearest surface is of
its own part (the trunk's capsules do not hide the torso cue) / all pixels of the
capsule (in or out of the image, occluded or not). Shading is in display units (albedo x light, no gamma).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from mocap_rt.geometry.rig import Rig
from mocap_rt.studio.body_shape import DEFAULT_ALBEDO_BGR, MATERIALS, BodyPrimitives
from mocap_rt.studio.scene import FLOOR, CameraBackground, StudioScene, camera_background

# Nearest accepted hit along a ray (m), to ignore self-hits of shadow rays.
MIN_HIT_T_M = 1e-6
# A capsule whose bounding box corner is closer than this to the image plane (m, camera
# z) gets the whole image as its box.
NEAR_PLANE_M = 0.05
# Cap on how far outside the image (fraction of its size) visibility counting goes.
OFF_IMAGE_MARGIN_FRAC = 1.0
# Off-image pixels are counted on a grid of this stride (each hit stands for stride^2).
OFF_IMAGE_STRIDE = 4
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


# ----------------------------------------------------------------------------- kernels

@njit(cache=True, nogil=True)
def _sphere_t(ox, oy, oz, dx, dy, dz, cx, cy, cz, r):
    """Nearest positive t of the ray o + t d (|d| = 1) on a sphere, or -1."""
    px, py, pz = ox - cx, oy - cy, oz - cz
    b = px * dx + py * dy + pz * dz
    c = px * px + py * py + pz * pz - r * r
    h = b * b - c
    if h < 0.0:
        return -1.0
    s = math.sqrt(h)
    t = -b - s
    if t > MIN_HIT_T_M:
        return t
    t = -b + s
    return t if t > MIN_HIT_T_M else -1.0


@njit(cache=True, nogil=True)
def _capsule_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, r):
    """Nearest positive t of the ray on the capsule (segment a-b, radius r), or -1."""
    best = 1e30
    t = _sphere_t(ox, oy, oz, dx, dy, dz, ax, ay, az, r)
    if 0.0 < t < best:
        best = t
    t = _sphere_t(ox, oy, oz, dx, dy, dz, bx, by, bz, r)
    if 0.0 < t < best:
        best = t
    bax, bay, baz = bx - ax, by - ay, bz - az
    baba = bax * bax + bay * bay + baz * baz
    if baba > 1e-12:
        oax, oay, oaz = ox - ax, oy - ay, oz - az
        bard = bax * dx + bay * dy + baz * dz
        baoa = bax * oax + bay * oay + baz * oaz
        rdoa = dx * oax + dy * oay + dz * oaz
        oaoa = oax * oax + oay * oay + oaz * oaz
        qa = baba - bard * bard
        if qa > 1e-12 * baba:
            qb = baba * rdoa - baoa * bard
            qc = baba * oaoa - baoa * baoa - r * r * baba
            h = qb * qb - qa * qc
            if h >= 0.0:
                s = math.sqrt(h)
                for t in ((-qb - s) / qa, (-qb + s) / qa):
                    y = baoa + t * bard
                    if t > MIN_HIT_T_M and 0.0 < y < baba and t < best:
                        best = t
                        break
    return best if best < 1e30 else -1.0


@njit(cache=True, nogil=True)
def _raster_capsules(rays, origin, rt_kinv, A, B, rad, bbox, cue_of, zbuf, idbuf, cuehit, total):
    """Z-buffer the capsules into zbuf/idbuf; count each capsule's pixels in ``total``.

    cue_of (P,) i8: cue index of each capsule or -1; cuehit (H, W) u1 gets bit k where
    cue k's capsule covers the pixel (occluded or not).

    rays (H, W, 3) f8; origin (3,); rt_kinv (3, 3) = R^T K^-1 for off-image pixels;
    A, B (P, 3); rad (P,); bbox (P, 4) int64 u0, u1, v0, v1 inclusive (may leave the
    image; off-image pixels are sampled every OFF_IMAGE_STRIDE); zbuf (H, W) f4 seeded
    with the background depth; idbuf (H, W) i2 seeded -1.
    """
    H, W = zbuf.shape
    ox, oy, oz = origin[0], origin[1], origin[2]
    for p in range(A.shape[0]):
        u0, u1, v0, v1 = bbox[p, 0], bbox[p, 1], bbox[p, 2], bbox[p, 3]
        ax, ay, az = A[p, 0], A[p, 1], A[p, 2]
        bx, by, bz = B[p, 0], B[p, 1], B[p, 2]
        r = rad[p]
        n = 0
        for v in range(v0, v1 + 1):
            row_inside = 0 <= v < H
            if not row_inside and v % OFF_IMAGE_STRIDE != 0:
                continue
            for u in range(u0, u1 + 1):
                inside = row_inside and 0 <= u < W
                if not inside and (u % OFF_IMAGE_STRIDE != 0 or v % OFF_IMAGE_STRIDE != 0):
                    continue
                if inside:
                    dx, dy, dz = rays[v, u, 0], rays[v, u, 1], rays[v, u, 2]
                else:
                    dx = rt_kinv[0, 0] * u + rt_kinv[0, 1] * v + rt_kinv[0, 2]
                    dy = rt_kinv[1, 0] * u + rt_kinv[1, 1] * v + rt_kinv[1, 2]
                    dz = rt_kinv[2, 0] * u + rt_kinv[2, 1] * v + rt_kinv[2, 2]
                    nn = math.sqrt(dx * dx + dy * dy + dz * dz)
                    dx, dy, dz = dx / nn, dy / nn, dz / nn
                t = _capsule_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, r)
                if t > 0.0:
                    n += 1 if inside else OFF_IMAGE_STRIDE * OFF_IMAGE_STRIDE
                    if inside:
                        if cue_of[p] >= 0:
                            cuehit[v, u] |= np.uint8(1 << cue_of[p])
                        if t < zbuf[v, u]:
                            zbuf[v, u] = t
                            idbuf[v, u] = p
        total[p] = n


@njit(cache=True, nogil=True)
def _cast_shadows(point, kind, idbuf, box, basis, light_index, seg2d, rad, shadow):
    """Set bit ``light_index[k]`` of ``shadow`` on floor pixels whose way to light k is blocked.

    A floor point is in the shadow of a capsule when the line through it along the light
    passes within the radius of the capsule's segment, i.e. when, projected on the plane
    normal to the light (orthonormal ``basis`` (K, 2, 3)), the point lies within the
    radius of the projected segment ``seg2d`` (K, P, 4: ax, ay, bx, by).
    point (H, W, 3) f4 world points; kind (H, W) u1; box (4,) u0, u1, v0, v1 in the image.
    """
    K, P = seg2d.shape[0], seg2d.shape[1]
    lo = np.empty((K, P, 2))
    hi = np.empty((K, P, 2))
    for k in range(K):
        for p in range(P):
            lo[k, p, 0] = min(seg2d[k, p, 0], seg2d[k, p, 2]) - rad[p]
            hi[k, p, 0] = max(seg2d[k, p, 0], seg2d[k, p, 2]) + rad[p]
            lo[k, p, 1] = min(seg2d[k, p, 1], seg2d[k, p, 3]) - rad[p]
            hi[k, p, 1] = max(seg2d[k, p, 1], seg2d[k, p, 3]) + rad[p]
    for v in range(box[2], box[3] + 1):
        for u in range(box[0], box[1] + 1):
            if kind[v, u] != FLOOR or idbuf[v, u] >= 0:
                continue
            px, py, pz = point[v, u, 0], point[v, u, 1], point[v, u, 2]
            bits = 0
            for k in range(K):
                qx = px * basis[k, 0, 0] + py * basis[k, 0, 1] + pz * basis[k, 0, 2]
                qy = px * basis[k, 1, 0] + py * basis[k, 1, 1] + pz * basis[k, 1, 2]
                for p in range(P):
                    if qx < lo[k, p, 0] or qx > hi[k, p, 0] or qy < lo[k, p, 1] or qy > hi[k, p, 1]:
                        continue
                    ax, ay = seg2d[k, p, 0], seg2d[k, p, 1]
                    ex, ey = seg2d[k, p, 2] - ax, seg2d[k, p, 3] - ay
                    ee = ex * ex + ey * ey
                    s = 0.0
                    if ee > 1e-12:
                        s = min(max(((qx - ax) * ex + (qy - ay) * ey) / ee, 0.0), 1.0)
                    dx, dy = qx - ax - s * ex, qy - ay - s * ey
                    if dx * dx + dy * dy <= rad[p] * rad[p]:
                        bits |= 1 << light_index[k]
                        break
            shadow[v, u] = bits


@njit(cache=True, nogil=True)
def _splitmix(x):
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@njit(cache=True, nogil=True)
def _gauss3(key):
    """Three approximately standard normal numbers from one 64-bit key.

    Each is a sum of three 7-bit uniforms (Irwin-Hall, n = 3), rescaled to unit variance.
    """
    x = _splitmix(key)
    m = np.uint64(0x7F)
    g0 = float(x & m) + float((x >> np.uint64(7)) & m) + float((x >> np.uint64(14)) & m)
    g1 = float((x >> np.uint64(21)) & m) + float((x >> np.uint64(28)) & m) + float((x >> np.uint64(35)) & m)
    g2 = float((x >> np.uint64(42)) & m) + float((x >> np.uint64(49)) & m) + float((x >> np.uint64(56)) & m)
    # (sum + 1.5) / 128 is a sum of three U(0, 1), mean 1.5, variance 3/12
    return ((g0 + 1.5) / 128.0 - 1.5) * 2.0, ((g1 + 1.5) / 128.0 - 1.5) * 2.0, ((g2 + 1.5) / 128.0 - 1.5) * 2.0


@njit(cache=True, nogil=True)
def _compose(bg_albedo, bg_cos, rays, origin, zbuf, idbuf, shadow, A, B, mat, mat_albedo,
             light_dirs, light_int, ambient, scale_bgr, noise_sigma, key, out, mask, visible,
             cuehit, cue_index, group, cue_visible):
    """Shade every pixel to uint8 BGR ``out``; fill ``mask``, per-capsule ``visible``
    counts, and ``cue_visible`` (6,): pixels where the cue's capsule is hit and the
    nearest surface belongs to its group."""
    H, W = zbuf.shape
    L = light_dirs.shape[0]
    for p in range(visible.shape[0]):
        visible[p] = 0
    for k in range(cue_visible.shape[0]):
        cue_visible[k] = 0
    for v in range(H):
        for u in range(W):
            p = idbuf[v, u]
            if p >= 0:
                visible[p] += 1
                mask[v, u] = True
                hits = cuehit[v, u]
                if hits != 0:
                    for k in range(cue_index.shape[0]):
                        if (hits >> k) & 1 and group[cue_index[k]] == group[p]:
                            cue_visible[k] += 1
                t = zbuf[v, u]
                hx = origin[0] + t * rays[v, u, 0]
                hy = origin[1] + t * rays[v, u, 1]
                hz = origin[2] + t * rays[v, u, 2]
                ex, ey, ez = B[p, 0] - A[p, 0], B[p, 1] - A[p, 1], B[p, 2] - A[p, 2]
                ee = ex * ex + ey * ey + ez * ez
                s = 0.0
                if ee > 1e-12:
                    s = ((hx - A[p, 0]) * ex + (hy - A[p, 1]) * ey + (hz - A[p, 2]) * ez) / ee
                    s = min(max(s, 0.0), 1.0)
                nx, ny, nz = hx - A[p, 0] - s * ex, hy - A[p, 1] - s * ey, hz - A[p, 2] - s * ez
                nn = math.sqrt(nx * nx + ny * ny + nz * nz) + 1e-12
                nx, ny, nz = nx / nn, ny / nn, nz / nn
                light = ambient
                for k in range(L):
                    c = nx * light_dirs[k, 0] + ny * light_dirs[k, 1] + nz * light_dirs[k, 2]
                    if c > 0.0:
                        light += light_int[k] * c
                m = mat[p]
                a0, a1, a2 = mat_albedo[m, 0], mat_albedo[m, 1], mat_albedo[m, 2]
            else:
                mask[v, u] = False
                light = ambient
                bits = shadow[v, u]
                for k in range(L):
                    if (bits >> k) & 1 == 0:
                        light += light_int[k] * bg_cos[v, u, k]
                a0, a1, a2 = bg_albedo[v, u, 0], bg_albedo[v, u, 1], bg_albedo[v, u, 2]
            if noise_sigma > 0.0:
                g = _gauss3(key ^ np.uint64(v * W + u))
                n0, n1, n2 = noise_sigma * g[0], noise_sigma * g[1], noise_sigma * g[2]
            else:
                n0 = n1 = n2 = 0.0
            for ch in range(3):
                a = a0 if ch == 0 else (a1 if ch == 1 else a2)
                val = 255.0 * a * light * scale_bgr[ch] + (n0 if ch == 0 else (n1 if ch == 1 else n2))
                val = math.floor(val + 0.5)
                if val < 0.0:
                    val = 0.0
                elif val > 255.0:
                    val = 255.0
                out[v, u, ch] = np.uint8(val)


# ----------------------------------------------------------------------------- renderer

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
        x = int(_splitmix(np.uint64(x ^ (int(i) & 0xFFFFFFFFFFFFFFFF))))
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
            _raster_capsules(bg.rays, bg.origin, self._rt_kinv[camera], a, b, rad,
                             self._bboxes(camera, prims), cue_of, zbuf, idbuf, cuehit, total)
            if len(self._shadow_dirs):
                box = self._shadow_box(camera, prims)
                if box is not None:
                    seg2d = np.concatenate([np.einsum("kij,pj->kpi", self._shadow_basis, a),
                                            np.einsum("kij,pj->kpi", self._shadow_basis, b)], axis=2)
                    _cast_shadows(bg.point, bg.kind, idbuf, box, self._shadow_basis, self._shadow_index,
                                  np.ascontiguousarray(seg2d), rad, shadow)
        image = np.empty((cam.height, cam.width, 3), np.uint8)
        mask = np.empty((cam.height, cam.width), np.bool_)
        scale = self.camera_gain_bgr[camera] * self.flicker(frame)
        key = _mix_key(self.seed, camera, frame)
        _compose(bg.albedo, bg.cos_light, bg.rays, bg.origin, zbuf, idbuf, shadow, a, b, mat, self._albedo,
                 self._light_dirs, self._light_int, float(self.scene.ambient), scale,
                 float(self.config.noise_sigma_levels), key, image, mask, visible,
                 cuehit, cue_index, group, cue_visible)
        vis = np.minimum(np.where(total > 0, visible / np.maximum(total, 1), 0.0), 1.0)
        if prims is None:
            return RenderResult(image, mask, vis, np.zeros(6))
        cue_total = total[cue_index]
        cue_vis = np.minimum(np.where(cue_total > 0, cue_visible / np.maximum(cue_total, 1), 0.0), 1.0)
        return RenderResult(image, mask, vis, cue_vis)
