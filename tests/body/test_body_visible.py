"""What a camera sees of each blob's body part (body/visible.py), against the studio's own
renderer (its ray-cast buffer of the nearest capsule per pixel) as the oracle."""

import numpy as np
import pytest

from mocap_rt.body.silhouette import CAPSULE_RADII_M, N_CAPSULES, body_capsules
from mocap_rt.body.visible import (COVER_CAPSULES, CUE_CAPSULES, N_PART_STATS, OFFSET_CUES, SHAPE_CUES, part_offsets,
                                   part_shapes, rig_rays, visible_parts)
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.io.bvh import read_bvh
from mocap_rt.names import CUE_NAMES
from mocap_rt.studio.body_map import body_motion
from mocap_rt.studio.body_shape import body_primitives
from mocap_rt.studio.render import RenderConfig, StudioRenderer


@pytest.fixture(scope="module")
def walk(data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    return body_motion(clip, fps=30, n_frames=40, placement="centre")


def test_visible_centres_match_the_studio_render(walk):
    """Per camera and part: the centre of the pixels the renderer gives the part's capsule
    (nearest along the ray), less the projection of its centre, agrees with
    ``part_offsets`` to a quarter of a pixel at 640x480; the offsets themselves are over
    a pixel for the hands (the sleeve covers their wrist end), so a zero offset fails. Where
    another part (the body, the other arm) hides more than ``OTHER_HIDDEN_FRAC`` of one, no
    offset is given: a few of the walk's views. The covariance of the pixels the renderer
    gives each shoe (inside the image) agrees with ``part_shapes`` to a twentieth of its size
    (median; a fifth at most); the shape of the whole shoe, with nothing hiding it, is off by a
    third or more in a tenth of the views (the trouser leg, the other shoe, the image's edge)."""
    rig = ring_rig(6, size=(640, 480))
    ren = StudioRenderer(rig, config=RenderConfig(noise_sigma_levels=0.0))
    A, B = np.empty((N_CAPSULES, 3)), np.empty((N_CAPSULES, 3))
    parts = np.empty((len(rig.cameras), len(CUE_NAMES), N_PART_STATS))
    diffs, sizes = {n: [] for n in OFFSET_CUES}, {n: [] for n in OFFSET_CUES}
    shape_errs, full_errs = [], []
    withheld = 0
    for frame in (5, 20, 35):
        points = walk.points[frame]
        prims = body_primitives(points)
        body_capsules(points, A, B)
        visible_parts(A, B, CAPSULE_RADII_M, *rig_rays(rig.cameras), CUE_CAPSULES, COVER_CAPSULES, parts)
        ours, shapes = part_offsets(parts), part_shapes(parts)
        alone = np.where(np.isin(np.arange(N_CAPSULES), CUE_CAPSULES), CAPSULE_RADII_M, 0.0)    # nothing hides
        visible_parts(A, B, alone, *rig_rays(rig.cameras), CUE_CAPSULES, COVER_CAPSULES, parts)
        whole = part_shapes(parts)
        for c, cam in enumerate(rig.cameras):
            ren.render(c, prims, frame)
            ids = ren._buffers[c]["id"]            # the renderer's nearest capsule per pixel
            for name in OFFSET_CUES:
                k = CUE_NAMES.index(name)
                m = prims.names.index(name)
                ys, xs = np.nonzero(ids == m)
                if len(xs) < 30:                  # hardly seen: no offset to compare
                    continue
                centre = cam.project(0.5 * (prims.a[m] + prims.b[m])[None])[0][0]
                oracle = np.array([xs.mean(), ys.mean()]) - centre
                if np.isnan(ours[c, k]).any():
                    withheld += 1
                    continue
                diffs[name].append(np.hypot(*(ours[c, k] - oracle)))
                sizes[name].append(np.hypot(*oracle))
            for name in SHAPE_CUES:
                k = CUE_NAMES.index(name)
                ys, xs = np.nonzero(ids == prims.names.index(name))
                if len(xs) < 30:
                    continue
                oracle = np.cov(np.stack([xs, ys]), bias=True)
                size = np.linalg.norm(oracle)
                shape_errs.append(np.linalg.norm(shapes[c, k] - oracle) / size)
                full_errs.append(np.linalg.norm(whole[c, k] - oracle) / size)
    for name in OFFSET_CUES:
        assert len(diffs[name]) >= 12
        assert np.median(diffs[name]) < 0.25, (name, np.round(diffs[name], 2))
        assert np.max(diffs[name]) < 0.8, (name, np.round(diffs[name], 2))
    assert np.median(sizes["hand_l"] + sizes["hand_r"]) > 1.0
    assert withheld <= 0.2 * sum(len(d) for d in diffs.values())
    assert len(shape_errs) >= 24
    assert np.median(shape_errs) < 0.05 and np.max(shape_errs) < 0.2, np.round(shape_errs, 3)
    assert np.percentile(full_errs, 90) > 0.3          # what hides a shoe changes its shape
    rows = {n: CUE_NAMES.index(n) for n in CUE_NAMES}
    assert np.isnan(ours[:, [rows["foot_l"], rows["foot_r"], rows["torso"]]]).all()
    assert np.isnan(shapes[:, [rows[n] for n in ("head", "hand_l", "hand_r", "torso")]]).all()


def test_no_offset_where_another_part_hides_the_part(walk):
    """The hand's offset points away from its sleeve; with the other hand's capsule moved
    between the camera and it, no offset is given (where the fit puts two limbs is less sure
    than a limb's own geometry)."""
    rig = ring_rig(6, size=(640, 480))
    rays = rig_rays(rig.cameras)
    A, B = np.empty((N_CAPSULES, 3)), np.empty((N_CAPSULES, 3))
    body_capsules(walk.points[20], A, B)
    parts = np.empty((len(rig.cameras), len(CUE_NAMES), N_PART_STATS))
    visible_parts(A, B, CAPSULE_RADII_M, *rays, CUE_CAPSULES, COVER_CAPSULES, parts)
    out = part_offsets(parts)
    k = CUE_NAMES.index("hand_l")
    c = int(np.argmax(np.linalg.norm(np.nan_to_num(out[:, k]), axis=1)))    # the view that sees most offset
    cam = rig.cameras[c]
    hand, sleeve = CUE_CAPSULES[k], COVER_CAPSULES[k]
    centre = cam.project(0.5 * (A[hand] + B[hand])[None])[0][0]
    wrist = cam.project(B[sleeve][None])[0][0]
    assert out[c, k] @ (centre - wrist) > 0.5 * np.linalg.norm(out[c, k]) * np.linalg.norm(centre - wrist)
    other = CUE_CAPSULES[CUE_NAMES.index("hand_r")]
    mid = 0.5 * (A[hand] + B[hand])
    A[other] = B[other] = mid + 0.15 * (cam.center - mid) / np.linalg.norm(cam.center - mid)
    visible_parts(A, B, CAPSULE_RADII_M, *rays, CUE_CAPSULES, COVER_CAPSULES, parts)
    assert np.isnan(part_offsets(parts)[c, k]).all()
