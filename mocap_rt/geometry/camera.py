"""The calibrated camera: pinhole intrinsics, the lens (``mocap_rt.geometry.lens``) and the
world -> camera pose; projection of world points and back-projection of pixels to rays.

World convention (used everywhere in mocap_rt): right-handed, +Z up, metres.
The floor is the plane Z = 0 and the capture volume is centred on the origin.

Camera convention (OpenCV): +X right, +Y down, +Z forward (optical axis).
Extrinsics are world-to-camera: ``p_cam = R @ p_world + t``.
Pixel convention (OpenCV): the centre of the top-left pixel is (0, 0);
``u`` grows to the right, ``v`` downwards.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.geometry.lens import dist8, distort, undistort

# Below this depth (metres, camera frame) a point counts as behind the camera.
MIN_DEPTH_M = 1e-9


def as_points(points: np.ndarray, dim: int, name: str) -> np.ndarray:
    """(N, dim) float64 view of ``points`` (a single (dim,) point becomes (1, dim));
    ValueError naming ``name`` for any other shape."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {np.shape(points)}")
    return arr


def rotation_from_rodrigues(rvec: np.ndarray) -> np.ndarray:
    """(3,) Rodrigues vector -> (3, 3) rotation matrix."""
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]


def rodrigues_from_rotation(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> (3,) Rodrigues vector, exact to rounding at every angle.

    Through scipy's quaternion (largest-component branch): ``cv2.Rodrigues`` takes the axis
    from R's skew part, which vanishes near pi, and loses up to 7e-7 there."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) for a camera at ``eye`` looking at ``target``.

    The image's "up" (-Y of the camera) is aligned with the projection of ``up``.
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])  # rows: camera axes in world coordinates
    return R, -R @ eye


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    name : str, as in the rig file; cameras keep file order, never sorted.
    size : (width, height) in pixels.
    K : (3, 3) float64 intrinsics, focal lengths and principal point in pixels.
    dist : (n,) float64 OpenCV distortion (k1, k2, p1, p2[, k3[, k4, k5, k6]]), n in {0, 4, 5, 8}.
    R : (3, 3) float64 rotation world -> camera.
    t : (3,) float64 translation world -> camera, metres.
    """

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    extra: dict = field(default_factory=dict, compare=False)
    # The Rodrigues vector R was made from, kept so a rig file round-trips bit-exact.
    rvec_source: np.ndarray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        t = np.asarray(self.t, dtype=np.float64).ravel()
        if dist.size not in (0, 4, 5, 8):
            raise ValueError(f"camera {self.name!r}: distortion must have 0, 4, 5 or 8 coefficients, got {dist.size}")
        if t.size != 3:
            raise ValueError(f"camera {self.name!r}: translation must have 3 values, got {t.size}")
        for label, arr in (("matrix", K), ("distortions", dist), ("rotation", R), ("translation", t)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"camera {self.name!r}: {label} has NaN or inf")
        if np.abs(K[2] - (0.0, 0.0, 1.0)).max() > 1e-12 or abs(K[1, 0]) > 1e-12 or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(f"camera {self.name!r}: matrix must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] "
                             f"with fx, fy > 0, got {K.tolist()}")
        if abs(np.linalg.det(R) - 1.0) > 1e-6 or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError(f"camera {self.name!r}: rotation is not a proper rotation matrix")
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise ValueError(f"camera {self.name!r}: size must be positive, got {self.size}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "size", (w, h))
        # derived once: K^-1 (affine, as K's last row is [0, 0, 1]) for back-projection
        object.__setattr__(self, "_K_inv", np.linalg.inv(K))

    # ------------------------------------------------------------------ derived
    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in the world frame, metres."""
        return -self.R.T @ self.t

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix K [R | t] (no distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def world_from_cam(self) -> np.ndarray:
        """(4, 4) homogeneous transform camera -> world."""
        T = np.eye(4)
        T[:3, :3] = self.R.T
        T[:3, 3] = self.center
        return T

    @property
    def rvec(self) -> np.ndarray:
        """(3,) Rodrigues vector of R (the one R was built from, when there is one)."""
        if self.rvec_source is not None:
            return np.array(self.rvec_source, dtype=np.float64)
        return rodrigues_from_rotation(self.R)

    def with_pose(self, R: np.ndarray, t: np.ndarray) -> "Camera":
        return Camera(self.name, self.size, self.K, self.dist, R, t, dict(self.extra))

    # --------------------------------------------------------------- projection
    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) camera-frame points, metres."""
        pts = as_points(points_world, 3, "points_world")
        return pts @ self.R.T + self.t

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) ideal normalised coordinates -> (N, 2) distorted normalised coordinates."""
        return np.stack(distort(xy[:, 0], xy[:, 1], dist8(self.dist)), axis=1)

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points into the image.

        points_world : (N, 3) float64, metres, world frame.
        Returns ``(uv, in_front)``: uv (N, 2) float64 pixels with distortion applied,
        NaN for points behind the camera; in_front (N,) bool.
        Matches ``cv2.projectPoints`` for points in front of the camera (cv2 ignores a
        skew term ``K[0, 1]``; this projection applies the full K).
        """
        pc = self.to_camera(points_world)
        in_front = pc[:, 2] > MIN_DEPTH_M
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pc[:, :2] / pc[:, 2:3]
        xy = self.distort_normalized(xy)
        uv = xy @ self.K[:2, :2].T + self.K[:2, 2]
        uv[~in_front] = np.nan
        return uv, in_front

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) distorted pixels -> (N, 2) ideal normalised coordinates (x/z, y/z)."""
        uv = as_points(uv, 2, "uv")
        if uv.shape[0] == 0:
            return np.zeros((0, 2))
        # Remove K (skew included, as project() applies it) to get distorted normalised xy.
        Kinv = self._K_inv
        xy = uv @ Kinv[:2, :2].T + Kinv[:2, 2]
        # OpenCV's iterative undistortion with K = I (cv2 ignores K's skew, so it is removed above)
        return undistort(xy, self.dist)

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels to world rays.

        uv : (N, 2) pixels (distorted, as seen in the image).
        Returns ``(origins, directions)``: (N, 3) camera centre repeated and (N, 3) unit
        directions, world frame.
        """
        xy = self.undistort_pixels(uv)
        d_cam = np.hstack([xy, np.ones((xy.shape[0], 1))])
        d_world = d_cam @ self.R  # R.T @ d for each row
        d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
        origins = np.broadcast_to(self.center, d_world.shape).copy()
        return origins, d_world

    def in_image(self, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """(N,) bool: pixel inside the image (pixel centres at integers)."""
        uv = as_points(uv, 2, "uv")
        u, v = uv[:, 0], uv[:, 1]
        with np.errstate(invalid="ignore"):
            return (
                (u >= -0.5 + margin_px)
                & (u < self.width - 0.5 - margin_px)
                & (v >= -0.5 + margin_px)
                & (v < self.height - 0.5 - margin_px)
            )
