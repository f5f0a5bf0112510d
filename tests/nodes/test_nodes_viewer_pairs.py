"""The viewer's same-frame pairing of camera images and cues, its inbox, its JPEG size reader."""

import threading

import cv2
import numpy as np

from mocap_rt.cues import N_CUES, CameraCues
from nodes.messages import Cues, Preview
from nodes.viewer import Inbox, SameFrame, _jpeg_size


def _cues(cam: str, frame: int) -> Cues:
    c = CameraCues(cam, frame, np.full((N_CUES, 2), 10.0 + frame), np.tile(np.eye(2), (N_CUES, 1, 1)),
                   np.full(N_CUES, 50.0), np.ones(N_CUES))
    return Cues("rig", c, frame, frame, 1.0)


def _preview(cam: str, frame: int) -> Preview:
    return Preview("rig", cam, frame, b"\xff\xd8jpeg")


def test_each_image_is_paired_with_the_cues_of_its_own_frame():
    pairs = SameFrame(keep=8)
    # a camera that never sent an image: its cues are drawn at once (nothing to disagree with)
    out = pairs.add_cues(_cues("cam_2", 0))
    assert out[0].cues.frame == 0 and out[1] is None
    # images every 3 frames; cues of every frame, before or after the image of that frame
    got = []
    for f in range(12):
        if f % 3 == 0:
            got.append(pairs.add_preview(_preview("cam_1", f)))
        got.append(pairs.add_cues(_cues("cam_1", f)))
    done = [g for g in got if g is not None]
    assert [(c.cues.frame, p.frame) for c, p in done] == [(0, 0), (3, 3), (6, 6), (9, 9)]
    # the image comes after its cues (the worker sends it later): still paired with them
    assert pairs.add_cues(_cues("cam_1", 12)) is None
    c, p = pairs.add_preview(_preview("cam_1", 12))
    assert c.cues.frame == p.frame == 12
    # an image whose cues are older than ``keep`` frames finds nothing, and is not drawn
    assert pairs.add_preview(_preview("cam_1", 1)) is None
    assert pairs.add_cues(_cues("cam_2", 5))[1] is None           # cam_2 still has no images


def test_inbox_keeps_the_newest_items_and_counts_what_it_dropped():
    box = Inbox(maxlen=50)
    dropped = []

    def put(base):
        dropped.append(sum(box.put((base, i)) for i in range(1000)))
    threads = [threading.Thread(target=put, args=(b,)) for b in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    items = []
    while (item := box.get(timeout_s=0.0)) is not None:
        items.append(item)
    assert len(items) == 50 and sum(dropped) == 4000 - 50
    for b in range(4):             # per producer, the kept items are in order
        mine = [i for base, i in items if base == b]
        assert mine == sorted(mine)
    assert box.get(timeout_s=0.05) is None


def test_jpeg_size_matches_opencv():
    for w, h in ((320, 240), (640, 480), (17, 5)):
        ok, jpg = cv2.imencode(".jpg", np.zeros((h, w, 3), np.uint8))
        assert ok and _jpeg_size(jpg.tobytes()) == f"{w}x{h}"
    assert _jpeg_size(b"not a jpeg") == ""
