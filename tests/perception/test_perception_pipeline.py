"""CameraPerceiver end to end on synthetic scenes with exact truth; torso cue; perceive CLI."""

import cv2
import numpy as np
import pytest
from perception_scenes import make_scene
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.cues import CameraCues, CuePrediction
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.names import CUE_NAMES
from mocap_rt.perception.pipeline import CameraPerceiver, PerceptionConfig, load_perception_config
from mocap_rt.perception.torso import torso_point

CAM = ring_rig()[0]


def test_cues_of_a_synthetic_person_with_shadow_and_flicker():
    sc = make_scene(shadow=0.5, flicker=1.05)
    p = CameraPerceiver(CAM, sc.background)
    first = p.process(sc.image, 6)
    assert np.all(first.confidence[:5] == 0.5)       # acquired without a prediction
    cues = p.process(sc.image, 7)
    assert isinstance(cues, CameraCues) and cues.camera == CAM.name and cues.frame == 7
    for k, name in enumerate(CUE_NAMES[:5]):
        assert np.hypot(*(cues.xy[k] - sc.centres[name])) < 0.5, name
        assert cues.confidence[k] > 0.9
        assert np.all(np.linalg.eigvalsh(cues.cov[k]) > 0)
    assert cues.found.all()
    assert {"silhouette", "colour", "blobs", "torso", "total"} <= set(cues.timings_ms)
    # serialisable
    back = CameraCues.from_dict(cues.to_dict())
    np.testing.assert_array_equal(back.xy, cues.xy)


def test_tracking_a_moving_person_across_roi_updates():
    p = None
    for f, cx in enumerate(np.linspace(200, 440, 25)):
        sc = make_scene(cx=float(cx), hand_l=(cx + 95, 200 - f), hand_r=(cx - 95, 200 + f))
        if p is None:
            p = CameraPerceiver(CAM, sc.background)
        cues = p.process(sc.image, f)
        for k, name in enumerate(CUE_NAMES[:5]):
            assert np.hypot(*(cues.xy[k] - sc.centres[name])) < 0.6, (f, name)


def test_empty_scene_gives_no_cues_and_person_is_found_again():
    sc = make_scene()
    p = CameraPerceiver(CAM, sc.background)
    empty = p.process(sc.background[1], 0)
    assert empty.bbox == (0, 0, 0, 0) and not empty.found.any()
    assert p.last_silhouette is not None and not p.last_silhouette.any()
    cues = p.process(sc.image, 1)
    assert cues.found.all()


def test_prediction_drives_labelling():
    sc = make_scene()
    p = CameraPerceiver(CAM, sc.background)
    xy = np.array([sc.centres[n] for n in CUE_NAMES[:5]] + [(np.nan, np.nan)], float)
    # predictions with swapped hands: the perceiver follows the prediction's identities
    xy[[1, 2]] = xy[[2, 1]]
    pred = CuePrediction(CAM.name, 0, xy, np.ones(6, bool), np.full(6, 10.0))
    cues = p.process(sc.image, 0, pred)
    np.testing.assert_allclose(cues.xy[1], sc.centres["hand_r"], atol=0.5)
    np.testing.assert_allclose(cues.xy[2], sc.centres["hand_l"], atol=0.5)


def test_prediction_offsets_move_the_cues_by_what_the_body_hides():
    """A prediction with the offsets of the parts' visible centres (fusion's ``body.visible``):
    the head and hands are reported at their measured centres less the offsets (the skin
    blobs then go without the completion from symmetry, which moves these barely covered discs
    by under a tenth of a pixel), the shoes without offsets as before; an offset farther
    than a blob's radius, or not finite, moves nothing (a stale or forged prediction)."""
    sc = make_scene()
    xy = np.array([sc.centres[n] for n in CUE_NAMES[:5]] + [(np.nan, np.nan)], float)
    plain = CameraPerceiver(CAM, sc.background).process(sc.image, 0, CuePrediction(
        CAM.name, 0, xy, np.ones(6, bool), np.full(6, 10.0)))
    off = np.full((6, 2), np.nan)
    off[0], off[1], off[2] = (0.5, -1.0), (300.0, 0.0), (-1.5, 2.0)     # hand_l's: beyond its radius
    got = CameraPerceiver(CAM, sc.background).process(sc.image, 0, CuePrediction(
        CAM.name, 0, xy, np.ones(6, bool), np.full(6, 10.0), off))
    np.testing.assert_allclose(got.xy[0], plain.xy[0] - off[0], atol=0.15)
    np.testing.assert_allclose(got.xy[1], plain.xy[1], atol=0.15)
    np.testing.assert_allclose(got.xy[2], plain.xy[2] - off[2], atol=0.15)
    np.testing.assert_array_equal(got.xy[3:5], plain.xy[3:5])          # the torso follows the head


def test_shoes_cut_off_by_a_camouflaged_band_of_the_legs_are_kept_where_feet_are_expected():
    """A band across both shins painted with the background (trousers in front of a backdrop of
    their colour): the lower legs and shoes are components of their own. Without any expectation
    the silhouette is the body above the band and the shoes are not found; where fusion's
    prediction, or the shoes' own 2D tracks, expect them, they are the person's and found."""
    sc = make_scene()
    cut = sc.image.copy()
    cut[320:332] = sc.background[0][320:332]
    feet = [sc.centres[n] for n in ("foot_l", "foot_r")]

    blind = CameraPerceiver(CAM, sc.background)
    got = blind.process(cut, 0)
    assert got.bbox[1] + got.bbox[3] <= 320 and not got.found[3:5].any()
    xy = np.array([sc.centres[n] for n in CUE_NAMES[:5]] + [(np.nan, np.nan)], float)
    pred = CuePrediction(CAM.name, 0, xy, np.ones(6, bool), np.full(6, 10.0))
    got = CameraPerceiver(CAM, sc.background).process(cut, 0, pred)
    np.testing.assert_allclose(got.xy[3:5], feet, atol=0.6)
    tracked = CameraPerceiver(CAM, sc.background)
    for f in range(3):
        tracked.process(sc.image, f)
    got = tracked.process(cut, 3)
    np.testing.assert_allclose(got.xy[3:5], feet, atol=0.6)
    assert tracked.last_silhouette[340:400].any()
    pred = CuePrediction(CAM.name, 0, xy + [0, -130], np.ones(6, bool), np.full(6, 10.0))  # expected elsewhere
    assert not CameraPerceiver(CAM, sc.background).process(cut, 0, pred).found[3:5].any()


def test_bad_inputs_are_clear_errors(tmp_path):
    sc = make_scene(size=(320, 240))
    with pytest.raises(ValueError, match="size"):
        CameraPerceiver(CAM, sc.background)
    p = CameraPerceiver(ring_rig(size=(320, 240))[0], sc.background)
    with pytest.raises(ValueError, match="uint8"):
        p.process(sc.image.astype(np.float32), 0)
    cfg = tmp_path / "p.toml"
    cfg.write_text("roi_margin_px = 5\n[skin_blobs]\nmin_area_px = 3.0\n")
    c = load_perception_config(cfg)
    assert c.roi_margin_px == 5 and c.skin_blobs.min_area_px == 3.0 and c.shoe_blobs == PerceptionConfig().shoe_blobs
    cfg.write_text("roi_margn_px = 5\n")
    with pytest.raises(ValueError, match=r"p\.toml.*roi_margn_px"):
        load_perception_config(cfg)


def test_torso_ridge_centre_of_a_trunk_shape():
    sil = np.zeros((300, 200), np.uint8)
    cv2.rectangle(sil, (70, 60), (130, 200), 255, -1)      # trunk 61 x 141, centre (100, 130)
    cv2.circle(sil, (100, 35), 22, 255, -1)                # head
    cv2.line(sil, (70, 70), (10, 150), 255, 12)            # arm
    cv2.rectangle(sil, (75, 200), (95, 290), 255, -1)      # legs
    cv2.rectangle(sil, (105, 200), (125, 290), 255, -1)
    for step in (1, 2):
        xy, cov, thick = torso_point(sil, step=step)
        assert abs(xy[0] - 100) < 1.0 + step
        assert abs(xy[1] - 130) < 4.0 + step
        assert thick == pytest.approx(30.5, abs=1.5 * step)
    assert np.isnan(torso_point(np.zeros((5, 5), np.uint8))[0]).all()


def _trunk_with_a_loop_of_arm(hole_px: int = 0):
    """A trunk (centre (100, 130)), head and legs, and an arm raised in a loop beside the head (a
    hand behind it) whose inside is background: the filled silhouette, its filled component and
    the change codes (the loop's inside and an optional small hole in the chest unchanged)."""
    member = np.zeros((300, 240), np.uint8)
    cv2.rectangle(member, (70, 60), (130, 200), 255, -1)      # trunk
    cv2.circle(member, (100, 35), 20, 255, -1)                # head
    cv2.rectangle(member, (75, 200), (95, 290), 255, -1)      # legs
    cv2.rectangle(member, (105, 200), (125, 290), 255, -1)
    cv2.rectangle(member, (125, 5), (215, 85), 255, -1)       # the arm's loop, filled ...
    change = member.copy()
    cv2.rectangle(change, (137, 17), (203, 73), 0, -1)        # ... around background (67 x 57 px)
    if hole_px:
        change[120:120 + hole_px, 100:100 + hole_px] = 0      # a person pixel block the change test missed
    return member.copy(), member, change


def test_torso_ridge_leaves_out_the_background_in_a_loop_of_arm():
    """Filled, the loop is the silhouette's thickest part and takes the ridge; taken out as a
    loop (holes of at least the given area), the ridge is the trunk's again (the test above)."""
    sil, member, change = _trunk_with_a_loop_of_arm()
    xy, _, _ = torso_point(sil, step=2)
    assert xy[0] > 150                                        # on the filled loop
    for step in (1, 2):
        xy, _, thick = torso_point(sil, step=step, loops=(member, change, 1000.0))
        assert abs(xy[0] - 100) < 1.0 + step and abs(xy[1] - 130) < 4.0 + step
        assert thick == pytest.approx(30.5, abs=1.5 * step)
    # a hole under the least area stays filled: the point is that of the silhouette with only
    # the loop's inside cleared
    sil, member, change = _trunk_with_a_loop_of_arm(hole_px=20)
    opened = sil.copy()
    opened[17:74, 137:204] = 0
    for step in (1, 2):
        got = torso_point(sil, step=step, loops=(member, change, 1000.0))
        want = torso_point(opened, step=step)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)


def test_torso_ridge_leaves_out_a_blob_of_head_and_arms():
    """Hands on the head seen from the side: head and arms one blob, thicker than the trunk.
    The ridge centroid lands within 2.5 head radii of the head, which the trunk's middle never
    is; measured again without the silhouette that near the head, it is on the trunk. A ridge
    already far from the head is left as it is."""
    sil = np.zeros((300, 240), np.uint8)
    cv2.rectangle(sil, (70, 60), (130, 200), 255, -1)      # trunk, half width 30.5
    cv2.rectangle(sil, (75, 200), (95, 290), 255, -1)      # legs
    cv2.rectangle(sil, (105, 200), (125, 290), 255, -1)
    head = (100.0, 35.0, 20.0)
    for step in (1, 2):                                     # the trunk's ridge far from the head: unchanged
        np.testing.assert_array_equal(torso_point(sil, step=step, head=head)[0], torso_point(sil, step=step)[0])
    cv2.circle(sil, (100, 45), 44, 255, -1)                # head (radius 20 at (100, 35)) and arms round it
    for step in (1, 2):
        xy, _, _ = torso_point(sil, step=step)
        assert np.hypot(xy[0] - 100, xy[1] - 35) < 2.5 * 20            # the blob's, not the trunk's
        xy, _, thick = torso_point(sil, step=step, head=head)
        assert np.hypot(xy[0] - 100, xy[1] - 35) >= 2.5 * 20 and abs(xy[0] - 100) < 1.0 + step
        assert 85 < xy[1] < 200 and thick == pytest.approx(30.5, abs=1.5 * step)


def _reference_torso_point(sil, ridge_frac, step):
    """The torso point with OpenCV's minMaxLoc and moments."""
    sil = np.ascontiguousarray(sil[::step, ::step])
    dist = cv2.distanceTransform(sil, cv2.DIST_L2, cv2.DIST_MASK_5)
    _, peak, _, _ = cv2.minMaxLoc(dist)
    m = cv2.moments((dist >= ridge_frac * peak).view(np.uint8), binaryImage=True)
    n = m["m00"]
    xy = np.array([m["m10"] / n, m["m01"] / n]) * step
    cov = (np.array([[m["mu20"], m["mu11"]], [m["mu11"], m["mu02"]]]) / n + np.eye(2) / 12.0) * step * step
    return xy, cov, peak * step


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([1, 2]), st.sampled_from([0.5, 0.85, 1.0]))
def test_torso_point_matches_opencv_moments(seed, step, frac):
    rng = np.random.default_rng(seed)
    sil = np.zeros((90, 70), np.uint8)
    for _ in range(3):
        c = (int(rng.integers(5, 65)), int(rng.integers(5, 85)))
        cv2.ellipse(sil, c, (int(rng.integers(3, 25)), int(rng.integers(3, 40))), float(rng.uniform(0, 180)),
                    0, 360, 255, -1)
    xy, cov, thick = torso_point(sil, frac, step)
    ref_xy, ref_cov, ref_thick = _reference_torso_point(sil, frac, step)
    np.testing.assert_allclose(xy, ref_xy, rtol=1e-12)
    np.testing.assert_allclose(cov, ref_cov, rtol=1e-9, atol=1e-9)
    assert thick == ref_thick


@pytest.mark.slow
def test_perceive_cli_on_a_small_recording(tmp_path):
    from mocap_rt.cli import main
    from mocap_rt.io.recording import RecordingWriter

    rig = ring_rig(n_cameras=2, size=(320, 240))
    frames = []
    with RecordingWriter(tmp_path / "rec", rig, fps=30.0, codec="FFV1") as w:
        for cam in rig:
            w.write_backgrounds(cam.name, make_scene(size=(320, 240), scale=0.5).background)
        for f in range(6):
            scs = [make_scene(size=(320, 240), scale=0.5, cx=120.0 + 4 * f + 20 * c) for c in range(2)]
            frames.append(scs)
            w.write_frame(f, [s.image for s in scs], [f / 30.0] * 2)
    # the two flat scenes are no 3D person: the 2D-only loop
    assert main(["perceive", str(tmp_path / "rec"), "--out", str(tmp_path / "cues.npz"), "--no-progress",
                 "--skin-model", "skin", "--open-loop"]) == 0
    z = np.load(tmp_path / "cues.npz")
    assert list(z["camera_names"]) == ["cam_1", "cam_2"] and list(z["cue_names"]) == list(CUE_NAMES)
    assert z["cues_2d"].shape == (2, 6, 6, 2) and z["confidence"].shape == (2, 6, 6)
    assert z["ms_per_frame"].shape == (2, 6) and np.isfinite(z["ms_per_frame"]).all()
    assert not z["closed_loop"]
    np.testing.assert_array_equal(z["frames"], np.arange(6))
    for c in range(2):
        for f in range(6):
            for k, name in enumerate(CUE_NAMES[:5]):
                assert np.hypot(*(z["cues_2d"][c, f, k] - frames[f][c].centres[name])) < 1.0
    assert main(["perceive", str(tmp_path / "nope"), "--out", str(tmp_path / "x.npz")]) == 2


@pytest.mark.parametrize("changes", [{"close_px": 3}, {"background_update_rate": 0.02}, {"torso_step_px": 2}])
def test_optional_stages_keep_the_cues(changes):
    from dataclasses import replace

    sc = make_scene(shadow=0.5)
    image = sc.image
    p = CameraPerceiver(CAM, sc.background, replace(PerceptionConfig(), **changes))
    for f in range(3):
        cues = p.process(image, f)
    for k, name in enumerate(CUE_NAMES[:5]):
        assert np.hypot(*(cues.xy[k] - sc.centres[name])) < 1.0, name
    sil = p.last_silhouette
    assert (sil & sc.mask).sum() / (sil | sc.mask).sum() > 0.97


def test_torso_head_shift_moves_the_torso_point_away_from_the_head():
    from dataclasses import replace

    sc = make_scene(shadow=0.5)
    plain = CameraPerceiver(CAM, sc.background).process(sc.image, 0)
    shifted = CameraPerceiver(CAM, sc.background, replace(PerceptionConfig(), torso_head_shift_frac=0.1)).process(
        sc.image, 0)
    t, h = CUE_NAMES.index("torso"), CUE_NAMES.index("head")
    np.testing.assert_allclose(shifted.xy[t], plain.xy[t] - 0.1 * (plain.xy[h] - plain.xy[t]), atol=1e-9)
    np.testing.assert_array_equal(shifted.xy[:5], plain.xy[:5])
