"""Scene-level checks (perception/scene.py): the torso from the head and the trunk axis, the
head re-seated on top of the trunk when a hand carried its label away."""

import cv2
import numpy as np
from conftest import make_scene

from mocap_rt.geometry.rig import ring_rig
from mocap_rt.names import CUE_NAMES, SKIN_CUES
from mocap_rt.perception.pipeline import CameraPerceiver
from mocap_rt.perception.scene import (HEAD_CHECK_FRAMES, TORSO_HEAD_RADII, SceneState, check_head, head_score,
                                       torso_from_head, trunk_up)

HEAD = CUE_NAMES.index("head")


def test_torso_lies_k_head_radii_from_the_head_toward_the_ridge():
    t = torso_from_head(np.array([100.0, 50.0]), 10.0, np.array([130.0, 90.0]), k=3.0)
    np.testing.assert_allclose(t, [100.0 + 30.0 * 0.6, 50.0 + 30.0 * 0.8])        # 3-4-5 direction
    assert torso_from_head(np.array([np.nan, 50.0]), 10.0, np.array([130.0, 90.0])) is None
    assert torso_from_head(np.array([100.0, 50.0]), np.nan, np.array([130.0, 90.0])) is None


def test_trunk_axis_points_up_the_image():
    np.testing.assert_allclose(trunk_up(np.diag([4.0, 100.0])), [0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(trunk_up(np.diag([50.0, 60.0])), [0.0, -1.0])          # round band: image vertical
    a = np.deg2rad(20.0)
    v = np.array([np.sin(a), np.cos(a)])                                                 # leaning trunk
    up = trunk_up(100.0 * np.outer(v, v) + 4.0 * np.eye(2))
    np.testing.assert_allclose(up, -v, atol=1e-9)


def _skin_with_head_and_hand():
    skin = np.zeros((200, 160), np.float32)
    cv2.circle(skin, (80, 40), 10, 1.0, -1)          # head, radius 10
    cv2.circle(skin, (130, 60), 5, 1.0, -1)          # a hand beside it
    return skin


def test_head_test_takes_the_head_and_not_a_hand_at_its_height():
    ridge, up = np.array([80.0, 40.0 + TORSO_HEAD_RADII * 10.0]), np.array([0.0, -1.0])
    assert head_score(np.array([80.0, 40.0]), np.pi * 100, ridge, up) < 0.1
    assert head_score(np.array([130.0, 60.0]), np.pi * 25, ridge, up) == np.inf        # beside the axis
    assert head_score(np.array([80.0, 40.0]), np.pi * 25, ridge, up) == np.inf         # hand-sized, too far up


def test_a_head_label_on_a_hand_is_re_seated_after_a_few_frames():
    skin = _skin_with_head_and_hand()
    ridge, cov = np.array([100.0, 90.0 + TORSO_HEAD_RADII * 10.0]), np.diag([30.0, 400.0])
    origin = (20, 50)                                 # the box's top-left in the image
    state = SceneState()
    head = np.array([100.0, 90.0])                    # image px of the disc at (80, 40)
    assert check_head(state, head, np.pi * 100, 1.0, ridge, cov, skin, origin) is None
    assert abs(state.head_radius() - 10.0) < 1e-9
    hand = np.array([150.0, 110.0])
    out = [check_head(state, hand, np.pi * 25, 1.0, ridge, cov, skin, origin) for _ in range(HEAD_CHECK_FRAMES)]
    assert all(o is None for o in out[:-1])
    xy, area = out[-1]
    np.testing.assert_allclose(xy, head, atol=0.5)
    assert abs(area - (skin[:, :120] > 0).sum()) < 1e-9


def test_pipeline_brings_the_head_back_from_a_hand():
    sc = make_scene(shadow=0.5)
    p = CameraPerceiver(ring_rig()[0], sc.background)
    for f in range(3):
        p.process(sc.image, f)
    hand = np.array(sc.centres["hand_l"], float)
    p.skin_tracker.reseat(SKIN_CUES.index("head"), hand, 10.0)  # a hand carried the head label away
    xs = [p.process(sc.image, 3 + f).xy[HEAD] for f in range(HEAD_CHECK_FRAMES + 2)]
    assert np.hypot(*(xs[0] - hand)) < 3.0                     # the 2D track follows the label ...
    for xy in xs[-2:]:                                         # ... until the scene check re-seats it
        assert np.hypot(*(xy - np.array(sc.centres["head"]))) < 1.0
