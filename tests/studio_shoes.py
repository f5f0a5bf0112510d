"""The studio's shoe rendered alone, for the tests of what perception and fusion measure on it."""

import numpy as np

from mocap_rt.studio.body_shape import SHOE, SHOE_RADIUS_M, BodyPrimitives
from mocap_rt.studio.render import StudioRenderer


def shoe_covariance(renderer: StudioRenderer, camera: int, heel: np.ndarray, toe: np.ndarray, frame: int = 0):
    """The pixel moments of one shoe capsule rendered alone by the studio: (cov (2, 2) px^2 with
    the pixel extent, centre (2,), area px) or None when it covers no pixel; ``frame`` is the
    renderer's frame index."""
    prims = BodyPrimitives(heel[None].astype(float), toe[None].astype(float), np.array([SHOE_RADIUS_M]),
                           np.array([SHOE]), ("foot",), np.zeros(6, np.int64), np.zeros(1, np.int64))
    m = renderer.render(camera, prims, frame).mask
    ys, xs = np.nonzero(m)
    if xs.size < 3:
        return None
    cov = np.cov(np.stack([xs, ys]), bias=True) + np.eye(2) / 12.0
    return cov, np.array([xs.mean(), ys.mean()]), float(xs.size)
