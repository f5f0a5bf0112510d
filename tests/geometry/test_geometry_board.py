"""Board calibration on rendered images with exact truth (K, distortion, poses)."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_rt.geometry.board import (
    BoardDetection,
    BoardSpec,
    calibrate_intrinsics,
    detect_board,
    extrinsics_from_board,
    extrinsics_from_points,
    floor_placement,
    placement_from_camera,
)
from mocap_rt.geometry.board_render import render_board_view
from mocap_rt.geometry.camera import Camera, look_at, rotation_from_rodrigues
from mocap_rt.geometry.dlt import CalibrationError
from mocap_rt.geometry.rig import ring_rig

DESK_BOARD = BoardSpec("charuco", 8, 6, 0.04, 0.03, "DICT_5X5_100")
FLOOR_BOARD = BoardSpec("charuco", 5, 4, 0.2, 0.15, "DICT_4X4_50")


def _lens_camera() -> Camera:
    K = np.array([[610.0, 0.0, 322.0], [0.0, 606.0, 236.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.16, 0.06, 8e-4, -5e-4, 0.0])
    return Camera("lens", (640, 480), K, dist, np.eye(3), np.zeros(3))


def _facing_placement(camera: Camera, spec: BoardSpec, rng) -> np.ndarray:
    """world_from_board for a board 0.45-0.7 m in front of ``camera``, tilted <= 35 deg."""
    w, h = spec.squares_x * spec.square_m, spec.squares_y * spec.square_m
    tilt = np.radians(rng.uniform(-35, 35, 2))
    R_tilt = rotation_from_rodrigues([tilt[0], tilt[1], np.radians(rng.uniform(-20, 20))])
    centre = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.04, 0.04), rng.uniform(0.45, 0.7)])
    cam_from_board = np.eye(4)
    cam_from_board[:3, :3] = R_tilt
    cam_from_board[:3, 3] = centre - R_tilt @ np.array([w / 2, h / 2, 0.0])
    return camera.world_from_cam @ cam_from_board


def _angle_deg(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1)))


@pytest.mark.slow
@pytest.mark.parametrize("spec, n_views", [
    (DESK_BOARD, 8),
    (BoardSpec("chessboard", 9, 7, 0.03), 6),
])
def test_intrinsics_recovered_from_rendered_board_views(spec, n_views):
    truth = _lens_camera()
    rng = np.random.default_rng(5)
    detections = []
    for _ in range(n_views):
        img = render_board_view(truth, spec, _facing_placement(truth, spec, rng), px_per_square=30)
        detections.append(detect_board(img, spec))
    detections.append(detect_board(np.full((480, 640), 128, np.uint8), spec))  # board absent
    result = calibrate_intrinsics(detections, spec, truth.size, n_dist=5)
    assert result.used.sum() >= n_views - 1 and not result.used[-1]
    assert result.rms_px < 0.3
    np.testing.assert_allclose(result.K[[0, 1], [0, 1]], truth.K[[0, 1], [0, 1]], rtol=0.01)
    np.testing.assert_allclose(result.K[:2, 2], truth.K[:2, 2], atol=4.0)
    # the lens model: compare where it matters, the distorted position of image-corner rays
    est = Camera("est", truth.size, result.K, result.dist, np.eye(3), np.zeros(3))
    xy = np.array([[-0.35, -0.25], [0.35, 0.25], [0.3, -0.2], [0.0, 0.0]])
    X = np.hstack([xy, np.ones((4, 1))])
    np.testing.assert_allclose(est.project(X)[0], truth.project(X)[0], atol=1.5)


@pytest.mark.slow
def test_ring_extrinsics_from_one_floor_board_in_one_world_frame():
    rig = ring_rig(n_cameras=6, radius_m=3.0, height_m=2.5, target_m=(0.0, 0.0, 0.9))
    w, h = FLOOR_BOARD.squares_x * FLOOR_BOARD.square_m, FLOOR_BOARD.squares_y * FLOOR_BOARD.square_m
    placement = floor_placement((-w / 2, h / 2, 0.0))     # board centred on the world origin
    corners_world = FLOOR_BOARD.corner_points @ placement[:3, :3].T + placement[:3, 3]
    assert np.allclose(corners_world[:, 2], 0.0) and np.allclose(corners_world.mean(0), 0.0)
    for cam in rig:
        det = detect_board(render_board_view(cam, FLOOR_BOARD, placement), FLOOR_BOARD)
        assert det is not None, cam.name
        R, t, res = extrinsics_from_board(cam.K, cam.dist, det, FLOOR_BOARD, placement)
        assert np.median(res) < 0.5
        assert _angle_deg(R, cam.R) < 0.5, cam.name
        assert np.linalg.norm(-R.T @ t - cam.center) < 0.05, cam.name


@pytest.mark.slow
def test_chaining_a_second_camera_through_a_shared_board_view():
    spec = BoardSpec("charuco", 6, 5, 0.08, 0.06, "DICT_4X4_50")
    rig = ring_rig(n_cameras=6, radius_m=2.0, height_m=1.4, target_m=(0.0, 0.0, 1.0))
    cam_a, cam_b = rig[0], rig[1]
    # the board held up between the two cameras, facing both, at a pose nobody measured:
    # its axes are those of a virtual camera midway between them, looking at the target
    mid = 0.5 * (cam_a.center + cam_b.center)
    target = np.array([0.0, 0.0, 1.0])
    R_virtual, _ = look_at(mid, target)
    placement = np.eye(4)
    placement[:3, :3] = R_virtual.T
    placement[:3, 3] = mid + 0.55 * (target - mid) - R_virtual.T @ np.array([0.24, 0.2, 0.0])
    det_a = detect_board(render_board_view(cam_a, spec, placement), spec)
    det_b = detect_board(render_board_view(cam_b, spec, placement), spec)
    assert det_a is not None and det_b is not None
    est_placement = placement_from_camera(cam_a, det_a, spec)
    assert np.linalg.norm(est_placement[:3, 3] - placement[:3, 3]) < 0.01
    R, t, _ = extrinsics_from_board(cam_b.K, cam_b.dist, det_b, spec, est_placement)
    assert _angle_deg(R, cam_b.R) < 1.0
    assert np.linalg.norm(-R.T @ t - cam_b.center) < 0.03


def test_extrinsics_from_known_points_noise_free():
    rng = np.random.default_rng(2)
    truth = ring_rig(dist=(-0.1, 0.02, 0.0, 0.0, 0.0))[2]
    X = rng.uniform([-1, -1, 0], [1, 1, 2], (12, 3))
    uv = truth.project(X)[0]
    R, t, res = extrinsics_from_points(truth.K, truth.dist, X, uv)
    np.testing.assert_allclose(R, truth.R, atol=1e-8)
    np.testing.assert_allclose(t, truth.t, atol=1e-8)
    assert res.max() < 1e-6
    with pytest.raises(CalibrationError, match=">= 6"):
        extrinsics_from_points(truth.K, truth.dist, X[:4], uv[:4])
    with pytest.raises(CalibrationError, match="NaN"):
        extrinsics_from_points(truth.K, truth.dist, np.where(X == X[0, 0], np.nan, X), uv)


def test_floor_placement_is_z_up_rigid_transform():
    T = floor_placement((1.0, 2.0, 0.5), yaw_deg=90.0)
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)   # columns along +Y
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1], [0, 0, -1], atol=1e-12)  # board z down
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, 3], [1.0, 2.0, 0.5])


def test_bad_board_input():
    with pytest.raises(ValueError, match="kind"):
        BoardSpec("circles")
    with pytest.raises(ValueError, match="marker_m"):
        BoardSpec("charuco", 5, 4, 0.1, 0.2)
    with pytest.raises(ValueError, match="dictionary"):
        BoardSpec("charuco", 5, 4, 0.1, 0.05, "DICT_NOPE")
    with pytest.raises(ValueError, match="uint8"):
        detect_board(np.zeros((10, 10), np.float32), DESK_BOARD)
    assert detect_board(np.zeros((100, 100, 3), np.uint8), DESK_BOARD) is None
    few = [BoardDetection(np.arange(10), np.zeros((10, 2)))] * 2 + [None]
    with pytest.raises(CalibrationError, match=">= 3 images, found it in 2 of 3"):
        calibrate_intrinsics(few, DESK_BOARD, (640, 480))
    with pytest.raises(ValueError, match="rigid"):
        extrinsics_from_board(np.eye(3), np.zeros(5), few[0], DESK_BOARD, 2 * np.eye(4))


@pytest.mark.slow
def test_real_charuco_video_detections_and_intrinsics(data_dir):
    """Caliscope webcam video of a real (white-on-black) ChArUco board: our detections
    match the published ones (same corner ids, sub-pixel agreement) and the intrinsics
    from them agree with the published calibration of that camera."""
    import csv
    import tomllib

    import cv2

    root = data_dir / "multiview" / "caliscope_post_optimization"
    spec = BoardSpec("charuco", 4, 5, 0.054, 0.0405, "DICT_4X4_1000", inverted=True)  # charuco.toml
    published: dict[int, dict[int, tuple[float, float]]] = {}
    with open(root / "CHARUCO" / "xy_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            if row["cam_id"] == "1":
                published.setdefault(int(row["sync_index"]), {})[int(row["keypoint_id"])] = (
                    float(row["img_loc_x"]), float(row["img_loc_y"]))
    cap = cv2.VideoCapture(str(root / "cam_1.mp4"))
    detections = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        detections.append(detect_board(frame, spec))
    cap.release()
    assert len(detections) == 57                      # sync_index 35..91
    errors, matched, total = [], 0, sum(len(v) for v in published.values())
    for k, det in enumerate(detections):
        ref = published.get(35 + k, {})
        if det is None:
            continue
        for cid, uv in zip(det.ids, det.uv):
            if cid in ref:
                matched += 1
                errors.append(np.linalg.norm(uv - ref[cid]))
    assert matched >= 0.9 * total
    assert np.median(errors) < 0.5
    # ids map to the same board-frame positions as in the published file
    with open(root / "CHARUCO" / "xy_CHARUCO.csv") as fh:
        row = next(csv.DictReader(fh))
    np.testing.assert_allclose(spec.corner_points[int(row["keypoint_id"])][:2],
                               [float(row["obj_loc_x"]), float(row["obj_loc_y"])], atol=1e-9)
    result = calibrate_intrinsics(detections, spec, (1280, 720), n_dist=4)
    K_pub = np.array(tomllib.loads((root / "camera_array.toml").read_text())["cameras"]["1"]["matrix"])
    assert result.rms_px < 0.4
    np.testing.assert_allclose(result.K[[0, 1], [0, 1]], K_pub[[0, 1], [0, 1]], rtol=0.02)
    np.testing.assert_allclose(result.K[:2, 2], K_pub[:2, 2], atol=30.0)
