"""The studio's body rendered into every camera of a rig, as the cues' compact silhouettes."""

import numpy as np

from mocap_rt.cues import CameraCues, CompactSilhouette
from mocap_rt.studio.body_shape import BodyPrimitives
from mocap_rt.studio.render import StudioRenderer


def silhouette_cues(renderer: StudioRenderer, prims: BodyPrimitives, frame: int) -> dict[str, CameraCues]:
    """{camera name: CameraCues carrying only the compact silhouette of ``prims`` as the
    renderer draws it in that camera at ``frame``} (no blob cues: NaN, zero confidence)."""
    out = {}
    for c, cam in enumerate(renderer.rig.cameras):
        m = renderer.render(c, prims, frame).mask
        ys, xs = np.nonzero(m)
        box = (xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1)
        sil = CompactSilhouette.from_box_mask(m[box[1]:box[1] + box[3], box[0]:box[0] + box[2]], box)
        out[cam.name] = CameraCues(cam.name, frame, np.full((6, 2), np.nan), np.full((6, 2, 2), np.nan),
                                   np.zeros(6), np.zeros(6), box, {}, sil)
    return out
