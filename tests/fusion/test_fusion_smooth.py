"""Offline smoothing of a clip's poses (``fusion.smooth``): a known motion with noise added,
the bones' lengths, runs kept apart, frames without a pose untouched."""

import numpy as np
import pytest

from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.skeleton import J, body_model
from mocap_rt.fusion.smooth import smooth_poses

FPS = 30.0
MODEL = body_model(preset="paper")


def motion(n: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """A slow known motion (1 Hz and slower): walking forward, turning, swinging the arms and
    bending a knee and an elbow, within the limits."""
    t = np.arange(n) / FPS
    root = np.column_stack([0.3 * np.sin(0.5 * t), 1.0 * t, 0.95 + 0.02 * np.sin(2 * np.pi * t)])
    angles = np.zeros((n, 20, 3))
    angles[:, J["pelvis"], 2] = 0.4 * np.sin(0.7 * t)
    angles[:, J["shoulder_r"], 0] = 0.6 * np.sin(2 * np.pi * t)
    angles[:, J["shoulder_l"], 1] = -0.5 - 0.3 * np.sin(2 * np.pi * 0.5 * t)
    angles[:, J["elbow_r"], 0] = 0.8 + 0.5 * np.sin(2 * np.pi * t)
    angles[:, J["hip_l"], 0] = 0.4 * np.sin(2 * np.pi * t)
    angles[:, J["knee_l"], 0] = -0.6 - 0.5 * np.sin(2 * np.pi * t)
    return root, angles


def joints_of(root: np.ndarray, angles: np.ndarray) -> np.ndarray:
    return np.array([forward_kinematics(MODEL, r, a)[0] for r, a in zip(root, angles)])


def test_noise_is_taken_out_and_the_bones_keep_their_lengths():
    root, angles = motion()
    truth = joints_of(root, angles)
    rng = np.random.default_rng(3)
    noisy_root = root + rng.normal(0, 0.01, root.shape)
    noisy = angles + np.where(MODEL.dof | (np.arange(20) == 0)[:, None], rng.normal(0, np.radians(4), angles.shape), 0)
    n = len(root)
    r, a, joints = smooth_poses(MODEL, noisy_root, noisy, np.ones(n, bool), np.ones((n, 20), bool), FPS, 4.0)
    np.testing.assert_allclose(joints, joints_of(r, a), atol=1e-9)        # the joints are the pose's
    err_noisy = np.linalg.norm(joints_of(noisy_root, noisy) - truth, axis=-1).mean()
    err = np.linalg.norm(joints - truth, axis=-1).mean()
    assert err < 0.6 * err_noisy, (err, err_noisy)
    for j, p in enumerate(MODEL.parents):
        if p >= 0:
            np.testing.assert_allclose(np.linalg.norm(joints[:, j] - joints[:, p], axis=-1),
                                       np.linalg.norm(MODEL.offsets[j]), atol=1e-9)


def test_a_slow_motion_passes_unchanged_and_keeps_its_angle_names():
    root, angles = motion()
    angles[:, J["shoulder_r"]] = [2.6, 0.3, 0.2]     # raised over the shoulder: |Y| > 90 deg under the other name
    angles[:, J["shoulder_r"], 1] = np.pi - 0.3
    n = len(root)
    r, a, joints = smooth_poses(MODEL, root, angles, np.ones(n, bool), np.ones((n, 20), bool), FPS, 6.0)
    truth = joints_of(root, angles)
    assert np.abs(joints - truth).max() < 0.01       # 1 Hz passes a 6 Hz low-pass nearly whole
    inner = slice(10, -10)
    np.testing.assert_allclose(a[inner, J["shoulder_r"]], angles[inner, J["shoulder_r"]], atol=5e-3)


def test_runs_are_not_blended_across_a_jump_or_a_gap_and_unposed_frames_stay():
    root, angles = motion(100)
    root[:] = root[0]
    angles[:] = angles[0]                             # one still pose ...
    root[50:, 0] += 2.0                               # ... that jumps 2 m at frame 50
    angles[50:, J["pelvis"], 2] += np.pi              # and turns round
    posed = np.ones(100, bool)
    posed[70:73] = False                              # three frames without a pose
    root[70:73] = np.nan
    r, a, joints = smooth_poses(MODEL, root, angles, posed, np.ones((100, 20), bool), FPS, 4.0)
    truth = joints_of(root[posed], angles[posed])
    np.testing.assert_allclose(joints[posed], truth, atol=1e-9)
    assert np.isnan(r[70:73]).all() and np.isnan(joints[70:73]).all()
    np.testing.assert_array_equal(a[70:73], angles[70:73])


def test_a_limb_at_rest_is_not_filtered():
    root, angles = motion()
    n = len(root)
    valid = np.ones((n, 20), bool)
    valid[:, [J["elbow_r"], J["wrist_r"], J["hand_r"]]] = False
    rng = np.random.default_rng(1)
    angles[:, J["elbow_r"], 0] += rng.uniform(-0.2, 0.2, n)     # jitter the filter would take out (bent 0.1-1.5)
    r, a, _ = smooth_poses(MODEL, root, angles, np.ones(n, bool), valid, FPS, 4.0)
    # its jitter (up to 0.2 rad) stays: it bends only as far as reaching its hand from the filtered trunk takes
    np.testing.assert_allclose(a[:, J["elbow_r"]], angles[:, J["elbow_r"]], atol=5e-3)


@pytest.mark.parametrize("hz", [0.0, -1.0, 15.0, 20.0])
def test_a_cutoff_outside_the_band_is_refused(hz):
    root, angles = motion(20)
    with pytest.raises(ValueError, match="cutoff"):
        smooth_poses(MODEL, root, angles, np.ones(20, bool), np.ones((20, 20), bool), FPS, hz)


def test_a_limb_reaches_its_end_bent_towards_its_pole():
    from mocap_rt.fusion.smooth import _two_link

    root, goal = np.zeros((2, 3)), np.array([[0, 0, -1.2], [0, 0, -3.0]])   # in reach; too far: stretched
    pole = np.array([[0, 1.0, -0.6], [0, 1.0, -0.6]])
    mid = _two_link(root, goal, pole, 1.0, 1.0)
    np.testing.assert_allclose(mid[0], [0, 0.8, -0.6], atol=1e-9)        # cos = (1 + 1.44 - 1) / 2.4 = 0.6
    np.testing.assert_allclose(mid[1], [0, 0, -1.0], atol=1e-4)


def test_one_posed_frame_or_none_passes_as_it_is():
    root, angles = motion(5)
    for n_posed in (0, 1):
        posed = np.arange(5) < n_posed
        r, a, joints = smooth_poses(MODEL, root, angles, posed, np.ones((5, 20), bool), FPS, 4.0)
        np.testing.assert_allclose(a, angles, atol=1e-6)
        assert np.isnan(joints[~posed]).all()
    np.testing.assert_allclose(joints[0], joints_of(root[:1], angles[:1])[0], atol=1e-12)
