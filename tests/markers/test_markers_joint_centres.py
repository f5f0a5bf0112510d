"""Joint-centre methods: exact recovery on noise-free synthetic joints, gaps, hand cases."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap_rt.markers.joint_centres import METHODS, estimate_joint_centre, linear_33, sphere
from mocap_rt.markers.synthetic import simulate_body, simulate_joint
from mocap_rt.markers.trial import joint_centres_for_trial

ALL = sorted(METHODS)


@pytest.mark.parametrize("method", ALL)
@pytest.mark.parametrize("continuous", [True, False])
@pytest.mark.parametrize("rigid", [True, False])
def test_exact_recovery_without_noise(method, continuous, rigid):
    rng = np.random.default_rng(11 if continuous else 12)
    trial = simulate_joint(rng, n_frames=60, continuous=continuous, range_name="II", noise=0.0)
    fit = estimate_joint_centre(trial.parent, trial.child, method, rigid=rigid)
    assert fit.method == method
    np.testing.assert_allclose(fit.centre, trial.centre, atol=1e-8)
    assert fit.residual_m < 1e-8


@pytest.mark.parametrize("method", ALL)
def test_exact_recovery_with_gaps(method):
    rng = np.random.default_rng(13)
    trial = simulate_joint(rng, n_frames=80, continuous=True, range_name="II", noise=0.0, n_parent=5, n_child=5)
    parent, child = trial.parent.copy(), trial.child.copy()
    parent[rng.random(parent.shape[:2]) < 0.1] = np.nan
    child[rng.random(child.shape[:2]) < 0.1] = np.nan
    fit = estimate_joint_centre(parent, child, method, rigid=True)
    ok = np.isfinite(fit.centre).all(axis=1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(fit.centre[ok], trial.centre[ok], atol=1e-8)


def test_hand_computed_hinge_about_a_known_point():
    """Child swings about the point (1, 2, 3) around a tilted axis plus a second axis."""
    centre = np.array([1.0, 2.0, 3.0])
    parent = centre + np.array([[0.0, 0, 0.5], [0.1, 0, 0.6], [0, 0.1, 0.7]])
    angles = np.stack([np.linspace(-60, 60, 40), 20 * np.sin(np.linspace(0, 6, 40)), np.zeros(40)], axis=1)
    rel = Rotation.from_euler("xyz", angles, degrees=True)
    child_local = np.array([[0.0, 0, -0.4], [0.05, 0, -0.3], [0, 0.05, -0.35]])
    child = centre + np.einsum("fab,kb->fka", rel.as_matrix(), child_local)
    par = np.broadcast_to(parent, child.shape).copy()
    for fn in (linear_33, sphere):
        fit = fn(par, child)
        np.testing.assert_allclose(fit.centre, np.broadcast_to(centre, (40, 3)), atol=1e-9)
    radii = sphere(par, child).info["radii_m"]
    np.testing.assert_allclose(radii, np.linalg.norm(child_local, axis=1), atol=1e-9)


def test_noise_gives_bounded_error_for_every_method():
    rng = np.random.default_rng(14)
    trial = simulate_joint(rng, n_frames=100, continuous=False, range_name="II", noise=0.01)
    for method in ALL:
        fit = estimate_joint_centre(trial.parent, trial.child, method)
        err = np.linalg.norm(fit.centre - trial.centre, axis=1).mean()
        assert err < 0.1, (method, err)  # noise 1 % of segment length -> error well below 10 %


def test_unknown_method_and_too_few_frames_are_errors():
    rng = np.random.default_rng(15)
    trial = simulate_joint(rng, n_frames=3)
    with pytest.raises(ValueError, match="unknown joint-centre method 'magic'"):
        estimate_joint_centre(trial.parent, trial.child, "magic")
    with pytest.raises(ValueError, match="only 3 frames"):
        estimate_joint_centre(trial.parent, trial.child, "linear")


def test_whole_body_trial_noise_free_recovers_all_twelve_joints():
    data, segs, truth = simulate_body(n_frames=300, noise_m=0.0, seed=2)
    res = joint_centres_for_trial(data, segs, "patent")
    assert res.names == tuple(truth)
    assert len(res.names) == 12
    for k, name in enumerate(res.names):
        np.testing.assert_allclose(res.centres[:, k], truth[name], atol=1e-6, err_msg=name)
    bones = {(b.joint_a, b.joint_b): b for b in res.bone_lengths(segs)}
    assert bones[("hip_r", "knee_r")].mean_m == pytest.approx(0.42, abs=1e-6)
    assert bones[("hip_r", "knee_r")].std_m < 1e-6


def test_trial_drops_a_never_seen_marker_and_names_segments_that_cannot_be_fitted():
    data, segs, truth = simulate_body(n_frames=200, noise_m=0.0, seed=3)
    pos = data.positions.copy()
    pos[:, data.index("THIGH_R4")] = np.nan  # one of 4 thigh markers never seen: still fine
    res = joint_centres_for_trial(type(data)(data.labels, pos, data.rate_hz), segs, "score")
    k = res.names.index("knee_r")
    np.testing.assert_allclose(res.centres[:, k], truth["knee_r"], atol=1e-6)
    pos[:, data.index("THIGH_R3")] = np.nan  # now only 2 remain
    with pytest.raises(ValueError, match=r"segment 'thigh_r'.*never seen: \['THIGH_R3', 'THIGH_R4'\]"):
        joint_centres_for_trial(type(data)(data.labels, pos, data.rate_hz), segs, "score")


def test_relative_rotation_range_of_a_known_swing():
    from mocap_rt.markers.trial import relative_rotation_range_deg

    angles = np.linspace(-30.0, 30.0, 201)  # uniform swing about one axis, mean 0
    rot_child = Rotation.from_euler("x", angles[:, None], degrees=True).as_matrix()
    rot_parent = np.broadcast_to(Rotation.from_euler("z", 40, degrees=True).as_matrix(), rot_child.shape)
    rot_child = np.matmul(rot_parent, rot_child)
    # 95th percentile of |angle| for a uniform -30..30 swing is 28.5 deg
    assert relative_rotation_range_deg(rot_parent, rot_child) == pytest.approx(28.5, abs=0.2)


@pytest.mark.parametrize("method", ALL)
def test_bad_shapes_are_named(method):
    with pytest.raises(ValueError, match=rf"{method}: parent and child must be \(F, k>=3, 3\)"):
        METHODS[method](np.zeros((10, 2, 3)), np.zeros((10, 3, 3)))
