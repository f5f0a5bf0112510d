"""Scene-level checks (perception/scene.py): the torso from the head and the trunk axis, the
head re-seated on top of the trunk when a hand carried its label away."""

import cv2
import numpy as np
from perception_scenes import make_scene

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


def test_a_cold_start_head_label_on_a_raised_hand_is_re_seated_at_once():
    """Arms overhead at a track's first frame: the head label took a hand above the head ("the
    region nearest the silhouette's top", the jumping jacks' first frame in two views). A label
    that never passed the head test has nothing to keep: it is re-seated on the first frame,
    where a head that passed once waits ``HEAD_CHECK_FRAMES`` (the test above)."""
    skin = np.zeros((200, 160), np.float32)
    cv2.circle(skin, (80, 60), 10, 1.0, -1)                    # head, radius 10
    cv2.circle(skin, (95, 15), 5, 1.0, -1)                     # a hand raised above it
    ridge, cov = np.array([80.0, 60.0 + TORSO_HEAD_RADII * 10.0]), np.diag([30.0, 400.0])
    hand = np.array([95.0, 15.0])
    out = check_head(SceneState(), hand, np.pi * 25, 1.0, ridge, cov, skin, (0, 0))
    assert out is not None
    np.testing.assert_allclose(out[0], (80.0, 60.0), atol=0.5)


def test_a_head_failing_on_a_tilted_axis_is_not_re_seated_on_a_hand():
    """An arm raised beside the head tilts the ridge band's axis: the head (radius 10) fails the
    test there, and only a hand-sized region beside the face passes it; the head label stays
    (the Bandai bye-bye, one view: the label went to the hand for 0.7 s)."""
    skin = np.zeros((200, 160), np.float32)
    cv2.circle(skin, (80, 40), 10, 1.0, -1)                    # head, radius 10
    cv2.circle(skin, (55, 60), 5, 1.0, -1)                     # a hand beside the face
    a = np.deg2rad(37.0)
    axis = np.array([-np.sin(a), -np.cos(a)])                  # up the tilted axis
    ridge = np.array([55.0, 60.0]) - 3.0 * 5.0 * axis          # the hand lies 3 of its radii up it
    cov = 400.0 * np.outer(axis, axis) + 30.0 * np.eye(2)
    up = trunk_up(cov)
    np.testing.assert_allclose(up, axis, atol=1e-9)
    head = np.array([80.0, 40.0])
    assert head_score(head, np.pi * 100, ridge, up) == np.inf                # the head fails on this axis ...
    assert np.isfinite(head_score(np.array([55.0, 60.0]), np.pi * 25, ridge, up))   # ... the hand passes
    state = SceneState()
    state.radii.extend([10.0] * 5)                              # the head's size, known
    out = [check_head(state, head, np.pi * 100, 1.0, ridge, cov, skin, (0, 0)) for _ in range(HEAD_CHECK_FRAMES + 2)]
    assert all(o is None for o in out)
    # the size is what decides: a state that does not know it yet re-seats on the hand
    fresh = SceneState()
    out = [check_head(fresh, head, np.pi * 100, 1.0, ridge, cov, skin, (0, 0)) for _ in range(HEAD_CHECK_FRAMES)]
    np.testing.assert_allclose(out[-1][0], (55.0, 60.0), atol=0.5)


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


def _walk_towards_the_camera(state: SceneState, radii, preds) -> None:
    """The head (a disc of each radius, in its own skin map) passes the head test every frame;
    ``preds``: fusion's predicted radius of each frame (NaN: no prediction)."""
    for r, p in zip(radii, preds):
        skin = np.zeros((400, 200), np.float32)
        cv2.circle(skin, (100, 60), int(round(r)), 1.0, -1)
        ridge = np.array([100.0, 60.0 + TORSO_HEAD_RADII * r])
        assert check_head(state, np.array([100.0, 60.0]), np.pi * r * r, 1.0, ridge, np.diag([30.0, 400.0]),
                          skin, (0, 0), p) is None


def test_head_radius_follows_the_depth_the_prediction_gives():
    """A person walking towards the camera: the head's image radius grows 3 % a frame. The plain
    median of the recent radii lags it; scaled by the predicted radii (which grow alike, here
    10 % smaller than what the camera measures, as the 0.10 m cue radius does) it does not."""
    radii = 10.0 * 1.03 ** np.arange(15)
    preds = 0.9 * radii
    state = SceneState()
    _walk_towards_the_camera(state, radii, preds)
    now = 0.9 * 10.0 * 1.03 ** 15                      # this frame's prediction
    assert abs(state.head_radius(now) - now / 0.9) < 1e-9
    assert state.head_radius() < 0.85 * now / 0.9      # the median of the last 15: 7 frames behind
    torso = torso_from_head(np.array([100.0, 60.0]), state.head_radius(now), np.array([100.0, 400.0]))
    np.testing.assert_allclose(torso, [100.0, 60.0 + TORSO_HEAD_RADII * now / 0.9])


def test_head_radius_without_a_usable_prediction_is_the_plain_median():
    state = SceneState()
    _walk_towards_the_camera(state, [10.0, 11.0, 12.0], [np.nan, np.inf, 0.0])   # none usable (a forged inf)
    assert state.head_radius(20.0) == state.head_radius() == 11.0
    assert state.head_radius(np.nan) == state.head_radius(np.inf) == 11.0
    _walk_towards_the_camera(state, [12.0], [6.0])
    assert state.head_radius(7.0) == 14.0             # only the radius measured with a prediction is scaled
