"""Marker file I/O: TRC round trip, C3D against ezc3d, units, gaps and bad files."""

import ezc3d
import numpy as np
import pytest

from mocap_rt.markers.io import MarkerData, MarkerFileError, read_c3d, read_markers, read_trc, write_trc


def _random_data(rng, n_frames=37, n_markers=5):
    pos = rng.normal(scale=0.5, size=(n_frames, n_markers, 3))
    pos[3:7, 1] = np.nan  # a gap
    pos[:, 4] = np.nan  # a marker never seen
    return MarkerData(tuple(f"M{k}.x" for k in range(n_markers)), pos, 120.0, 1)


@pytest.mark.parametrize("units", ["mm", "m", "cm"])
def test_trc_round_trip_keeps_values_gaps_and_names(tmp_path, units):
    data = _random_data(np.random.default_rng(3))
    path = tmp_path / "t.trc"
    write_trc(path, data, units=units)
    back = read_trc(path)
    assert back.labels == data.labels
    assert back.rate_hz == pytest.approx(120.0)
    assert back.first_frame == 1
    np.testing.assert_array_equal(np.isnan(back.positions), np.isnan(data.positions))
    # 6 decimals in the file unit
    np.testing.assert_allclose(back.positions, data.positions, atol={"mm": 1e-9, "cm": 1e-8, "m": 1e-6}[units],
                               equal_nan=True)


def test_shared_trc_is_converted_to_metres(data_dir):
    path = data_dir / "markers/opensim_models/gait2392_subject01_walk1.trc"
    data = read_markers(path)
    assert data.positions.shape == (151, 41, 3)
    assert data.labels[0] == "R.ASIS"
    assert data.rate_hz == pytest.approx(60.0)
    # first row of the file: 617.247620 1055.275020 170.781980 (mm)
    np.testing.assert_allclose(data.positions[0, 0], [0.61724762, 1.05527502, 0.17078198])


def test_shared_c3d_matches_ezc3d_in_metres_with_gaps_as_nan(data_dir):
    path = data_dir / "markers/biobuddy_vicon_P01_lightweight/Test_func_rhip.c3d"
    data = read_c3d(path)
    raw = ezc3d.c3d(str(path))
    pts = raw["data"]["points"][:3].transpose(2, 1, 0) / 1000.0
    assert data.labels == tuple(raw["parameters"]["POINT"]["LABELS"]["value"])
    assert data.rate_hz == pytest.approx(12.0)
    missing = np.isnan(data.positions).any(axis=2)
    assert missing.any(), "this file has gaps"
    np.testing.assert_allclose(data.positions[~missing], pts[~missing])
    assert np.all(np.isnan(data.positions[missing]))
    # vertical axis is -Z in this file (head at z ~ -1.78 m): we keep the file's axes
    assert np.nanmin(data.select(["LFHD"])[..., 2]) < -1.5


def test_c3d_negative_residual_and_zero_points_are_missing(tmp_path):
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [50.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = ("A", "B")
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    pts = np.ones((4, 2, 6))
    pts[:3, 0, :] = np.arange(18).reshape(3, 6) + 1.0
    pts[:3, 1, :] = 500.0
    pts[:3, 1, 2] = 0.0  # all-zero sample
    c3d["data"]["points"] = pts
    c3d.add_parameter("POINT", "DESCRIPTIONS", ("", ""))
    path = tmp_path / "x.c3d"
    c3d.write(str(path))
    data = read_c3d(path)
    assert data.positions.shape == (6, 2, 3)
    np.testing.assert_allclose(data.positions[:, 0, 0], (np.arange(6) + 1.0) / 1000.0)
    assert np.isnan(data.positions[2, 1]).all()
    assert np.isfinite(data.positions[[0, 1, 3, 4, 5], 1]).all()


def test_bad_files_give_errors_naming_the_file(tmp_path):
    bad = tmp_path / "bad.trc"
    bad.write_text("hello\nworld\n")
    with pytest.raises(MarkerFileError, match="bad.trc.*not a TRC"):
        read_trc(bad)
    good = tmp_path / "good.trc"
    write_trc(good, _random_data(np.random.default_rng(0)))
    lines = good.read_text().splitlines()
    fields = lines[7].split("\t")
    fields[3] = "1.0abc"
    lines[7] = "\t".join(fields)
    broken = tmp_path / "broken.trc"
    broken.write_text("\n".join(lines))
    with pytest.raises(MarkerFileError, match="broken.trc: line 8"):
        read_trc(broken)
    lines = good.read_text().splitlines()
    lines[2] = lines[2].replace("\tmm\t", "\tfurlong\t")
    unit = tmp_path / "unit.trc"
    unit.write_text("\n".join(lines))
    with pytest.raises(MarkerFileError, match="unknown length unit 'furlong'"):
        read_trc(unit)
    junk = tmp_path / "junk.c3d"
    junk.write_bytes(b"\x00\x01not a c3d at all" * 10)
    with pytest.raises(MarkerFileError, match="junk.c3d"):
        read_c3d(junk)
    with pytest.raises(MarkerFileError, match="unknown marker file type"):
        read_markers(tmp_path / "x.csv")
    with pytest.raises(FileNotFoundError, match="nope.trc"):
        read_markers(tmp_path / "nope.trc")
