"""BVH -> world body points: every shared clip, axes, left/right, placement, data table."""

import dataclasses

import numpy as np
import pytest

from mocap_rt.io.bvh import read_bvh
from mocap_rt.names import JOINT_NAMES
from mocap_rt.studio.body_map import (POINT_NAMES, SkeletonMapError, body_motion, find_map,
                                      load_skeleton_maps, parse_combination)
from mocap_rt.studio.body_shape import SKIN_BGR_UCI_MEDIAN

FAMILY = {"cmu_131": "cmu_3dsmax", "cmu_02_03": "makehuman", "cmu_": "cmu_motionbuilder",
          "dataset-1": "bandai_namco"}
RIGID = [("hip_l", "knee_l"), ("knee_l", "ankle_l"), ("shoulder_r", "elbow_r"), ("elbow_r", "wrist_r"),
         ("wrist_l", "hand_l")]


def _family(name: str) -> str:
    return next(v for k, v in FAMILY.items() if name.startswith(k))


def test_every_clip_maps_to_a_plausible_upright_body(data_dir):
    clips = sorted((data_dir / "bvh").glob("*/*.bvh"))
    assert len(clips) == 13
    for path in clips:
        clip = read_bvh(path)
        body = body_motion(clip, fps=30.0)
        assert body.family == _family(path.name), path.name
        assert body.points.shape[1:] == (len(POINT_NAMES), 3) and np.isfinite(body.points).all()
        z = {n: np.median(body.point(n)[:, 2]) for n in POINT_NAMES}
        # Z up, metres: a standing adult
        assert 1.3 < z["head"] < 1.8 and 0.75 < z["pelvis"] < 1.1, (path.name, z["head"], z["pelvis"])
        assert z["head"] > z["neck"] > z["torso"] > z["pelvis"] > z["knee_l"] > z["ankle_l"] > z["foot_l"]
        # left is on the subject's left: toes point forward = up x (right hip - left hip)
        fwd = np.cross([0.0, 0.0, 1.0], body.point("hip_r") - body.point("hip_l"))
        toes = np.einsum("fi,fi->f", body.point("toe_l") - body.point("heel_l"), fwd)
        assert np.median(toes) > 0 and (toes > 0).mean() > 0.6, path.name  # mirrored: ~0
        # placement: first pelvis near the origin is not required for "first" only; feet on the floor
        feet = body.points[:, [POINT_NAMES.index(n) for n in ("toe_l", "toe_r", "heel_l", "heel_r")], 2]
        assert np.percentile(feet.min(axis=1), 5) == pytest.approx(0.045, abs=1e-9)
        for a, b in RIGID:  # slerp resampling keeps bones rigid (02_03 is 25 -> 30 fps)
            length = np.linalg.norm(body.point(a) - body.point(b), axis=1)
            assert np.ptp(length) < 1e-9, (path.name, a, b)
        assert 0.3 < body.bone_lengths()[12] < 0.5  # hip_l-knee_l, metres


def test_placement_and_resampling(data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    first = body_motion(clip, fps=30.0, placement="first")
    np.testing.assert_allclose(first.point("pelvis")[0, :2], 0.0, atol=1e-12)
    centre = body_motion(clip, fps=30.0, placement="centre")
    p = centre.point("pelvis")[:, :2]
    np.testing.assert_allclose(p.min(axis=0) + p.max(axis=0), 0.0, atol=1e-9)
    # 120 Hz -> 30 Hz is every 4th source frame: same points as mapping the source directly
    clip = dataclasses.replace(clip, frame_time_s=1 / 120)  # the file says 0.008333
    native = body_motion(clip, placement="none")
    resampled = body_motion(clip, fps=30.0, placement="none")
    np.testing.assert_allclose(resampled.points, native.points[::4][: len(resampled.points)], atol=1e-9)
    assert len(resampled.times_s) == len(resampled.points)
    np.testing.assert_allclose(np.diff(resampled.times_s), 1 / 30.0)


def test_map_table_is_validated():
    assert parse_combination("1.5 a - 0.5 b", "t") == [(1.5, "a"), (-0.5, "b")]
    with pytest.raises(SkeletonMapError, match="sum to"):
        parse_combination("1 a + 1 b", "t")
    with pytest.raises(SkeletonMapError, match="cannot parse"):
        parse_combination("1 a 1 b", "t")
    maps = load_skeleton_maps()
    assert {m.family for m in maps} == {"cmu_motionbuilder", "cmu_3dsmax", "bandai_namco", "makehuman"}
    for m in maps:
        assert set(m.points) == set(POINT_NAMES) and set(JOINT_NAMES) <= set(m.points)
    with pytest.raises(SkeletonMapError, match="no skeleton map"):
        find_map(["Root", "Thing"])


def test_bad_map_file(tmp_path):
    bad = tmp_path / "maps.toml"
    bad.write_text('[x]\ndetect = ["a"]\nunit_m = 1.0\nup = "Y"\nelbow_q = "1 a"\n')
    with pytest.raises(SkeletonMapError, match=r"\[x\].*unknown point 'elbow_q'"):
        load_skeleton_maps(bad)


def test_skin_albedo_is_the_uci_skin_median(data_dir):
    rows = np.loadtxt(data_dir / "skin" / "uci_skin_segmentation" / "Skin_NonSkin.txt", dtype=np.int64)
    skin = rows[rows[:, 3] == 1, :3]  # B, G, R
    np.testing.assert_allclose(np.median(skin, axis=0), SKIN_BGR_UCI_MEDIAN)
