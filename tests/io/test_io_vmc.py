"""VMC bundles decoded by the tests' own OSC reader (tests/osc_reader.py, not python-osc): known poses, a full
forward-kinematics round trip in Unity axes, and the stream target rules."""

import numpy as np
import pytest

from mocap_rt.body.bvh_export import bvh_frame
from mocap_rt.body.humanoid import BONE_NAMES, HumanoidRig, humanoid_pose, humanoid_pose_from_bvh_row
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.skeleton import J, BoneLengths, body_model
from mocap_rt.io.vmc import VmcEncoder, parse_vmc_target, vmc_bundle
from osc_reader import JOINT, bones_of, qrot, receiver_fk, unity

MODEL = body_model(BoneLengths(), "paper")
RIG = HumanoidRig.of(MODEL)


def _bundle(angles, root=(0.4, -0.3, 0.93)):
    pos, _ = forward_kinematics(MODEL, np.array(root), angles)
    hp = humanoid_pose_from_bvh_row(RIG, MODEL, bvh_frame(MODEL, np.array(root), angles))
    return pos, vmc_bundle(hp, 2.5)


def _tpose():
    a = np.zeros((20, 3))
    a[J["shoulder_r"], 1] = np.pi / 2         # +Y swings a limb to the subject's right
    a[J["shoulder_l"], 1] = -np.pi / 2
    return a


def test_tpose_is_identity_everywhere_and_root_is_the_pelvis():
    pos, data = _bundle(_tpose())
    # the T-pose itself, checked on the joints: arms horizontal, right hand towards world +X
    assert pos[J["hand_r"], 2] == pytest.approx(pos[J["shoulder_r"], 2])
    assert pos[J["hand_r"], 0] > pos[J["shoulder_r"], 0] + 0.5
    bones, root, other = bones_of(data)
    assert list(bones) == list(BONE_NAMES) and len(bones) == 20
    for name, (_, q) in bones.items():
        np.testing.assert_allclose(q, [0, 0, 0, 1], atol=1e-6, err_msg=name)
    assert root[0] == "root"
    np.testing.assert_allclose(root[1:4], unity(pos[J["pelvis"]]), atol=1e-6)
    np.testing.assert_allclose(root[4:8], [0, 0, 0, 1])
    assert other["/VMC/Ext/OK"][0] == 1 and other["/VMC/Ext/T"] == [2.5]
    # Unity humanoid: faces +Z, its left arm along -X, legs down -Y
    assert bones["LeftLowerArm"][0][0] < -0.2 and bones["RightLowerArm"][0][0] > 0.2
    assert bones["LeftLowerLeg"][0][1] < -0.3


@pytest.mark.parametrize("side, q_y", [("l", np.sqrt(0.5)), ("r", -np.sqrt(0.5))])
def test_elbow_bent_90_degrees_in_the_tpose(side, q_y):
    """Flexing the elbow by 90 degrees in the T-pose swings the forearm forward (palms down):
    a rotation about Unity's up axis, taking -X (left) or +X (right) to +Z. Unity's R_y(phi)
    maps (-1, 0, 0) to (-cos phi, 0, sin phi): +90 degrees for the left arm, -90 for the right,
    i.e. the quaternion (0, +-sin 45, 0, cos 45)."""
    a = _tpose()
    a[J[f"elbow_{side}"], 0] = np.pi / 2       # elbow flexion
    pos, data = _bundle(a)
    fore = pos[J[f"wrist_{side}"]] - pos[J[f"elbow_{side}"]]
    np.testing.assert_allclose(fore / np.linalg.norm(fore), [0, 1, 0], atol=1e-9)   # world forward
    bones, _, _ = bones_of(data)
    lower = "LeftLowerArm" if side == "l" else "RightLowerArm"
    np.testing.assert_allclose(bones[lower][1], [0, q_y, 0, np.sqrt(0.5)], atol=1e-6)
    for name, (_, q) in bones.items():
        if name != lower:
            np.testing.assert_allclose(q, [0, 0, 0, 1], atol=1e-6, err_msg=name)


def test_receiver_forward_kinematics_rebuilds_random_poses_in_unity_axes():
    rng = np.random.default_rng(7)
    for _ in range(25):
        lo, hi = MODEL.limits[..., 0], MODEL.limits[..., 1]
        a = MODEL.clamp(rng.uniform(np.maximum(lo, -3.0), np.minimum(hi, 3.0)))
        a[0] = rng.uniform(-np.pi, np.pi, 3)               # any body orientation
        pos, data = _bundle(a, root=rng.uniform(-2, 2, 3) + [0, 0, 1])
        bones, root, _ = bones_of(data)
        for name, (_, q) in bones.items():
            assert abs(np.linalg.norm(q) - 1.0) < 1e-6, name
        world = receiver_fk(bones, root)
        for name, joint in JOINT.items():
            np.testing.assert_allclose(world[name][0], unity(pos[J[joint]]), atol=2e-6, err_msg=name)
        # the hand centre: the wrist plus the T-pose hand offset turned by the hand's rotation
        for side, sx in (("Left", -1.0), ("Right", 1.0)):
            P, W = world[f"{side}Hand"]
            hand = P + qrot(W, np.array([sx * MODEL.lengths.hand_m, 0, 0]))
            np.testing.assert_allclose(hand, unity(pos[J[f"hand_{side[0].lower()}"]]), atol=2e-6)


def test_stream_targets():
    assert parse_vmc_target("vmc") == ("127.0.0.1", 39539)
    assert parse_vmc_target("vmc:localhost") == ("127.0.0.1", 39539)
    assert parse_vmc_target("vmc:127.0.0.1:40000") == ("127.0.0.1", 40000)
    assert parse_vmc_target("vmc::39540") == ("127.0.0.1", 39540)
    with pytest.raises(ValueError, match="--allow-remote-stream"):
        parse_vmc_target("vmc:192.168.1.20:39539")
    assert parse_vmc_target("vmc:192.168.1.20:39539", allow_remote=True) == ("192.168.1.20", 39539)
    for bad in ("osc:1.2.3.4", "vmc:127.0.0.1:x", "vmc:127.0.0.1:70000", "vmc:a:b:c"):
        with pytest.raises(ValueError, match="--stream"):
            parse_vmc_target(bad)


def test_fast_bvh_path_equals_the_matrix_reference():
    """``humanoid_pose_from_bvh_row`` (quaternions, no tree chaining) against ``humanoid_pose``
    on the world frames of forward kinematics (matrices, scipy)."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        a = rng.uniform(-2.5, 2.5, (20, 3))
        root = rng.uniform(-1, 1, 3)
        _, rot = forward_kinematics(MODEL, root, a)
        ref = humanoid_pose(RIG, root, rot @ np.transpose(MODEL.rest_world, (0, 2, 1)))
        fast = humanoid_pose_from_bvh_row(RIG, MODEL, bvh_frame(MODEL, root, a))
        sign = np.sign(np.sum(ref.local_rotations * fast.local_rotations, axis=1))[:, None]
        np.testing.assert_allclose(fast.local_rotations * sign, ref.local_rotations, atol=1e-9)
        np.testing.assert_allclose(fast.root_position, ref.root_position, atol=1e-12)


def test_encoder_writes_the_bytes_of_vmc_bundle():
    """The stream's in-place encoder (template built by python-osc's writers, floats patched)
    gives byte for byte what ``vmc_bundle`` builds, pose after pose on one buffer, and the
    independent reader decodes the pose it was given."""
    rng = np.random.default_rng(4)
    model = body_model(BoneLengths.from_array(BoneLengths().as_array() * 1.07), "paper")
    rig = HumanoidRig.of(model)
    enc = VmcEncoder(rig.local_positions)
    for k in range(10):
        root = rng.uniform(-2, 2, 3)
        hp = humanoid_pose_from_bvh_row(rig, model, bvh_frame(model, root, rng.uniform(-2, 2, (20, 3))))
        data = enc.encode_pose(hp, 0.1 * k)
        assert bytes(data) == vmc_bundle(hp, 0.1 * k)
        bones, root_msg, other = bones_of(bytes(data))
        np.testing.assert_allclose(root_msg[1:4], unity(root), atol=1e-6)
        np.testing.assert_allclose([bones[n][1] for n in BONE_NAMES], hp.local_rotations, atol=1e-7)
        np.testing.assert_allclose([bones[n][0] for n in BONE_NAMES], rig.local_positions, atol=1e-7)
        assert other["/VMC/Ext/T"] == [pytest.approx(0.1 * k)]
    with pytest.raises(ValueError, match="skeleton"):
        enc.encode_pose(humanoid_pose_from_bvh_row(RIG, MODEL, bvh_frame(MODEL, root, np.zeros((20, 3)))), 0.0)
    with pytest.raises(ValueError, match="local_positions"):
        VmcEncoder(np.zeros((3, 3)))
