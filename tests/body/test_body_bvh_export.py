"""BVH output of the body model, read back with the independent ``bvh`` PyPI parser."""

import bvh
import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.body.bvh_export import WORLD_TO_BVH, bvh_frames, bvh_skeleton
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.skeleton import N_JOINTS, BoneLengths, body_model
from mocap_rt.io.bvh import read_bvh
from mocap_rt.io.bvh_writer import BvhStreamWriter, write_bvh
from mocap_rt.names import JOINT_NAMES


def _positions_with_bvh_package(text: str) -> np.ndarray:
    """Joint positions (F, J, 3) by FK over the ``bvh`` package's parse (independent of io.bvh)."""
    mocap = bvh.Bvh(text)
    names = mocap.get_joints_names()
    out = np.zeros((mocap.nframes, len(names), 3))
    for f in range(mocap.nframes):
        glob = {}
        for i, n in enumerate(names):
            chans = mocap.joint_channels(n)
            vals = mocap.frame_joint_channels(f, n, chans)
            offset = np.array(mocap.joint_offset(n), dtype=float)
            pos = offset.copy()
            rot_axes, rot_vals = "", []
            for c, v in zip(chans, vals):
                if c.endswith("position"):
                    pos["XYZ".index(c[0])] = v
                else:
                    rot_axes += c[0]
                    rot_vals.append(v)
            R = Rotation.from_euler(rot_axes, rot_vals, degrees=True).as_matrix()
            parent = mocap.joint_parent(n)
            if parent is None:
                glob[n] = (R, pos)
            else:
                pR, pp = glob[parent.name]
                glob[n] = (pR @ R, pp + pR @ pos)
            out[f, i] = glob[n][1]
    return out


def _poses(model, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = model.limits[..., 0], model.limits[..., 1]
    angles = np.where(model.dof, lo + (hi - lo) * rng.uniform(0.1, 0.9, (n,) + lo.shape), 0.0)
    angles[:, 0] = rng.uniform(-0.4, 0.4, (n, 3)) * [1, 1, 6]
    roots = rng.normal([0, 0, 1], 0.5, (n, 3))
    return roots, angles


def test_bvh_written_and_read_by_independent_parser_gives_same_joints(tmp_path):
    model = body_model(BoneLengths().scaled(0.93))
    roots, angles = _poses(model, 6, 0)
    rows = bvh_frames(model, roots, angles)
    path = tmp_path / "poses.bvh"
    write_bvh(path, bvh_skeleton(model), rows, 1 / 30)
    got = _positions_with_bvh_package(path.read_text())
    assert bvh.Bvh(path.read_text()).get_joints_names() == list(JOINT_NAMES)
    want = np.array([forward_kinematics(model, r, a)[0] for r, a in zip(roots, angles)]) @ WORLD_TO_BVH.T
    np.testing.assert_allclose(got, want, atol=1e-6)  # file precision (9 significant digits)
    # and B's reader agrees too
    clip = read_bvh(path)
    np.testing.assert_allclose(clip.motion, rows, atol=1e-6)


def test_bvh_rest_pose_is_zero_rotations_and_y_up():
    model = body_model()
    row = bvh_frames(model, np.zeros((1, 3)), np.zeros((1, N_JOINTS, 3)))[0]
    np.testing.assert_allclose(row[3:], 0.0, atol=1e-9)
    sk = bvh_skeleton(model)
    head = sk.joints[JOINT_NAMES.index("head")]
    assert head.offset[1] > 0 and head.end_site is not None  # head above the neck in Y-up


def test_stream_writer_round_trip(tmp_path):
    model = body_model()
    roots, angles = _poses(model, 4, 1)
    rows = bvh_frames(model, roots, angles)
    w = BvhStreamWriter(tmp_path / "s.bvh", bvh_skeleton(model), 1 / 30)
    for r in rows:
        w.write(r)
    w.close()
    got = _positions_with_bvh_package((tmp_path / "s.bvh").read_text())
    want = np.array([forward_kinematics(model, r, a)[0] for r, a in zip(roots, angles)]) @ WORLD_TO_BVH.T
    np.testing.assert_allclose(got, want, atol=1e-6)
