"""Random cameras and scenes with known truth, shared by the geometry tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from mocap_rt.geometry.camera import Camera, look_at


def random_camera(rng: np.random.Generator, name: str = "cam", dist_size: int = 0,
                  skew: float = 0.0) -> Camera:
    """A camera 2.5-5 m from the origin looking near it, random intrinsics."""
    direction = rng.normal(size=3)
    direction[2] = abs(direction[2]) * 0.5
    direction /= np.linalg.norm(direction)
    eye = direction * rng.uniform(2.5, 5.0)
    target = rng.uniform(-0.3, 0.3, 3)
    R, t = look_at(eye, target)
    w, h = 640, 480
    f = rng.uniform(400.0, 1400.0)
    K = np.array([[f, skew, w / 2 + rng.uniform(-20, 20)],
                  [0.0, f * rng.uniform(0.95, 1.05), h / 2 + rng.uniform(-20, 20)],
                  [0.0, 0.0, 1.0]])
    dist = np.zeros(dist_size)
    if dist_size:
        dist[:4] = [rng.uniform(-0.2, 0.1), rng.uniform(-0.05, 0.05), rng.uniform(-1e-3, 1e-3),
                    rng.uniform(-1e-3, 1e-3)]
        if dist_size >= 5:
            dist[4] = rng.uniform(-0.02, 0.02)
        if dist_size == 8:
            dist[5:] = rng.uniform(-0.02, 0.02, 3)
    return Camera(name, (w, h), K, dist, R, t)


def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) points in a 1 m cube around the origin, metres."""
    return rng.uniform(-0.5, 0.5, (n, 3))


seeds = st.integers(min_value=0, max_value=2**32 - 1)
