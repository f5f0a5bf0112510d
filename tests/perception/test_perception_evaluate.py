"""2D cue scoring for the hard-case suite (perception/evaluate.py), hand-computed cases."""

import numpy as np
import pytest

from mocap_rt.perception.evaluate import (along_limb_errors, cue_track_stats, loss_episodes, pair_best_errors,
                                         truth_visible)


def test_pair_best_errors_takes_the_better_labelling_per_frame():
    t = np.zeros((1, 2, 6, 2))
    t[0, :, 1] = (100, 100)      # hand_l
    t[0, :, 2] = (200, 100)      # hand_r
    xy = t.copy()
    xy[0, 0, 1], xy[0, 0, 2] = (203, 104), (100, 100)     # frame 0: swapped, hand_l 5 px off hand_r
    xy[0, 1, 1] = (103, 104)                              # frame 1: straight, 5 px off
    xy[0, 1, 2] = (np.nan, np.nan)                        # hand_r lost: straight scoring
    e = pair_best_errors(xy, t)
    assert e[0, 0, 1] == pytest.approx(5.0) and e[0, 0, 2] == pytest.approx(0.0)
    assert e[0, 1, 1] == pytest.approx(5.0) and np.isnan(e[0, 1, 2])
    assert (e[0, :, [0, 3, 4, 5]] == 0).all()


def test_along_limb_errors_split_each_error_along_and_across_its_limb():
    """The head 2 px beyond its truth, away from the neck below it, and 1 px to the side; the
    hands found exchanged, each 3 px short of its truth towards its wrist: the split follows
    the matched hand's own wrist."""
    t = np.full((1, 1, 6, 2), np.nan)
    j = np.full((1, 1, 6, 2), np.nan)
    t[0, 0, 0], j[0, 0, 0] = (50, 50), (50, 80)            # head above the neck (y down)
    t[0, 0, 1], j[0, 0, 1] = (100, 100), (90, 100)         # hand_l, its wrist to the left
    t[0, 0, 2], j[0, 0, 2] = (200, 100), (200, 110)        # hand_r, its wrist below
    xy = t.copy()
    xy[0, 0, 0] = (51, 48)
    xy[0, 0, 1], xy[0, 0, 2] = (200, 103), (97, 100)       # exchanged, each 3 px towards its wrist
    e = along_limb_errors(xy, t, j)
    np.testing.assert_allclose(e[0, 0, 0], (2.0, 1.0))
    np.testing.assert_allclose(e[0, 0, 1], (-3.0, 0.0))
    np.testing.assert_allclose(e[0, 0, 2], (-3.0, 0.0))
    assert np.isnan(e[0, 0, 3:]).all()                     # no truth, no joint


def test_loss_episodes_neutral_frames_and_reacquisition():
    lost = np.array([0, 1, 1, 0, 0, 0, 1, 0, 0], bool)
    ok = np.array([1, 0, 0, 0, 1, 1, 0, 0, 0], bool)      # frame 3 not visible (neutral)
    assert loss_episodes(lost, ok) == [(3, True, 2), (3, False, 1)]
    assert loss_episodes(np.zeros(4, bool), np.ones(4, bool)) == []


def test_cue_track_stats_hand_computed():
    C, F, fps = 1, 10, 10.0
    t = np.tile(np.arange(6, dtype=float)[None, None, :, None] * 50 + 50, (C, F, 1, 2))
    xy = t + [3.0, 4.0]                                   # 5 px everywhere
    xy[0, 2:5, 0] = np.nan                                # head missing for 3 frames, then back
    xy[0, 7:, 5] += 100                                   # torso 100 px off from frame 7 to the end
    vis = np.ones((C, F, 6), bool)
    s = cue_track_stats(xy, t, vis, fps, lost_px=20.0)
    h = s["head"]
    assert (h.median_px, h.lost_frames, h.visible_frames, h.episodes) == (pytest.approx(5.0), 3, 10, 1)
    assert h.longest_loss_s == pytest.approx(0.3) and h.reacq_median_s == pytest.approx(0.3)
    tor = s["torso"]
    assert tor.lost_frames == 3 and tor.longest_loss_s == pytest.approx(0.3) and np.isnan(tor.reacq_max_s)
    assert tor.p95_px > 100 and s["hand_l"].lost_frames == 0 and s["hand_l"].longest_loss_s == 0.0
    assert h.longest_seen_loss_s == pytest.approx(0.3)


def test_a_loss_counts_hidden_frames_but_the_seen_loss_does_not():
    """A hand lost for one frame as it goes behind the head, hidden for 6 frames, found in the
    first frame it shows again: an episode of 7 frames, of which 1 was seen."""
    C, F, fps = 1, 10, 10.0
    t = np.full((C, F, 6, 2), 100.0)
    xy = t.copy()
    xy[0, 2, 1] = np.nan
    vis = np.ones((C, F, 6), bool)
    vis[0, 3:9, 1] = False
    hand = cue_track_stats(xy, t, vis, fps, lost_px=20.0)["hand_l"]
    assert hand.longest_loss_s == pytest.approx(0.7) and hand.longest_seen_loss_s == pytest.approx(0.1)


def test_truth_visible_needs_visibility_and_image_bounds():
    truth = {"cues_2d": np.array([[[[10.0, 10], [700, 10], [10, 10], [np.nan, 1], [5, 5], [639, 479]]]]),
             "cue_visibility": np.array([[[1.0, 1, 0.4, 1, 0.5, 1]]])}
    np.testing.assert_array_equal(truth_visible(truth, 640, 480)[0, 0], [1, 0, 0, 0, 1, 1])
