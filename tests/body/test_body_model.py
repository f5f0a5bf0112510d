"""Body model: Euler/quaternion conversions, forward kinematics, frames, bone lengths."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from mocap_rt.body.estimate import bone_lengths_from_joints, estimate_bone_lengths
from mocap_rt.body.kinematics import (angles_from_frames, angles_from_quaternions, euler_xyz_from_matrix,
                                      euler_xyz_matrix, forward_kinematics, other_xyz_name,
                                      quaternions_from_angles)
from mocap_rt.body.skeleton import (END_EFFECTORS, J, N_JOINTS, BoneLengths, body_model, read_bone_lengths,
                                    write_bone_lengths)
from mocap_rt.names import CUE_JOINT_INDEX, JOINT_NAMES

angle = st.floats(-3.0, 3.0)


@settings(max_examples=60, deadline=None)
@given(angle, st.floats(-1.5, 1.5), angle)
def test_euler_matrix_matches_scipy_and_round_trips(ax, ay, az):
    R = euler_xyz_matrix(ax, ay, az)
    np.testing.assert_allclose(R, Rotation.from_euler("XYZ", [ax, ay, az]).as_matrix(), atol=1e-12)
    back = euler_xyz_from_matrix(R)
    np.testing.assert_allclose(euler_xyz_matrix(*back), R, atol=1e-9)
    np.testing.assert_allclose(back, [ax, ay, az], atol=1e-7)


@settings(max_examples=60, deadline=None)
@given(angle, angle, angle)
def test_other_xyz_name_is_the_same_rotation(ax, ay, az):
    other = np.array(other_xyz_name(ax, ay, az))
    np.testing.assert_allclose(euler_xyz_matrix(*other), euler_xyz_matrix(ax, ay, az), atol=1e-12)
    assert np.all(np.abs(other) <= np.pi)
    np.testing.assert_allclose(np.cos(np.array(other_xyz_name(*other)) - [ax, ay, az]), 1.0, atol=1e-12)  # own inverse


def random_angles(model, rng, frac=(0.0, 1.0)):
    lo, hi = model.limits[..., 0], model.limits[..., 1]
    a = np.where(model.dof, lo + (hi - lo) * rng.uniform(*frac, lo.shape), 0.0)
    a[0] = rng.uniform(-np.pi, np.pi, 3) * [0.3, 0.3, 1.0]
    return a


def test_model_counts_and_names():
    full, paper = body_model(preset="full"), body_model(preset="paper")
    assert full.n_dof == 38 and paper.n_dof == 23
    assert full.names == JOINT_NAMES and len(full.dof_names) == 38
    with pytest.raises(ValueError, match="preset"):
        body_model(preset="nope")


def test_rest_pose_geometry():
    L = BoneLengths()
    m = body_model(L)
    p = m.rest_positions()
    # standing: head above neck above torso above pelvis, hands below shoulders, left is -X
    assert p[J["head"], 2] > p[J["neck"], 2] > p[J["torso"], 2] > p[J["pelvis"], 2]
    assert p[J["hand_l"], 0] < 0 < p[J["hand_r"], 0]
    assert p[J["foot_l"], 1] > 0  # feet point forward (+Y)
    np.testing.assert_allclose(p[J["torso"]], (p[J["pelvis"]] + p[J["neck"]]) / 2)
    np.testing.assert_allclose(np.linalg.norm(p[J["knee_r"]] - p[J["hip_r"]]), L.thigh_m)
    # Z axis of every bone frame points along the bone (B.5)
    for j in range(1, N_JOINTS):
        kids = m.children(j)
        if len(kids) == 1:
            d = p[kids[0]] - p[j]
            np.testing.assert_allclose(m.rest_world[j][:, 2], d / np.linalg.norm(d), atol=1e-12)


def test_forward_kinematics_keeps_bones_and_proper_rotations():
    rng = np.random.default_rng(3)
    m = body_model()
    rest = m.rest_positions()
    for _ in range(10):
        a = random_angles(m, rng)
        root = rng.normal(size=3)
        P, R = forward_kinematics(m, root, a)
        np.testing.assert_allclose(P[0], root)
        for j in range(1, N_JOINTS):
            p = m.parents[j]
            np.testing.assert_allclose(np.linalg.norm(P[j] - P[p]), np.linalg.norm(rest[j] - rest[p]), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
        np.testing.assert_allclose(R @ np.transpose(R, (0, 2, 1)), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_angles_from_frames_inverts_fk_and_quaternions_round_trip():
    rng = np.random.default_rng(4)
    m = body_model()
    a = random_angles(m, rng, (0.1, 0.9))
    a[:, 1] = np.clip(a[:, 1], -1.4, 1.4)  # unique Euler decomposition away from gimbal lock
    _, R = forward_kinematics(m, np.zeros(3), a)
    np.testing.assert_allclose(angles_from_frames(m, R), a, atol=1e-9)
    q = quaternions_from_angles(a)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(angles_from_quaternions(q), a, atol=1e-9)


def test_limits_are_mirrored_and_contain_rest():
    m = body_model()
    lim_l, lim_r = m.limits[J["shoulder_l"]], m.limits[J["shoulder_r"]]
    np.testing.assert_allclose(lim_l[0], lim_r[0])            # flexion the same on both sides
    np.testing.assert_allclose(lim_l[1:], -lim_r[1:, ::-1])   # abduction/rotation mirrored
    assert np.all(m.limits[..., 0] <= 0) and np.all(m.limits[..., 1] >= 0)
    np.testing.assert_allclose(np.degrees(m.limits[J["knee_l"], 0]), (-135, 0))


def test_bone_lengths_toml_round_trip_and_errors(tmp_path):
    L = replace(BoneLengths().scaled(1.1), torso_cue_up_m=-0.02)      # the cue's height may be below the joint
    path = tmp_path / "bones.toml"
    write_bone_lengths(L, path)
    assert read_bone_lengths(path) == L
    assert BoneLengths.from_array(L.as_array()) == L
    bad = tmp_path / "bad.toml"
    bad.write_text("[bones]\nthigh_m = 0.4\nwing_m = 1.0\n")
    with pytest.raises(ValueError, match="bad.toml.*wing_m"):
        read_bone_lengths(bad)
    bad.write_text("[bones]\nthigh_m = -0.4\n")
    with pytest.raises(ValueError, match="thigh_m"):
        read_bone_lengths(bad)


def test_a_foot_pitched_again_keeps_the_legs_reach():
    """``with_foot_pitch``: the rest pose's hip -> knee -> foot centre (forward kinematics, the
    oracle of ``leg_reach_m``) reaches as far at the new pitch, the foot's angle below the
    horizontal is the new one, and the round trip gives the lengths back."""
    def reach_and_pitch(L):
        rest = body_model(L).rest_positions()
        knee, ankle, foot = (rest[J[f"{n}_r"]] for n in ("knee", "ankle", "foot"))
        v = foot - ankle
        return (np.linalg.norm(rest[J["knee_r"]] - rest[J["hip_r"]]) + np.linalg.norm(foot - knee),
                np.degrees(np.arctan2(-v[2], np.hypot(v[0], v[1]))))

    L = BoneLengths(thigh_m=0.45, shank_m=0.40, foot_m=0.11, foot_pitch_deg=55.0)
    for pitch in (20.0, 30.0, 55.0, 70.0):
        P = L.with_foot_pitch(pitch)
        reach, got_pitch = reach_and_pitch(P)
        assert reach == pytest.approx(reach_and_pitch(L)[0], rel=1e-12) == pytest.approx(L.leg_reach_m(), rel=1e-12)
        assert got_pitch == pytest.approx(pitch, abs=1e-9)
        assert P.trunk_m == L.trunk_m and P.upper_arm_m == L.upper_arm_m
        back = P.with_foot_pitch(L.foot_pitch_deg)
        for k in ("thigh_m", "shank_m", "foot_m", "foot_pitch_deg"):
            assert getattr(back, k) == pytest.approx(getattr(L, k), rel=1e-12)
    assert L.with_foot_pitch(L.foot_pitch_deg) is L


def test_bone_lengths_from_joints_and_from_cues():
    rng = np.random.default_rng(5)
    L = BoneLengths(trunk_m=0.46, thigh_m=0.40, forearm_m=0.24, foot_pitch_deg=35.0)
    m = body_model(L)
    frames = []
    for _ in range(40):
        a = random_angles(m, rng, (0.4, 0.6)) * 0.3
        frames.append(forward_kinematics(m, rng.normal(size=3), a)[0])
    joints = np.array(frames)
    got = bone_lengths_from_joints(joints)
    for k in ("trunk_m", "thigh_m", "forearm_m", "shoulder_half_width_m", "foot_m"):
        assert getattr(got, k) == pytest.approx(getattr(L, k), rel=1e-9)
    # a scaled default adult seen through its cues: the estimate recovers the scale
    big = BoneLengths().scaled(1.08)
    mb = body_model(big)
    cues = np.array([forward_kinematics(mb, np.zeros(3), random_angles(mb, rng, (0.45, 0.55)) * 0.1)[0]
                     [list(CUE_JOINT_INDEX)] for _ in range(30)])
    est = estimate_bone_lengths(cues)
    assert est.thigh_m == pytest.approx(big.thigh_m, rel=0.03)
    assert estimate_bone_lengths(cues[:3]) is None


def test_end_effectors_are_leaves():
    m = body_model()
    for name in END_EFFECTORS:
        assert m.children(J[name]) == []


def test_limb_lengths_from_cues_leave_out_frames_whose_fit_is_not_the_person():
    """The fit's body axes of the first frames can be far off (jumping jacks: the trunk tilted
    60 deg): those frames are left out, and the arm and leg lengths estimated from the cues of
    near-straight limbs are those of the body that made them."""
    rng = np.random.default_rng(11)
    L = BoneLengths().scaled(1.05)
    L = BoneLengths(**{**L.__dict__, "upper_arm_m": L.upper_arm_m * 0.85, "forearm_m": L.forearm_m * 0.85,
                       "hand_m": L.hand_m * 0.85})
    m = body_model(L)
    joints = np.array([forward_kinematics(m, rng.normal(size=3) * [1, 1, 0], random_angles(m, rng, (0.45, 0.55)) * 0.1)[0]
                       for _ in range(60)])
    cues = joints[:, list(CUE_JOINT_INDEX)]
    right = joints[:, J["hip_r"]] - joints[:, J["hip_l"]]
    up = joints[:, J["neck"]] - joints[:, J["pelvis"]]
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    axes = np.stack([right, np.cross(up, right), up], axis=2)                  # columns right, fwd, up
    cold = axes.copy()
    cold[:20] = Rotation.from_euler("y", 60, degrees=True).as_matrix() @ axes[:20]
    arm = L.upper_arm_m + L.forearm_m + L.hand_m
    for ax in (axes, cold):
        est = estimate_bone_lengths(cues, BoneLengths(), ax)
        assert est.upper_arm_m + est.forearm_m + est.hand_m == pytest.approx(arm, rel=0.03)
        assert est.thigh_m == pytest.approx(L.thigh_m, rel=0.03)
