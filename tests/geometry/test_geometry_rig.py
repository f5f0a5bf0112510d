"""Rig TOML (Pose2Sim/aniposelib layout) round trips, OpenCV YAML import, errors."""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import pytest
from geometry_strategies import random_camera, seeds
from hypothesis import given, settings

from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.rig import Rig, RigFileError, read_opencv_yaml, read_rig, ring_rig, rig_to_toml, write_rig

REAL_RIG = ("multiview", "pose2sim_demo_single_person", "calibration", "Calib_scene.toml")


def _same_camera(a: Camera, b: Camera) -> None:
    """Every value the file stores is bit-identical; R (stored as its Rodrigues vector)
    is rebuilt from it, so it matches to rounding unless ``a`` itself came from a file."""
    assert a.name == b.name and a.size == b.size
    for field in ("K", "dist", "t", "rvec"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    if a.rvec_source is not None:
        assert np.array_equal(a.R, b.R)
    np.testing.assert_allclose(a.R, b.R, rtol=0, atol=1e-14)  # rebuilt from the vector


@settings(max_examples=20, deadline=None)
@given(seeds)
def test_round_trip_is_bit_exact(tmp_path_factory, seed):
    rng = np.random.default_rng(seed)
    cams = tuple(random_camera(rng, f"cam_{i + 1}", dist_size=int(rng.choice([0, 4, 5, 8])))
                 for i in range(int(rng.integers(1, 8))))
    rig = Rig(cams, {"note": "random"})
    path = tmp_path_factory.mktemp("rig") / "rig.toml"
    write_rig(rig, path)
    back = read_rig(path)
    assert back.names == rig.names  # file order, never sorted
    for a, b in zip(rig, back):
        _same_camera(a, b)
    assert back.metadata["note"] == "random"
    assert rig_to_toml(back) == path.read_text()


def test_real_pose2sim_rig_round_trip(data_dir, tmp_path):
    src = data_dir.joinpath(*REAL_RIG)
    rig = read_rig(src)
    raw = tomllib.loads(src.read_text())
    assert rig.names == [k for k in raw if k != "metadata"]
    for cam in rig:
        table = raw[cam.name]
        assert cam.size == tuple(int(v) for v in table["size"])
        assert np.array_equal(cam.K, np.array(table["matrix"]))
        assert np.array_equal(cam.rvec, np.array(table["rotation"]))
        assert np.array_equal(cam.t, np.array(table["translation"]))
        # Rodrigues convention: world -> camera, checked against cv2.projectPoints
        X = np.array([[0.3, 0.2, 1.0], [-0.4, 0.1, 0.5]])
        ref = cv2.projectPoints(X, cam.rvec, cam.t, cam.K, cam.dist)[0].reshape(-1, 2)
        np.testing.assert_allclose(cam.project(X)[0], ref, atol=1e-7)
    out = tmp_path / "copy.toml"
    write_rig(rig, out)
    again = read_rig(out)
    for a, b in zip(rig, again):
        _same_camera(a, b)
    assert tomllib.loads(out.read_text()) == raw  # same tables, keys and values


def test_opencv_yaml_import(tmp_path):
    cam = random_camera(np.random.default_rng(3), dist_size=5)
    path = tmp_path / "cam.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", cam.width)
    fs.write("image_height", cam.height)
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", cam.dist.reshape(1, -1))
    fs.write("rvec", cam.rvec.reshape(3, 1))
    fs.write("tvec", cam.t.reshape(3, 1))
    fs.release()
    got = read_opencv_yaml(path, name="cam_7")
    assert got.name == "cam_7" and got.size == cam.size
    np.testing.assert_allclose(got.K, cam.K, rtol=1e-15)
    np.testing.assert_allclose(got.dist, cam.dist, rtol=1e-15)
    np.testing.assert_allclose(got.R, cam.R, atol=1e-14)
    np.testing.assert_allclose(got.t, cam.t, rtol=1e-15)
    # a 3x3 rotation node and the `size` form are accepted too
    path2 = tmp_path / "cam2.yml"
    fs = cv2.FileStorage(str(path2), cv2.FILE_STORAGE_WRITE)
    fs.write("K", cam.K)
    fs.write("R", cam.R)
    fs.write("T", cam.t.reshape(3, 1))
    fs.write("size", np.array([[cam.width, cam.height]], dtype=np.float64))
    fs.release()
    got2 = read_opencv_yaml(path2)
    assert got2.name == "cam2" and got2.size == cam.size
    np.testing.assert_allclose(got2.R, cam.R, atol=1e-14)


def test_opencv_yaml_errors(tmp_path):
    with pytest.raises(RigFileError, match="no such file"):
        read_opencv_yaml(tmp_path / "missing.yml")
    path = tmp_path / "nok.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 10)
    fs.release()
    with pytest.raises(RigFileError, match="camera_matrix"):
        read_opencv_yaml(path)


@pytest.mark.parametrize("body, pattern", [
    ('[cam_1]\nname = "cam_1"\nsize = [640.0, 480.0]\n', r"\[cam_1\] is missing matrix"),
    ("[cam_1\n", "not valid TOML"),
    ("[metadata]\nerror = 0.0\n", "no camera tables"),
    (None, "fisheye"),
    (None, "matrix must be 3x3"),
    (None, "duplicate"),
])
def test_bad_rig_files_name_file_and_field(tmp_path, body, pattern):
    good = rig_to_toml(ring_rig(2))
    if body is None and pattern == "fisheye":
        body = good.replace("fisheye = false", "fisheye = true", 1)
    elif body is None and pattern.startswith("matrix"):
        body = good.replace("matrix = ", "matrix = [ 1.0, 2.0] #", 1)
    elif body is None and pattern == "duplicate":
        body = good.replace('name = "cam_2"', 'name = "cam_1"')
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(RigFileError, match=pattern) as info:
        read_rig(path)
    assert str(path) in str(info.value)
    with pytest.raises(RigFileError, match="no such rig file"):
        read_rig(tmp_path / "absent.toml")


def test_ring_rig_geometry():
    rig = ring_rig(n_cameras=6, radius_m=3.0, height_m=1.6, target_m=(0.0, 0.0, 0.9))
    assert rig.names == [f"cam_{i}" for i in range(1, 7)]
    np.testing.assert_allclose(rig["cam_1"].center, [0.0, -3.0, 1.6], atol=1e-12)
    for cam in rig:
        assert np.linalg.norm(cam.center[:2]) == pytest.approx(3.0)
        uv, ok = cam.project(np.array([[0.0, 0.0, 0.9]]))
        assert ok[0]
        np.testing.assert_allclose(uv[0], [(cam.width - 1) / 2, (cam.height - 1) / 2], atol=1e-9)
    assert rig.with_camera(rig[0].with_pose(np.eye(3), np.ones(3))).names == rig.names
    assert rig.subset(["cam_3", "cam_1"]).names == ["cam_3", "cam_1"]


def test_aniposelib_style_tables_keep_their_names(tmp_path):
    text = (
        '[cam_0]\nname = "A"\nsize = [ 1280, 720]\n'
        "matrix = [ [ 900.0, 0.0, 640.0], [ 0.0, 900.0, 360.0], [ 0.0, 0.0, 1.0]]\n"
        "distortions = [ -0.1, 0.01, 0.0, 0.0, 0.0]\nrotation = [ 0.1, -0.2, 0.3]\n"
        "translation = [ 0.5, 0.1, 2.0]\n\n"
        '[cam_1]\nname = "B"\nsize = [ 1280, 720]\n'
        "matrix = [ [ 910.0, 0.0, 641.0], [ 0.0, 905.0, 362.0], [ 0.0, 0.0, 1.0]]\n"
        "distortions = [ 0.0, 0.0, 0.0, 0.0, 0.0]\nrotation = [ 0.0, 0.0, 0.0]\n"
        "translation = [ 0.0, 0.0, 0.0]\n\n[metadata]\nadjusted = true\nerror = 0.4\n")
    src = tmp_path / "anipose.toml"
    src.write_text(text)
    rig = read_rig(src)
    assert rig.names == ["A", "B"] and rig["B"].size == (1280, 720)
    out = tmp_path / "out.toml"
    write_rig(rig, out)
    assert tomllib.loads(out.read_text()) == {**tomllib.loads(text), **{
        k: {**v, "fisheye": False} for k, v in tomllib.loads(text).items() if k != "metadata"}}
    assert read_rig(out).metadata == {"adjusted": True, "error": 0.4}
