"""C3D / TRC exports of the joints: round trips through ezc3d and the project's TRC reader."""

import ezc3d
import numpy as np
import pytest

from mocap_rt.io.exports import regular_rows, write_joints_trc, write_pose_exports
from mocap_rt.markers.io import read_c3d, read_trc
from mocap_rt.names import JOINT_NAMES


def _poses(rng, n=12):
    """Joints (n, 20, 3) metres, world Z up, around a standing height, with a missing joint."""
    joints = rng.uniform(-1, 1, (n, len(JOINT_NAMES), 3)) + [0, 0, 1.0]
    joints[3, 5] = np.nan
    return joints


def test_exports_round_trip_with_gaps_units_and_axes(tmp_path):
    rng = np.random.default_rng(3)
    joints = _poses(rng)
    frames = np.array([7, 8, 9, 11, 12, 13, 14, 15, 16, 17, 18, 19])     # frame 10 was dropped
    c3d_path, trc_path = write_pose_exports(tmp_path / "poses", frames, joints, 30.0)
    assert (c3d_path.name, trc_path.name) == ("poses.c3d", "poses.trc")
    grid = np.full((13, 20, 3), np.nan)
    grid[frames - 7] = joints

    # C3D through ezc3d itself: millimetres, world axes (Z up), labels, rate, missing = residual -1
    raw = ezc3d.c3d(str(c3d_path))
    point = raw["parameters"]["POINT"]
    assert [s.strip() for s in point["LABELS"]["value"]] == list(JOINT_NAMES)
    assert point["UNITS"]["value"] == ["mm"] and float(point["RATE"]["value"][0]) == 30.0
    pts = np.transpose(raw["data"]["points"][:3], (2, 1, 0))           # (F, J, 3) mm
    res = raw["data"]["meta_points"]["residuals"][0].T                 # (F, J)
    missing = ~np.isfinite(grid).all(axis=2)
    assert missing[3].all() and missing[4, 5] and missing.sum() == 21
    np.testing.assert_array_equal(res < 0, missing)
    np.testing.assert_allclose(pts[~missing], grid[~missing] * 1000.0, rtol=1e-6)   # float32 in C3D
    # ... and through the project's reader (metres, NaN for missing)
    back = read_c3d(c3d_path)
    np.testing.assert_allclose(back.positions, grid, atol=1e-6)
    assert back.rate_hz == 30.0

    # TRC: Y up (world (x, y, z) -> (x, z, -y)), millimetres, OpenSim header
    trc = read_trc(trc_path)
    assert trc.labels == JOINT_NAMES and trc.rate_hz == 30.0 and trc.first_frame == 1
    expect = np.stack([grid[..., 0], grid[..., 2], -grid[..., 1]], axis=-1)
    np.testing.assert_allclose(trc.positions, expect, atol=1e-8)
    lines = trc_path.read_text().splitlines()
    assert lines[0].split("\t") == ["PathFileType", "4", "(X/Y/Z)", "poses.trc"]
    header = dict(zip(lines[1].split("\t"), lines[2].split("\t")))
    assert header["Units"] == "mm" and header["NumFrames"] == "13" and header["NumMarkers"] == "20"
    assert header["DataRate"] == "30" and header["CameraRate"] == "30"
    assert lines[5] == ""                                               # blank line, then the rows
    row = lines[6 + 4].split("\t")                                      # 5th row: frame 5, t = 4/30 s
    assert row[0] == "5" and float(row[1]) == pytest.approx(4 / 30, abs=1e-6)
    assert float(row[2]) == pytest.approx(grid[4, 0, 0] * 1000.0, abs=1e-5)
    assert float(row[3]) == pytest.approx(grid[4, 0, 2] * 1000.0, abs=1e-5)    # Y column = world Z
    assert not list(tmp_path.glob("*.tmp*"))


def test_trc_y_axis_is_up_for_a_standing_body(tmp_path):
    """A body standing on the floor (world Z up): the head's TRC Y is its height in mm."""
    from mocap_rt.body.skeleton import body_model

    model = body_model()
    rest = model.rest_positions() + [0.3, -0.2, 0.95]      # pelvis 0.95 m above the floor
    write_joints_trc(tmp_path / "s.trc", rest[None], 60.0)
    trc = read_trc(tmp_path / "s.trc")
    head, foot = JOINT_NAMES.index("head"), JOINT_NAMES.index("foot_l")
    assert trc.positions[0, head, 1] == pytest.approx(rest[head, 2]) and trc.positions[0, head, 1] > 1.5
    assert trc.positions[0, foot, 1] < 0.15


def test_regular_rows_rejects_bad_input():
    with pytest.raises(ValueError, match="increasing"):
        regular_rows(np.array([3, 2]), np.zeros((2, 20, 3)))
    with pytest.raises(ValueError, match="joints must be"):
        regular_rows(np.array([1, 2]), np.zeros((3, 20, 3)))
    with pytest.raises(ValueError, match="fps"):
        write_joints_trc("x.trc", np.zeros((1, 20, 3)), 0.0)
