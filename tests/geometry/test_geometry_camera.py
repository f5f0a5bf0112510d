"""Camera model against cv2.projectPoints / cv2.undistortPoints and geometric truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from geometry_strategies import random_camera, random_points, seeds
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.geometry.camera import Camera, look_at, rodrigues_from_rotation, rotation_from_rodrigues

SETTINGS = settings(max_examples=30, deadline=None)


@SETTINGS
@given(seeds, st.sampled_from([0, 4, 5, 8]))
def test_project_matches_cv2_project_points(seed, dist_size):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, dist_size=dist_size)
    X = random_points(rng, 40)
    uv, in_front = cam.project(X)
    assert in_front.all()
    ref = cv2.projectPoints(X, cam.rvec, cam.t, cam.K, cam.dist if dist_size else None)[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, ref, atol=1e-7)


@SETTINGS
@given(seeds, st.sampled_from([0, 4, 5, 8]), st.sampled_from([0.0, 2.0]))
def test_rays_pass_through_the_point(seed, dist_size, skew):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, dist_size=dist_size, skew=skew)
    X = random_points(rng, 40)
    uv, _ = cam.project(X)
    origins, dirs = cam.rays(uv)
    np.testing.assert_allclose(origins, np.broadcast_to(cam.center, X.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=1e-12)
    # distance of X from its ray, and the ray points forwards (towards X)
    v = X - origins
    along = np.einsum("ij,ij->i", v, dirs)
    assert np.all(along > 0)
    np.testing.assert_allclose(np.linalg.norm(v - along[:, None] * dirs, axis=1), 0.0, atol=1e-9)
    # and back: re-projecting a point on the ray gives the pixel
    np.testing.assert_allclose(cam.project(origins + 2.0 * dirs)[0], uv, atol=1e-7)


@SETTINGS
@given(seeds, st.sampled_from([4, 5, 8]))
def test_undistort_matches_cv2_undistort_points(seed, dist_size):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, dist_size=dist_size)
    uv = rng.uniform([0, 0], cam.size, (30, 2))
    ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist, None, None, None,
                              (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)).reshape(-1, 2)
    # where the lens model is invertible (strong random lenses fold over near the corners,
    # and there the fixed-point iteration has no answer), distorting the result gives
    # back the pixel, and cv2 agrees
    got = cam.undistort_pixels(uv)
    back = cam.distort_normalized(got) @ cam.K[:2, :2].T + cam.K[:2, 2]
    valid = np.linalg.norm(back - uv, axis=1) < 1e-6
    assert valid.mean() > 0.5
    np.testing.assert_allclose(got[valid], ref[valid], atol=1e-9)


def test_points_behind_camera_are_flagged_not_projected():
    rng = np.random.default_rng(0)
    cam = random_camera(rng, dist_size=5)
    X = random_points(rng, 5)
    behind = 2 * cam.center - X          # mirrored through the camera centre
    uv, in_front = cam.project(np.vstack([X, behind, cam.center[None]]))
    assert in_front[:5].all() and not in_front[5:].any()
    assert np.isfinite(uv[:5]).all() and np.isnan(uv[5:]).all()
    # cv2 would happily project the mirrored point to the same pixel as X
    ref = cv2.projectPoints(behind, cam.rvec, cam.t, cam.K, cam.dist)[0].reshape(-1, 2)
    assert np.isfinite(ref).all()


def test_projection_matrix_centre_and_transforms_agree():
    rng = np.random.default_rng(1)
    cam = random_camera(rng)
    X = random_points(rng, 10)
    h = np.hstack([X, np.ones((10, 1))]) @ cam.P.T
    np.testing.assert_allclose(h[:, :2] / h[:, 2:], cam.project(X)[0], atol=1e-9)
    np.testing.assert_allclose(cam.P @ np.append(cam.center, 1.0), 0.0, atol=1e-9)
    pc = cam.to_camera(X)
    back = (cam.world_from_cam @ np.hstack([pc, np.ones((10, 1))]).T).T[:, :3]
    np.testing.assert_allclose(back, X, atol=1e-12)
    np.testing.assert_allclose(rotation_from_rodrigues(rodrigues_from_rotation(cam.R)), cam.R, atol=1e-12)


@pytest.mark.parametrize("angle", [np.pi - 1e-9, np.pi - 1e-5, np.pi, 1e-9, 0.0])
def test_rodrigues_round_trip_is_exact_near_pi_and_zero(angle):
    """The rig file stores R as its Rodrigues vector; it must come back to rounding at every
    angle (cv2.Rodrigues takes the axis from R's vanishing skew part near pi)."""
    axis = np.array([0.3, -0.8, 0.52])
    axis /= np.linalg.norm(axis)
    R = rotation_from_rodrigues(axis * angle)
    rvec = rodrigues_from_rotation(R)
    np.testing.assert_allclose(rotation_from_rodrigues(rvec), R, rtol=0, atol=2e-15)
    np.testing.assert_allclose(np.linalg.norm(rvec), angle, rtol=0, atol=1e-12)


def test_look_at_centres_the_target_and_keeps_up_up():
    eye, target = np.array([3.0, -1.0, 2.0]), np.array([0.2, 0.1, 0.9])
    R, t = look_at(eye, target)
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    cam = Camera("c", (640, 480), K, [], R, t)
    np.testing.assert_allclose(cam.center, eye, atol=1e-12)
    uv = cam.project(np.stack([target, target + [0, 0, 0.3]]))[0]
    np.testing.assert_allclose(uv[0], [320, 240], atol=1e-9)
    assert uv[1, 1] < uv[0, 1]             # world +Z is image up (smaller v)
    assert np.linalg.det(R) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 3.0], [0, 0, 0.0])


@pytest.mark.parametrize("kwargs, pattern", [
    ({"dist": [0.1, 0.2, 0.3]}, "0, 4, 5 or 8"),
    ({"K": np.full((3, 3), np.nan)}, "matrix has NaN"),
    ({"R": np.diag([1.0, 1.0, -1.0])}, "proper rotation"),
    ({"R": 2 * np.eye(3)}, "proper rotation"),
    ({"t": [0.0, 1.0]}, "3 values"),
    ({"size": (0, 480)}, "size"),
])
def test_invalid_camera_raises(kwargs, pattern):
    args = {"name": "bad", "size": (640, 480), "K": np.eye(3), "dist": [], "R": np.eye(3), "t": np.zeros(3)}
    args.update(kwargs)
    with pytest.raises(ValueError, match=pattern):
        Camera(**args)


def test_in_image_uses_pixel_centre_convention():
    cam = Camera("c", (4, 3), np.eye(3), [], np.eye(3), np.zeros(3))
    uv = np.array([[-0.5, 0], [-0.51, 0], [3.49, 2.49], [3.5, 1], [np.nan, 1]])
    assert cam.in_image(uv).tolist() == [True, False, True, False, False]


@SETTINGS
@given(seeds, st.sampled_from([0, 4, 5, 8]), st.sampled_from([0.0, 2.0]))
def test_compiled_undistortion_matches_camera(seed, dist_size, skew):
    from mocap_rt.geometry.lens import undistort_pixels

    rng = np.random.default_rng(seed)
    cam = random_camera(rng, dist_size=dist_size, skew=skew)
    uv = rng.uniform([0, 0], cam.size, (50, 2))
    ref = cam.undistort_pixels(uv)
    # compare where the inverse exists (strong random lenses fold over near the corners)
    valid = np.linalg.norm(cam.distort_normalized(ref) @ cam.K[:2, :2].T + cam.K[:2, 2] - uv, axis=1) < 1e-6
    assert valid.mean() > 0.5
    np.testing.assert_allclose(undistort_pixels(uv, cam.K, cam.dist)[valid], ref[valid], atol=1e-10)


@pytest.mark.parametrize("K", [
    [[500.0, 0, 320], [0, 500, 240], [0, 0, 2.0]],
    [[500.0, 0, 320], [0, 500, 240], [0.001, 0, 1]],
    [[500.0, 0, 320], [3.0, 500, 240], [0, 0, 1]],
    [[-500.0, 0, 320], [0, 500, 240], [0, 0, 1]],
])
def test_intrinsics_must_be_upper_triangular_with_unit_last_row(K):
    with pytest.raises(ValueError, match="matrix must be"):
        Camera("c", (640, 480), K, [], np.eye(3), np.zeros(3))


@SETTINGS
@given(seeds, st.sampled_from([4, 5, 8]))
def test_skew_is_applied_after_distortion_like_a_full_K(seed, dist_size):
    """cv2.projectPoints ignores K[0, 1]; the camera applies the whole K to the distorted
    normalised point: u = fx xd + s yd + cx. Checked against cv2 on the skew-free K."""
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, dist_size=dist_size, skew=3.0)
    X = random_points(rng, 20)
    K0 = cam.K.copy()
    K0[0, 1] = 0.0
    uv0 = cv2.projectPoints(X, cam.rvec, cam.t, K0, cam.dist)[0].reshape(-1, 2)
    xd_yd = (uv0 - K0[:2, 2]) / np.diag(K0)[:2]              # distorted normalised (cv2)
    expected = uv0 + np.stack([3.0 * xd_yd[:, 1], np.zeros(20)], axis=1)
    np.testing.assert_allclose(cam.project(X)[0], expected, atol=1e-7)
    # and the rays invert exactly that projection
    origins, dirs = cam.rays(expected)
    v = X - origins
    off_ray = v - np.einsum("ij,ij->i", v, dirs)[:, None] * dirs
    np.testing.assert_allclose(np.linalg.norm(off_ray, axis=1), 0.0, atol=1e-9)
