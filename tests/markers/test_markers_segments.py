"""Segment definition TOML: parsing, neighbours, and the documented errors."""

import pytest

from mocap_rt.markers.io import read_markers
from mocap_rt.markers.segments import (SegmentError, dumps_segments, load_segments, segments_from_dict,
                                       shipped_segments_path)

EXAMPLE = """
[segments.thigh_r]
markers = ["RTHI", "RKNE", "RTH2", "RTH3"]
[segments.shank_r]
markers = ["RTIB", "RANK", "RSH2"]
[segments.pelvis]
markers = ["LASI", "RASI", "SACR"]
[joints.knee_r]
parent = "thigh_r"
child = "shank_r"
[joints.hip_r]
parent = "pelvis"
child = "thigh_r"
"""


def test_example_from_the_issue_parses_in_file_order(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(EXAMPLE)
    segs = load_segments(path)
    assert list(segs.segments) == ["thigh_r", "shank_r", "pelvis"]
    assert segs.segments["thigh_r"] == ("RTHI", "RKNE", "RTH2", "RTH3")
    assert segs.joint_names == ("knee_r", "hip_r")
    assert segs.neighbours("knee_r") == ("hip_r",)
    assert segs.neighbours("hip_r") == ("knee_r",)
    path.write_text(dumps_segments(segs))
    assert load_segments(path) == segments_from_dict(__import__("tomllib").loads(EXAMPLE), str(path))


def test_unknown_segment_in_joint_is_named(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(EXAMPLE + '[joints.ankle_r]\nparent = "shank_r"\nchild = "foot_r"\n')
    with pytest.raises(SegmentError, match=r"joint 'ankle_r' refers to unknown segment\(s\) \['foot_r'\]"):
        load_segments(path)


def test_unknown_markers_are_all_named(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(EXAMPLE)
    segs = load_segments(path)
    labels = ["RTHI", "RKNE", "RTH2", "RTIB", "RANK", "RSH2", "LASI", "RASI", "SACR"]
    with pytest.raises(SegmentError, match=r"unknown marker.*thigh_r: \['RTH3'\]"):
        segs.check_markers(labels)
    segs.check_markers(labels + ["RTH3"])


@pytest.mark.parametrize("text, message", [
    ('[segments.a]\nmarkers = ["x", "y"]\n[joints.j]\nparent = "a"\nchild = "a"\n', "has 2 markers"),
    ('[segments.a]\nmarker = ["x", "y", "z"]\n', "exactly one key 'markers'"),
    ('[segments.a]\nmarkers = ["x", "y", "z"]\n[joints.j]\nparent = "a"\n', "needs exactly 'parent' and 'child'"),
    ('[segment.a]\nmarkers = ["x", "y", "z"]\n', "unknown top-level"),
    ('[segments.a]\nmarkers = ["x", "y", "z"]\n', "no \\[joints"),
    ('[segments.a\n', "not valid TOML"),
])
def test_malformed_definitions(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SegmentError, match=message):
        load_segments(path)


@pytest.mark.parametrize("name, trial", [
    ("biobuddy_qualisys", "markers/biobuddy_qualisys_subjectECH/functional_right_hip.c3d"),
    ("biobuddy_vicon", "markers/biobuddy_vicon_P01_lightweight/Test_func_rhip.c3d"),
    ("opensim_gait", "markers/opensim_models/gait2392_subject01_walk1.trc"),
])
def test_shipped_segment_sets_match_their_marker_sets(data_dir, name, trial):
    segs = load_segments(shipped_segments_path(name))
    segs.check_markers(read_markers(data_dir / trial).labels)
