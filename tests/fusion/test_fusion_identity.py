"""Left/right identity in fusion: the filter swap and the walking-side check (BodyTracker)."""

import numpy as np
import pytest

from mocap_rt.body.estimate import bone_lengths_from_joints
from mocap_rt.cues import CameraCues
from mocap_rt.fusion.filter import CueFilter
from mocap_rt.fusion.tracker import BodyTracker, FusionConfig
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.io.bvh import read_bvh
from mocap_rt.names import CUE_JOINT_INDEX, CUE_NAMES
from mocap_rt.studio.body_map import body_motion

FL, FR = CUE_NAMES.index("foot_l"), CUE_NAMES.index("foot_r")


def test_filter_swap_exchanges_the_whole_track_state():
    f = CueFilter(3)
    f.update(0.0, np.array([[0.0, 0, 0], [1, 1, 1], [np.nan] * 3]))
    f.update(0.1, np.array([[0.1, 0, 0], [1, 1, 1.2], [np.nan] * 3]))
    before = [a.copy() for a in (f.pos, f.vel, f.cov, f.alive, f.last_update_s, f.last_meas)]
    f.swap(0, 1)
    for b, a in zip(before, (f.pos, f.vel, f.cov, f.alive, f.last_update_s, f.last_meas)):
        np.testing.assert_array_equal(a[[1, 0, 2]], b)
    # the swapped tracks predict each other's paths
    np.testing.assert_allclose(f.predict_at(0.2)[1], f.pos[1] + 0.1 * f.vel[1])


@pytest.fixture(scope="module")
def walk(data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    return body_motion(clip, fps=30, n_frames=90, placement="centre").joints


def _run(rig, joints, swap_feet):
    tracker = BodyTracker(rig, FusionConfig(bone_lengths=bone_lengths_from_joints(joints)))
    rng = np.random.default_rng(0)
    err = []
    for f, J in enumerate(joints):
        C = J[list(CUE_JOINT_INDEX)]
        cues = {}
        for cam in rig.cameras:
            uv, front = cam.project(C)
            uv = uv + rng.normal(0, 1.0, uv.shape)
            ok = front & cam.in_image(uv)
            xy = np.where(ok[:, None], uv, np.nan)
            if swap_feet:                   # every view labels the feet the other way round
                xy[[FL, FR]] = xy[[FR, FL]]
                ok[[FL, FR]] = ok[[FR, FL]]
            cues[cam.name] = CameraCues(cam.name, f, xy, np.zeros((6, 2, 2)), ok * 100.0, ok * 1.0)
        r = tracker.step(f, cues)
        err.append(np.linalg.norm(r.cues_3d[[FL, FR]] - C[[FL, FR]], axis=1))
    return tracker, np.array(err)


def test_walking_side_check_unmirrors_feet_labelled_the_wrong_way_in_every_view(walk):
    rig = ring_rig()
    tracker, err = _run(rig, walk, swap_feet=True)
    assert tracker.side_swaps == 1
    assert np.median(err[:5]) > 0.1             # mirrored at first (the views agree on it) ...
    assert np.percentile(err[60:], 95) < 0.02   # ... then on the right feet for good (1 s of path + 8 votes)


def test_walking_backwards_is_not_taken_for_a_mirror(walk):
    """The same walk played backwards: hands and feet are both on the 'wrong' side of the
    velocity, which is what walking backwards looks like; the labels are right and stay."""
    rig = ring_rig()
    tracker, err = _run(rig, walk[::-1].copy(), swap_feet=False)
    assert tracker.side_swaps == 0
    assert np.percentile(err, 95) < 0.02
