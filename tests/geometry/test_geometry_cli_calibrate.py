"""`mocap-rt calibrate` end to end: CSV / rendered images in, rig TOML out."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from mocap_rt.cli import main
from mocap_rt.geometry.board import BoardSpec, floor_placement
from mocap_rt.geometry.board_render import render_board_view
from mocap_rt.geometry.camera import Camera, look_at, rotation_from_rodrigues
from mocap_rt.geometry.rig import read_rig, ring_rig

BOARD = BoardSpec("charuco", 6, 5, 0.08, 0.06, "DICT_4X4_50")
BOARD_ARGS = ["--board", "charuco", "--squares", "6x5", "--square-m", "0.08", "--marker-m", "0.06",
              "--dict", "DICT_4X4_50"]


def _write_csv(path, X, uv, header=("X", "Y", "Z", "u", "v")):
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(np.hstack([X, uv]).tolist())


def test_dlt_command_recovers_cameras_and_adds_them_to_the_rig(tmp_path, capsys):
    rig = ring_rig(3)
    rng = np.random.default_rng(0)
    X = rng.uniform([-1, -1, 0], [1, 1, 2], (30, 3))
    out = tmp_path / "rig.toml"
    for cam in (rig[0], rig[2]):
        pts = tmp_path / f"{cam.name}.csv"
        _write_csv(pts, X, cam.project(X)[0])
        code = main(["calibrate", "dlt", "--points", str(pts), "--size", "640x480", "--name", cam.name,
                     "--out", str(out)])
        assert code == 0
        assert "reprojection RMS 0.0000 px" in capsys.readouterr().out
    got = read_rig(out)
    assert got.names == ["cam_1", "cam_3"]
    for name in got.names:
        np.testing.assert_allclose(got[name].K, rig[name].K, rtol=1e-9, atol=1e-7)
        np.testing.assert_allclose(got[name].R, rig[name].R, atol=1e-9)
        np.testing.assert_allclose(got[name].t, rig[name].t, atol=1e-9)
    # re-calibrating cam_1 from noisy points replaces it in place, keeping the order
    pts = tmp_path / "noisy.csv"
    _write_csv(pts, X, rig[0].project(X)[0] + rng.normal(0, 0.5, (30, 2)))
    assert main(["calibrate", "dlt", "--points", str(pts), "--size", "640x480", "--name", "cam_1",
                 "--out", str(out)]) == 0
    rms = float(capsys.readouterr().out.split("reprojection RMS ")[1].split()[0])
    assert 0.2 < rms < 1.0
    assert read_rig(out).names == ["cam_1", "cam_3"]


@pytest.mark.parametrize("rows, header, pattern", [
    (5, ("X", "Y", "Z", "u", "v"), "at least 6"),
    (10, ("X", "Y", "Z", "u"), "missing v"),
    (10, ("X", "Y", "Z", "u", "v"), "coplanar"),
])
def test_dlt_command_reports_bad_input(tmp_path, capsys, rows, header, pattern):
    cam = ring_rig(1)[0]
    X = np.random.default_rng(1).uniform(-1, 1, (rows, 3))
    if pattern == "coplanar":
        X[:, 2] = 0.5
    uv = cam.project(X)[0]
    pts = tmp_path / "pts.csv"
    _write_csv(pts, X[:, :len(header) - 2] if len(header) < 5 else X, uv if len(header) == 5 else uv[:, :1],
               header)
    out = tmp_path / "rig.toml"
    code = main(["calibrate", "dlt", "--points", str(pts), "--size", "640x480", "--name", "c", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and pattern in err
    assert not out.exists()


def test_dlt_command_bad_csv_value_names_line(tmp_path, capsys):
    pts = tmp_path / "pts.csv"
    pts.write_text("X,Y,Z,u,v\n1,2,3,4,5\n1,2,oops,4,5\n")
    assert main(["calibrate", "dlt", "--points", str(pts), "--size", "640x480", "--name", "c",
                 "--out", str(tmp_path / "r.toml")]) == 2
    assert f"{pts}:3" in capsys.readouterr().err
    assert main(["calibrate", "dlt", "--points", str(pts), "--size", "640by480", "--name", "c",
                 "--out", str(tmp_path / "r.toml")]) == 2
    assert "--size" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["calibrate"], ["calibrate", "dlt"], ["calibrate", "board"]])
def test_help(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv + ["--help"])
    assert info.value.code == 0
    assert "usage: mocap-rt calibrate" in capsys.readouterr().out


@pytest.mark.slow
def test_board_command_images_and_video_then_floor_placement(tmp_path, capsys):
    K = np.array([[600.0, 0, 318.0], [0, 600.0, 242.0], [0, 0, 1]])
    R, t = look_at([0.0, -1.3, 1.3], [0.0, 0.0, 0.0])
    truth = Camera("cam_2", (640, 480), K, [-0.12, 0.04, 0.0, 0.0, 0.0], R, t)
    rng = np.random.default_rng(3)
    folder = tmp_path / "intrinsics"
    folder.mkdir()
    frames = []
    for i in range(6):  # board held 0.6-0.8 m in front of the camera, tilted
        cam_from_board = np.eye(4)
        cam_from_board[:3, :3] = rotation_from_rodrigues(np.radians(rng.uniform(-30, 30, 3)) * [1, 1, 0.5])
        cam_from_board[:3, 3] = [rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.6, 0.8)]
        cam_from_board[:3, 3] -= cam_from_board[:3, :3] @ [0.24, 0.2, 0.0]
        img = render_board_view(truth, BOARD, truth.world_from_cam @ cam_from_board, px_per_square=40)
        cv2.imwrite(str(folder / f"view_{i}.png"), img)
        frames.append(img)
    placement = floor_placement((-0.24, 0.2, 0.0))  # board centred on the origin, face up
    ext = tmp_path / "floor.png"
    cv2.imwrite(str(ext), render_board_view(truth, BOARD, placement, px_per_square=40))
    out = tmp_path / "rig.toml"
    code = main(["calibrate", "board", "--images", str(folder), *BOARD_ARGS, "--extrinsic-image", str(ext),
                 "--board-origin=-0.24,0.2,0", "--name", "cam_2", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "intrinsics from 6 of 6 images" in text
    cam = read_rig(out)["cam_2"]
    np.testing.assert_allclose(cam.K[[0, 1], [0, 1]], [600.0, 600.0], rtol=0.02)
    assert np.linalg.norm(cam.center - truth.center) < 0.03
    assert np.degrees(np.arccos(np.clip((np.trace(cam.R @ truth.R.T) - 1) / 2, -1, 1))) < 1.0
    # the same views as a video; intrinsics then reused from the rig with known points
    video = tmp_path / "board.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (640, 480))
    for img in frames:
        writer.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    writer.release()
    out2 = tmp_path / "rig2.toml"
    assert main(["calibrate", "board", "--images", str(video), "--every", "1", *BOARD_ARGS,
                 "--name", "cam_2", "--out", str(out2)]) == 0
    assert "intrinsics from 6 of 6 images" in capsys.readouterr().out
    X = np.random.default_rng(4).uniform([-0.5, -0.5, 0], [0.5, 0.5, 0.6], (10, 3))  # inside the views
    pts = tmp_path / "known.csv"
    _write_csv(pts, X, truth.project(X)[0])
    assert main(["calibrate", "board", "--intrinsics-from", str(out2), *BOARD_ARGS, "--extrinsic-points",
                 str(pts), "--name", "cam_2", "--out", str(out2)]) == 0
    cam2 = read_rig(out2)["cam_2"]
    assert np.linalg.norm(cam2.center - truth.center) < 0.05  # MJPG-compressed intrinsics
    assert main(["calibrate", "board", *BOARD_ARGS, "--name", "cam_2", "--out", str(out2)]) == 2
    assert "--images" in capsys.readouterr().err


def test_make_board_writes_a_detectable_board(tmp_path, capsys):
    from mocap_rt.geometry.board import detect_board

    out = tmp_path / "board.png"
    assert main(["calibrate", "make-board", *BOARD_ARGS, "--px-per-square", "60", "--out", str(out)]) == 0
    assert "print so that one square is 8.0 cm" in capsys.readouterr().out
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (5 * 60 + 60, 6 * 60 + 60)
    det = detect_board(img, BOARD)
    assert det is not None and len(det) == BOARD.n_corners
    # corners land where the board frame says: (id position in squares) * 60 px + margin
    expected = BOARD.corner_points[det.ids, :2] / BOARD.square_m * 60 + 30 - 0.5
    np.testing.assert_allclose(det.uv, expected, atol=0.2)
