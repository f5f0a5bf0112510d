"""The empty studio: a textured floor, a cylindrical backdrop, directional lights.

World frame: right-handed, Z up, metres; the floor is Z = 0. The backdrop is a vertical
cylinder of radius ``backdrop_radius_m`` around the Z axis, ``backdrop_height_m`` tall;
above it the ceiling is a flat dark grey. Everything here is static per camera, so it
is computed once (``camera_background``) and each frame only adds the body and its
shadow (``mocap_rt.studio.render``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_rt.geometry.camera import Camera

# Background kinds stored per pixel.
FLOOR, BACKDROP, CEILING = 0, 1, 2
# Depth (m) given to ceiling pixels (nothing is hit; the body is always nearer).
FAR_DEPTH_M = 1.0e4


@dataclass(frozen=True)
class Light:
    """A directional light. ``direction`` points from the scene TOWARDS the light."""

    direction: tuple[float, float, float]
    intensity: float
    casts_shadow: bool = True

    def unit(self) -> np.ndarray:
        d = np.asarray(self.direction, dtype=np.float64)
        return d / np.linalg.norm(d)


def _default_lights() -> tuple[Light, ...]:
    # key light high in front-left of cam_1's view, a weaker fill from the other side
    return (Light((-0.45, -0.55, 1.0), 0.62, True), Light((0.6, 0.5, 0.7), 0.18, False))


@dataclass(frozen=True)
class StudioScene:
    """Geometry, textures and lights of the empty studio (units in the names)."""

    floor_tile_m: float = 0.5
    floor_bgr: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.56, 0.56, 0.54), (0.44, 0.45, 0.45))
    backdrop_radius_m: float = 6.0
    backdrop_height_m: float = 3.5
    backdrop_panel_m: float = 0.8
    backdrop_bgr: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.48, 0.42, 0.36), (0.40, 0.44, 0.40))
    ceiling_bgr: tuple[float, float, float] = (0.20, 0.20, 0.22)
    texture_amplitude: float = 0.04   # fine albedo noise, fraction of albedo
    lights: tuple[Light, ...] = field(default_factory=_default_lights)
    ambient: float = 0.38

    def __post_init__(self) -> None:
        if self.floor_tile_m <= 0 or self.backdrop_radius_m <= 0 or self.backdrop_height_m <= 0:
            raise ValueError("floor_tile_m, backdrop_radius_m and backdrop_height_m must be > 0")
        for light in self.lights:
            if light.unit()[2] <= 0.05:
                raise ValueError(f"light {light} must come from above (direction z > 0.05)")

    def light_dirs(self) -> np.ndarray:
        """(L, 3) float64 unit vectors towards each light."""
        return np.array([lt.unit() for lt in self.lights]).reshape(-1, 3)

    def light_intensities(self) -> np.ndarray:
        return np.array([lt.intensity for lt in self.lights], dtype=np.float64)

    def light_shadows(self) -> np.ndarray:
        return np.array([lt.casts_shadow for lt in self.lights], dtype=np.bool_)


@dataclass(frozen=True)
class CameraBackground:
    """Per-pixel static scene of one camera (H, W = image size).

    rays : (H, W, 3) float64 unit ray directions, world frame (lens distortion removed).
    origin : (3,) camera centre, world metres.
    depth : (H, W) float32 distance along the ray to the background, metres.
    point : (H, W, 3) float32 world point hit; kind : (H, W) uint8 FLOOR/BACKDROP/CEILING.
    albedo : (H, W, 3) float32 BGR in [0, 1].
    cos_light : (H, W, L) float32 Lambert factor max(0, n . l) per light.
    """

    rays: np.ndarray
    origin: np.ndarray
    depth: np.ndarray
    point: np.ndarray
    kind: np.ndarray
    albedo: np.ndarray
    cos_light: np.ndarray


def pixel_rays(camera: Camera) -> np.ndarray:
    """(H, W, 3) unit world directions through every pixel centre (distortion removed)."""
    w, h = camera.width, camera.height
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    _, d = camera.rays(np.stack([u.ravel(), v.ravel()], axis=1))
    return d.reshape(h, w, 3)


def _hash_noise(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Deterministic value noise in [-1, 1] from integer lattice coordinates."""
    x = (ix.astype(np.int64) * 73856093) ^ (iy.astype(np.int64) * 19349663) ^ (salt * 83492791)
    x = (x ^ (x >> 13)) * 1274126177
    return ((x & 0xFFFF).astype(np.float64) / 32767.5) - 1.0


def camera_background(camera: Camera, scene: StudioScene) -> CameraBackground:
    """Ray-cast the empty studio for every pixel of ``camera``."""
    rays = pixel_rays(camera)                                   # (H, W, 3)
    o = camera.center
    h, w = camera.height, camera.width
    inf = np.inf
    # floor z = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(rays[..., 2] < -1e-12, -o[2] / rays[..., 2], inf)
    # cylinder x^2 + y^2 = R^2 (camera inside): far root of |o_xy + t d_xy|^2 = R^2
    dx, dy = rays[..., 0], rays[..., 1]
    a = dx * dx + dy * dy
    bq = 2.0 * (o[0] * dx + o[1] * dy)
    c = o[0] ** 2 + o[1] ** 2 - scene.backdrop_radius_m ** 2
    disc = np.maximum(bq * bq - 4 * a * c, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = np.where(a > 1e-12, (-bq + np.sqrt(disc)) / (2 * a), inf)
    z_wall = o[2] + t_wall * rays[..., 2]
    t_wall = np.where((z_wall >= 0) & (z_wall <= scene.backdrop_height_m), t_wall, inf)
    kind = np.full((h, w), CEILING, np.uint8)
    depth = np.full((h, w), FAR_DEPTH_M)
    floor_first = t_floor <= t_wall
    is_floor = np.isfinite(t_floor) & floor_first
    is_wall = np.isfinite(t_wall) & ~is_floor
    kind[is_floor], depth[is_floor] = FLOOR, t_floor[is_floor]
    kind[is_wall], depth[is_wall] = BACKDROP, t_wall[is_wall]
    point = o + depth[..., None] * rays
    albedo = np.empty((h, w, 3))
    albedo[:] = scene.ceiling_bgr
    normal = np.zeros((h, w, 3))
    normal[..., 2] = -1.0  # ceiling faces down
    # floor: checker tiles with fine noise
    fp = point[is_floor]
    tiles = np.floor(fp[:, :2] / scene.floor_tile_m).astype(np.int64)
    which = (tiles[:, 0] + tiles[:, 1]) & 1
    fine = np.floor(fp[:, :2] / 0.02).astype(np.int64)
    noise = 1.0 + scene.texture_amplitude * _hash_noise(fine[:, 0], fine[:, 1], 1)
    albedo[is_floor] = np.asarray(scene.floor_bgr)[which] * noise[:, None]
    normal[is_floor] = (0.0, 0.0, 1.0)
    # backdrop: vertical panels, a darker band at 1.0-1.2 m, fine noise
    wp = point[is_wall]
    ang = np.arctan2(wp[:, 1], wp[:, 0]) * scene.backdrop_radius_m
    panel = np.floor(ang / scene.backdrop_panel_m).astype(np.int64) & 1
    band = (wp[:, 2] > 1.0) & (wp[:, 2] < 1.2)
    fine = np.floor(np.stack([ang, wp[:, 2]], 1) / 0.02).astype(np.int64)
    noise = 1.0 + scene.texture_amplitude * _hash_noise(fine[:, 0], fine[:, 1], 2)
    alb = np.asarray(scene.backdrop_bgr)[panel] * noise[:, None]
    alb[band] *= 0.7
    albedo[is_wall] = alb
    nxy = -wp[:, :2] / np.linalg.norm(wp[:, :2], axis=1, keepdims=True)
    normal[is_wall] = np.column_stack([nxy, np.zeros(len(wp))])
    cos_light = np.maximum(np.einsum("hwk,lk->hwl", normal, scene.light_dirs()), 0.0)
    return CameraBackground(
        rays=np.ascontiguousarray(rays),
        origin=o.astype(np.float64),
        depth=depth.astype(np.float32),
        point=point.astype(np.float32),
        kind=kind,
        albedo=np.clip(albedo, 0.0, 1.0).astype(np.float32),
        cos_light=np.ascontiguousarray(cos_light, dtype=np.float32),
    )
