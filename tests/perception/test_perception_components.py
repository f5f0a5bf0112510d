"""The largest 8-connected component with its holes filled, from pixel runs (``components.py``),
against scipy.ndimage (labels with the 3 x 3 structure, holes with its default 4-connected
background) and against the OpenCV contour route it replaced."""

import cv2
import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy import ndimage

from mocap_rt.perception.components import clear_large_holes, largest_component_box


def _reference(mask, min_area):
    """scipy: of the three components with the most pixels (ties: first in raster order, scipy's
    label order), the one with the largest filled area (ties: the earlier of the three)."""
    labels, n = ndimage.label(mask > 0, structure=np.ones((3, 3)))
    if n == 0:
        return None
    sizes = np.bincount(labels.ravel())[1:]
    top = np.argsort(-sizes, kind="stable")[:3] + 1
    fills = [ndimage.binary_fill_holes(labels == k) for k in top]
    filled = fills[int(np.argmax([f.sum() for f in fills]))]
    if filled.sum() < max(1, min_area):
        return None
    ys, xs = np.nonzero(filled)
    x0, y0 = xs.min(), ys.min()
    box = (int(x0), int(y0), int(xs.max() - x0 + 1), int(ys.max() - y0 + 1))
    return filled[y0:y0 + box[3], x0:x0 + box[2]], box


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.floats(0.05, 0.9), st.integers(0, 2**31 - 1),
       st.sampled_from([0, 1, 5, 30]))
@example(3, 3, 0.5, 0, 0)
@example(1, 17, 0.5, 1, 0)
def test_matches_scipy_on_random_masks(h, w, density, seed, min_area):
    rng = np.random.default_rng(seed)
    mask = (rng.random((h, w)) < density).astype(np.uint8) * rng.choice([1, 128, 255])
    got, box = largest_component_box(mask, min_area)
    ref = _reference(mask, min_area)
    if ref is None:
        assert box == (0, 0, 0, 0) and got.size == 0
        return
    assert box == ref[1]
    np.testing.assert_array_equal(got > 0, ref[0])
    assert set(np.unique(got)) <= {0, 255}


def test_hand_made_shapes():
    m = np.zeros((12, 14), np.uint8)
    m[1:10, 1:10] = 255
    m[3:7, 3:7] = 0            # a hole ...
    m[4, 4] = 255              # ... with a speck in it: both filled
    m[2:8, 8] = 0              # a notch open to the right edge of the square's column 9: not a hole
    m[5, 9] = 0
    m[11, 12:14] = 255         # a separate small component
    got, box = largest_component_box(m)
    assert box == (1, 1, 9, 9)
    np.testing.assert_array_equal(got > 0, _reference(m, 0)[0])
    assert got[2:6, 2:6].all()                      # hole and speck filled
    assert not got[1:7, 7].any() and not got[4, 8]  # the notch and the gap on the outline stay open
    # a hole reached only diagonally (8-connected foreground, 4-connected background): still a hole
    d = np.full((5, 5), 255, np.uint8)
    d[2, 2] = 0
    d[1, 1] = 0
    got, box = largest_component_box(d)
    assert box == (0, 0, 5, 5) and got.all()
    assert largest_component_box(np.zeros((4, 6), np.uint8))[1] == (0, 0, 0, 0)
    assert largest_component_box(d, min_area_px=25)[1] == (0, 0, 5, 5)     # 25 pixels filled
    assert largest_component_box(d, min_area_px=26)[1] == (0, 0, 0, 0)


def test_a_ring_with_fewer_pixels_but_more_filled_area_wins():
    """The person split in two (upper body a ring of clothes around an unchanged patch): the
    part enclosing more area is kept, as the contour route ranked outlines by enclosed area."""
    m = np.zeros((40, 60), np.uint8)
    cv2.rectangle(m, (2, 2), (21, 21), 255, 1)          # ring: 76 pixels, 400 filled
    m[25:35, 30:41] = 255                                # solid: 110 pixels
    got, box = largest_component_box(m)
    assert box == (2, 2, 20, 20) and got.all()


def test_same_as_opencv_contours_on_person_like_masks():
    """A filled body with holes and noise specks, as the change mask gives: the same filled
    component as findContours + drawContours FILLED of the largest outer boundary."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        m = (rng.random((200, 120)) < 0.02).astype(np.uint8) * 128                # specks
        cv2.ellipse(m, (60, 100), (int(rng.integers(20, 40)), 80), float(rng.uniform(0, 30)), 0, 360, 255, -1)
        cv2.circle(m, (60 + int(rng.integers(-5, 5)), 90), 6, 0, -1)                # a hole
        m[rng.random(m.shape) < 0.01] = 0                                            # pinholes
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        big = max(contours, key=cv2.contourArea)
        want = np.zeros_like(m)
        cv2.drawContours(want, [big], 0, 255, thickness=cv2.FILLED)
        x, y, w, h = cv2.boundingRect(big)
        got, box = largest_component_box(m)
        assert box == (x, y, w, h)
        np.testing.assert_array_equal(got, want[y:y + h, x:x + w])


@settings(max_examples=200, deadline=None)
@given(st.integers(4, 40), st.integers(4, 40), st.floats(0.05, 0.6), st.integers(0, 2**31 - 1),
       st.integers(1, 4), st.sampled_from([0, 1, 3, 8]))
@example(26, 38, 0.25, 1021, 3, 1)   # a point 0.38 px from a pixel centre, reach 0.29, inside the run's span
def test_parts_within_reach_of_kept_points_join_the_largest_as_scipy_finds_them(h, w, density, seed, n_pts, part_min):
    """Every other component of at least ``part_min_area`` pixels (0: none) with a pixel within a
    point's reach is kept, each filled on its own, in the union of the boxes: against scipy's labels,
    fills and distance from each point to each pixel."""
    rng = np.random.default_rng(seed)
    mask = (rng.random((h, w)) < density).astype(np.uint8) * 255
    pts = np.column_stack([rng.uniform(-2, w + 2, n_pts), rng.uniform(-2, h + 2, n_pts)])
    pts[rng.random(n_pts) < 0.2] = np.nan
    reach = rng.uniform(0, 6, n_pts)
    got, box = largest_component_box(mask, 0, np.column_stack([pts + 5.0, reach]), (5, 5), part_min)
    ref = _reference(mask, 0)
    if ref is None:
        assert box == (0, 0, 0, 0)
        return
    want = np.zeros((h, w), bool)
    x, y, bw, bh = ref[1]
    want[y:y + bh, x:x + bw] = ref[0]
    labels, n = ndimage.label(mask > 0, structure=np.ones((3, 3)))
    biggest = np.bincount(labels[want & (mask > 0)]).argmax()
    ys, xs = np.mgrid[:h, :w]
    for k in range(1, n + 1):
        part = labels == k
        if k == biggest or part_min == 0 or part.sum() < part_min:
            continue
        d2 = (xs[None] - pts[:, 0, None, None]) ** 2 + (ys[None] - pts[:, 1, None, None]) ** 2
        if (part[None] & (d2 <= (reach ** 2)[:, None, None])).any():
            want |= ndimage.binary_fill_holes(part)
    ys, xs = np.nonzero(want)
    assert box == (xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1)
    np.testing.assert_array_equal(got > 0, want[box[1]:box[1] + box[3], box[0]:box[0] + box[2]])


def test_a_shoe_cut_off_by_a_camouflaged_leg_is_kept_where_a_foot_is_expected():
    """The person's body, and below it a shoe the change test separated from it (the shin in
    front of a background of its colour) and a speck: with the foot expected at the shoe the
    shoe joins the silhouette, the speck does not; expected elsewhere, or too small, it stays out."""
    m = np.zeros((120, 80), np.uint8)
    cv2.ellipse(m, (40, 40), (15, 35), 0, 0, 360, 255, -1)          # body, rows 5-75
    m[100:106, 30:50] = 255                                         # shoe, 120 pixels, 25 rows below
    m[110, 5] = 255                                                 # speck
    body, box = largest_component_box(m, 0)
    assert box[3] < 75
    foot = np.array([[41.0, 103.0, 8.0], [5.0, 110.0, 8.0]])
    got, box = largest_component_box(m, 0, foot, (0, 0), 40)
    assert box == (25, 5, 31, 101)
    assert got[100 - 5:106 - 5, 30 - 25:50 - 25].all() and (got[:body.shape[0]] == body).all()
    assert largest_component_box(m, 0, foot + [0, -20, 0], (0, 0), 40)[1][3] < 75        # out of reach
    assert largest_component_box(m, 0, foot, (0, 0), 121)[1][3] < 75                     # too small
    assert largest_component_box(m[20:], 0, foot, (0, 20), 40)[1] == (25, 0, 31, 86)       # image px, mask offset


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([1, 2, 3]), st.integers(1, 40))
def test_clear_large_holes_matches_opencv_components(seed, step, min_area):
    """The holes (member set, change 0) sampled every ``step``-th pixel, their 4-connected groups
    of at least ``min_area`` pixels cleared from the sampled silhouette: as OpenCV labels them."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 40, size=2)
    member = (rng.random((h, w)) < 0.8).astype(np.uint8) * 255
    change = np.where(rng.random((h, w)) < 0.6, rng.choice([128, 255], size=(h, w)), 0).astype(np.uint8)
    sil = np.ascontiguousarray(((member > 0) & (rng.random((h, w)) < 0.9)).astype(np.uint8)[::step, ::step] * 255)
    holes = ((member[::step, ::step] != 0) & (change[::step, ::step] == 0)).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(holes, connectivity=4)
    want = sil.copy()
    want[np.isin(labels, np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= min_area)) & (holes > 0)] = 0
    before = sil.copy()
    got = clear_large_holes(sil, member, change, step, float(min_area))
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(sil, before)                # the input is left as it was
