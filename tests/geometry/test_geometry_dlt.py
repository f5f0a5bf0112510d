"""DLT calibration: synthetic truth, cv2.decomposeProjectionMatrix, real ChArUco data."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest
from geometry_strategies import random_camera, seeds
from hypothesis import given, settings

from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.dlt import (
    CalibrationError,
    calibrate_dlt,
    decompose_projection,
    dlt_projection_matrix,
)

SETTINGS = settings(max_examples=25, deadline=None)


def _volume_points(rng, n):
    return rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], (n, 3))


@SETTINGS
@given(seeds)
def test_noise_free_recovery_of_K_R_t(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng, skew=float(rng.choice([0.0, 1.5])))
    X = _volume_points(rng, int(rng.integers(6, 40)))
    uv, ok = cam.project(X)
    assert ok.all()
    est, res = calibrate_dlt(X, uv, cam.size, "cam_9")
    assert est.name == "cam_9" and est.size == cam.size
    np.testing.assert_allclose(est.K, cam.K, rtol=1e-9, atol=1e-9 * cam.K[0, 0])
    np.testing.assert_allclose(est.R, cam.R, atol=1e-9)
    np.testing.assert_allclose(est.t, cam.t, atol=1e-9 * np.linalg.norm(cam.t))
    assert np.linalg.det(est.R) == pytest.approx(1.0) and est.K[0, 0] > 0 and est.K[1, 1] > 0
    assert res.shape == (len(X),) and res.max() < 1e-6


@SETTINGS
@given(seeds)
def test_decompose_matches_cv2_and_ignores_scale_and_sign(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng)
    scale = rng.uniform(0.01, 100.0)
    K_cv, R_cv, C_cv = cv2.decomposeProjectionMatrix(scale * cam.P)[:3]
    K, R, t = decompose_projection(scale * cam.P)
    np.testing.assert_allclose(K, K_cv / K_cv[2, 2], rtol=1e-9, atol=1e-9 * cam.K[0, 0])
    np.testing.assert_allclose(R, R_cv, atol=1e-9)
    np.testing.assert_allclose(-R.T @ t, (C_cv[:3] / C_cv[3]).ravel(), atol=1e-9)
    K2, R2, t2 = decompose_projection(-scale * cam.P)
    np.testing.assert_allclose(K2, K, rtol=1e-9, atol=1e-9 * cam.K[0, 0])
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-9)


def test_half_pixel_noise_gives_rms_near_noise_level():
    rng = np.random.default_rng(42)
    cam = random_camera(rng)
    X = _volume_points(rng, 200)
    uv = cam.project(X)[0] + rng.normal(0.0, 0.5, (200, 2))
    est, res = calibrate_dlt(X, uv, cam.size, "c")
    rms = np.sqrt(np.mean(res**2))
    # 2D noise sigma 0.5 px -> expected residual RMS 0.5 * sqrt(2 (2N - 11) / 2N) ~ 0.70 px
    assert 0.6 < rms < 0.8
    assert np.linalg.norm(est.center - cam.center) < 0.05
    assert abs(est.K[0, 0] / cam.K[0, 0] - 1) < 0.02


def test_projection_matrix_is_normalised_with_positive_depth():
    rng = np.random.default_rng(0)
    cam = random_camera(rng)
    X = _volume_points(rng, 12)
    P = dlt_projection_matrix(X, cam.project(X)[0])
    assert np.linalg.norm(P) == pytest.approx(1.0)
    assert np.all(np.hstack([X, np.ones((12, 1))]) @ P[2] > 0)
    np.testing.assert_allclose(P, cam.P / np.linalg.norm(cam.P), atol=1e-9)


@pytest.mark.parametrize("case, pattern", [
    ("five", "at least 6"),
    ("coplanar", "coplanar"),
    ("collinear", "coplanar"),
    ("nan", "NaN or inf"),
    ("inf", "NaN or inf"),
    ("shape", r"shape \(N, 3\)"),
    ("count", "3D points but"),
    ("repeated", "degenerate"),
    ("same_pixel", "identical"),
])
def test_bad_input_raises_calibration_error(case, pattern):
    rng = np.random.default_rng(8)
    cam = random_camera(rng)
    X = _volume_points(rng, 10)
    uv = cam.project(X)[0]
    if case == "five":
        X, uv = X[:5], uv[:5]
    elif case == "coplanar":
        X = X.copy()
        X[:, 2] = 0.3 * X[:, 0] - 0.1 * X[:, 1] + 0.2
        uv = cam.project(X)[0]
    elif case == "collinear":
        X = np.outer(np.linspace(0, 1, 10), [1.0, 2.0, 0.5])
        uv = cam.project(X)[0]
    elif case == "nan":
        X = X.copy()
        X[3, 1] = np.nan
    elif case == "inf":
        uv = uv.copy()
        uv[2, 0] = np.inf
    elif case == "shape":
        X = X[:, :2]
    elif case == "count":
        uv = uv[:9]
    elif case == "repeated":  # 4 distinct non-coplanar points repeated: rank 8 < 11
        X = np.vstack([X[:4]] * 3)
        uv = cam.project(X)[0]
    elif case == "same_pixel":
        uv = np.tile(uv[:1], (10, 1))
    with pytest.raises(CalibrationError, match=pattern):
        calibrate_dlt(X, uv, cam.size, "c")
    assert issubclass(CalibrationError, ValueError)


def test_decompose_rejects_singular_and_nan():
    with pytest.raises(CalibrationError, match="singular"):
        decompose_projection(np.hstack([np.ones((3, 3)), np.ones((3, 1))]))
    with pytest.raises(CalibrationError, match="NaN"):
        decompose_projection(np.full((3, 4), np.nan))


# ----------------------------------------------------------------------------- real data
def _caliscope(data_dir):
    import tomllib

    root = data_dir / "multiview" / "caliscope_post_optimization"
    table = tomllib.loads((root / "camera_array.toml").read_text())["cameras"]
    cams = {int(k): Camera(f"cam_{k}", tuple(v["size"]), v["matrix"], v["distortions"],
                           v["rotation"], v["translation"]) for k, v in table.items()}
    xyz = {}
    with open(root / "CHARUCO" / "xyz_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            xyz[int(row["sync_index"]), int(row["keypoint_id"])] = [
                float(row[k]) for k in ("x_coord", "y_coord", "z_coord")]
    obs: dict[int, list] = {}
    with open(root / "CHARUCO" / "xy_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            key = int(row["sync_index"]), int(row["keypoint_id"])
            obs.setdefault(int(row["cam_id"]), []).append(
                (key, float(row["img_loc_x"]), float(row["img_loc_y"])))
    return cams, xyz, obs


def test_dlt_on_real_charuco_data_agrees_with_published_calibration(data_dir):
    """Caliscope's 3D board corners (m) and their detections (px): DLT on undistorted
    pixels must find the published camera (an independent bundle adjustment)."""
    cams, xyz, obs = _caliscope(data_dir)
    for cam_id in (1, 2):
        cam = cams[cam_id]
        rows = [(xyz[k], (u, v)) for k, u, v in obs[cam_id] if k in xyz]
        X = np.array([r[0] for r in rows])
        uv = np.array([r[1] for r in rows])
        und = (np.hstack([cam.undistort_pixels(uv), np.ones((len(uv), 1))]) @ cam.K.T)[:, :2]
        est, res = calibrate_dlt(X, und, cam.size, cam.name)
        assert len(X) > 100
        assert np.median(res) < 2.5  # detections vs published model: median 0.9-1.5 px
        assert np.linalg.norm(est.center - cam.center) < 0.05
        assert abs(est.K[0, 0] / cam.K[0, 0] - 1) < 0.05
        angle = np.degrees(np.arccos(np.clip((np.trace(est.R @ cam.R.T) - 1) / 2, -1, 1)))
        assert angle < 2.0
