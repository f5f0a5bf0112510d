"""The recorder's C3D/TRC exports: what was recorded is in them, written atomically."""

import numpy as np

from mocap_rt.body.bvh_export import bvh_skeleton_of
from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.markers.io import read_c3d, read_trc
from nodes.messages import Pose
from nodes.recorder import PoseFiles, output_paths


def _pose(frame: int, rng) -> Pose:
    n_ch = bvh_skeleton_of(BoneLengths()).n_channels
    return Pose("r", frame, 0, 1, np.zeros((6, 3)), np.ones(6, bool), rng.uniform(-1, 2, (20, 3)),
                np.zeros(n_ch), ("a",), (), BoneLengths().as_array())


def test_pose_files_write_c3d_and_trc_matching_the_npz(tmp_path):
    rng = np.random.default_rng(1)
    npz, bvh, bones, _ = output_paths(tmp_path)
    files = PoseFiles(npz, bvh, bones, ["a"], 30.0)
    frames = [f for f in range(25) if f not in (10, 11)]          # two frames without a pose
    for f in frames[:15]:
        files.add(_pose(f, rng))
    files.snapshot(now=100.0)                                      # first rewrite: due at once
    assert read_c3d(tmp_path / "poses.c3d").n_frames == 17        # frames 0..16, 10 and 11 empty
    for f in frames[15:]:
        files.add(_pose(f, rng))
    files.snapshot(now=100.1)                                      # not due yet: NPZ only
    assert read_trc(tmp_path / "poses.trc").n_frames == 17
    files.close()                                                  # close writes everything
    with np.load(npz) as z:
        joints, rec_frames = z["joints"], z["frames"]
    np.testing.assert_array_equal(rec_frames, frames)
    c3d, trc = read_c3d(tmp_path / "poses.c3d"), read_trc(tmp_path / "poses.trc")
    assert c3d.n_frames == trc.n_frames == 25
    rows = np.asarray(frames)
    np.testing.assert_allclose(c3d.positions[rows], joints, atol=1e-6)
    np.testing.assert_allclose(trc.positions[rows][..., [0, 2, 1]] * [1, -1, 1], joints, atol=1e-8)
    assert np.isnan(c3d.positions[[10, 11]]).all() and np.isnan(trc.positions[[10, 11]]).all()
    # a second recording in the same directory never touches these files
    assert output_paths(tmp_path)[0].name == "poses_001.npz"
    assert not list(tmp_path.glob("*.tmp*"))
