"""Regions of the change test (``perception.roi``): candidates from the last boxes, a change
mask grown band by band, and cues identical to the margin ROI's."""

from dataclasses import replace

import numpy as np
from perception_scenes import make_scene
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.geometry.rig import ring_rig
from mocap_rt.perception import roi as roi_module
from mocap_rt.perception.background import BackgroundModel, ChangeThresholds, change_mask
from mocap_rt.perception.pipeline import CameraPerceiver, PerceptionConfig
from mocap_rt.perception.roi import ChangeMask, roi_candidates

CAM = ring_rig()[0]


def test_roi_candidates_hand_computed():
    # box moved 5 px right and 2 px up since the last frame; widened by 5 px on the right
    got = roi_candidates((100, 50, 40, 100), (95, 52, 40, 100), (640, 480), 16, 0.05, 6)
    # margin ROI: 16 + 0.05 * 100 = 21 px around the box
    wide = (79, 29, 161, 171)
    # motion ROI: left/bottom did not move outwards (6 px); top moved up 2 (2 x 2 + 6 = 10 px);
    # right moved out 5 (2 x 5 + 6 = 16 px), clipped to the margin ROI
    assert got == [(94, 40, 156, 156), wide, (0, 0, 640, 480)]
    assert roi_candidates(None, None, (640, 480), 16, 0.05, 6) == [(0, 0, 640, 480)]
    # no previous box, or motion ROI off: the margin ROI first
    assert roi_candidates((100, 50, 40, 100), None, (640, 480), 16, 0.05, 6) == [wide, (0, 0, 640, 480)]
    assert roi_candidates((100, 50, 40, 100), (95, 52, 40, 100), (640, 480), 16, 0.05, 0) == [wide, (0, 0, 640, 480)]


@settings(max_examples=60, deadline=None)
@given(st.tuples(st.integers(0, 300), st.integers(0, 200), st.integers(1, 300), st.integers(1, 280)),
       st.tuples(st.integers(-40, 40), st.integers(-40, 40), st.integers(-40, 40), st.integers(-40, 40)),
       st.integers(0, 12))
def test_roi_candidates_are_nested_inside_the_image(box, motion, motion_px):
    W, H = 320, 240
    x, y, w, h = box
    w, h = min(w, W - x), min(h, H - y)
    prev = (x - motion[0], y - motion[1], max(1, w - motion[2]), max(1, h - motion[3]))
    rects = roi_candidates((x, y, w, h), prev, (W, H), 16, 0.05, motion_px)
    assert rects[-1] == (0, 0, W, H)
    for a, b in zip(rects, rects[1:]):
        assert b[0] <= a[0] and b[1] <= a[1] and b[2] >= a[2] and b[3] >= a[3] and a != b
    for x0, y0, x1, y1 in rects:
        assert 0 <= x0 <= x and 0 <= y0 <= y and x + w <= x1 <= W and y + h <= y1 <= H   # the box inside


def test_change_mask_grows_band_by_band_to_the_plain_change_test():
    rng = np.random.default_rng(3)
    model = BackgroundModel.from_frames(rng.integers(0, 256, (3, 60, 80, 3), dtype=np.uint8))
    img = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    th = ChangeThresholds()
    cm = ChangeMask((80, 60))
    cm.buf[:] = 77                                  # stale codes of an earlier frame
    cm.start()
    for rect in [(30, 20, 45, 31), (22, 20, 60, 44), (0, 0, 80, 60)]:
        x0, y0, x1, y1 = rect
        got = cm.extend(img, model, th, rect)
        np.testing.assert_array_equal(got, change_mask(img, model, (x0, y0, x1 - x0, y1 - y0), th))
    cm.start()
    cm.extend(img, model, th, (10, 10, 30, 30))
    try:
        cm.extend(img, model, th, (12, 10, 40, 40))
    except ValueError as e:
        assert "does not hold" in str(e)
    else:
        raise AssertionError("a region not holding the last one must be refused")


def test_motion_roi_gives_the_margin_rois_cues_and_falls_back(monkeypatch):
    """A person walking and jumping sideways (steps of 2-40 px): cues, boxes and silhouettes
    are those of the margin ROI alone; the jumps leave the motion ROI (a second search)."""
    searches = []
    extend = ChangeMask.extend

    def counting(self, *a):
        searches.append((self, self.done is None))
        return extend(self, *a)

    monkeypatch.setattr(roi_module.ChangeMask, "extend", counting)
    xs = np.cumsum([0, 2, 2, 3, 2, 40, 2, 2, -3, -2, -30, 2, 2, 2, 25, 2, 2])
    scenes = [make_scene(cx=220.0 + float(x), hand_l=(315 + x, 200 - f), hand_r=(125 + x, 200 + f))
              for f, x in enumerate(xs)]
    motion = CameraPerceiver(CAM, scenes[0].background)
    margin = CameraPerceiver(CAM, scenes[0].background, replace(PerceptionConfig(), roi_motion_px=0))
    for f, sc in enumerate(scenes):
        a, b = motion.process(sc.image, f), margin.process(sc.image, f)
        for k in ("xy", "cov", "area", "confidence"):
            np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=f"frame {f} {k}")
        assert a.bbox == b.bbox
        np.testing.assert_array_equal(a.silhouette.mask, b.silhouette.mask)
    mine = [first for cm, first in searches if cm is motion._change]
    assert sum(mine) == len(scenes)
    more = len(mine) - len(scenes)
    assert more >= 3                       # the jumps: a second search
    assert more <= len(scenes) // 2        # most frames: one search
