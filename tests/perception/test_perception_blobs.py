"""Blob kernels and tracker (seed digest A.2, A.4): labelling, deformable ellipse, identities."""

import itertools

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.perception.blob_kernels import (REFINE_PARAMS, SHAPE_PIXEL_VAR, deform_ellipse, label_moments,
                                             params_record)
from mocap_rt.perception.region_kernels import acquire_candidates, acquire_regions, colour_regions, snap_window
from mocap_rt.perception.blobs import (SNAP_MAX_REGIONS, SNAP_NEAR_GATES, SNAP_WINDOW_GATES, BlobParams,
                                       BlobTracker)
from mocap_rt.perception.track_kernels import snap_centres

_NO_SITES = np.full((1, 2), np.nan)


def _kp(n_pts: int, search_frac: float, mirror_iters: int) -> np.ndarray:
    """``deform_ellipse``'s settings: scale 2, +-3 px search at least, window half length 2 px."""
    return params_record(REFINE_PARAMS, BlobParams(), ellipse_scale=2.0, n_contour_pts=n_pts, search_frac=search_frac,
                         search_min_px=3.0, window_half_px=2, mirror_iters=mirror_iters)


def _ellipse_map(shape, centre, axes, angle):
    """Skin map (float32 0/1) of an anti-aliased-free drawn ellipse + its exact area centroid."""
    m = np.zeros(shape, np.uint8)
    s = 16
    cv2.ellipse(m, (round(centre[0] * s), round(centre[1] * s)), (round(axes[0] * s), round(axes[1] * s)),
                angle, 0, 360, 1, -1, cv2.LINE_8, 4)
    return m.astype(np.float32)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_label_moments_matches_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    skin = (rng.random((40, 50)) < 0.3).astype(np.float32)
    centers = rng.uniform(0, 50, (3, 2))
    centers[rng.integers(0, 3)] = np.nan
    gate = rng.uniform(5, 30, 3)
    size = rng.uniform(3, 20, 3)
    sums = np.zeros((3, 6))
    label_moments(skin, 2, 3, 45, 38, centers, gate * gate, 1.0 / size ** 2, sums, np.zeros((0, 2, 2)))
    ys, xs = np.nonzero(skin[3:38, 2:45])
    xs, ys = xs + 2.0, ys + 3.0
    d = (xs[:, None] - centers[None, :, 0]) ** 2 + (ys[:, None] - centers[None, :, 1]) ** 2
    d = np.where(np.isfinite(d) & (d < gate * gate), d / size ** 2, np.inf)         # nearest in blob sizes
    lab = np.where(np.isfinite(d.min(axis=1)), d.argmin(axis=1), -1)
    for k in range(3):
        sel = lab == k
        x, y = xs[sel], ys[sel]
        ref = [sel.sum(), x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()]
        np.testing.assert_allclose(sums[k], ref)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_label_moments_by_shape_matches_numpy_reference(seed):
    """With a shape for every tracked blob, each pixel in a gate goes to the blob of least
    Mahalanobis distance + log det of its covariance (the Gaussian discriminant)."""
    rng = np.random.default_rng(seed)
    skin = (rng.random((40, 50)) < 0.3).astype(np.float32)
    centers = rng.uniform(0, 50, (3, 2))
    gate = rng.uniform(5, 30, 3)
    A = rng.normal(size=(3, 2, 2)) * rng.uniform(1, 6, (3, 1, 1))
    cov = A @ np.transpose(A, (0, 2, 1))
    sums = np.zeros((3, 6))
    label_moments(skin, 2, 3, 45, 38, centers, gate * gate, np.ones(3), sums, cov)
    ys, xs = np.nonzero(skin[3:38, 2:45])
    xs, ys = xs + 2.0, ys + 3.0
    dx, dy = xs[:, None] - centers[None, :, 0], ys[:, None] - centers[None, :, 1]
    wide = cov + SHAPE_PIXEL_VAR * np.eye(2)
    inv = np.linalg.inv(wide)
    m = inv[:, 0, 0] * dx * dx + 2 * inv[:, 0, 1] * dx * dy + inv[:, 1, 1] * dy * dy + np.log(np.linalg.det(wide))
    m = np.where(dx * dx + dy * dy < gate * gate, m, np.inf)
    lab = np.where(np.isfinite(m.min(axis=1)), m.argmin(axis=1), -1)
    for k in range(3):
        sel = lab == k
        x, y = xs[sel], ys[sel]
        ref = [sel.sum(), x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()]
        np.testing.assert_allclose(sums[k], ref, rtol=1e-9)


@pytest.mark.parametrize("missing", [np.nan, 0.0])
def test_labelling_falls_back_to_sizes_when_a_tracked_blob_has_no_shape(missing):
    """A blob never apart (zero covariance) or lost (NaN): every blob is labelled by size."""
    rng = np.random.default_rng(5)
    skin = (rng.random((40, 50)) < 0.3).astype(np.float32)
    centers, gate2, size = rng.uniform(0, 50, (3, 2)), np.full(3, 400.0), np.array([1.0, 2.0, 1.0])
    cov = np.array([[[30.0, 5.0], [5.0, 8.0]]] * 3)
    cov[1] = missing
    by_size, mixed = np.zeros((3, 6)), np.zeros((3, 6))
    label_moments(skin, 0, 0, 50, 40, centers, gate2, 1.0 / size ** 2, by_size, np.zeros((0, 2, 2)))
    label_moments(skin, 0, 0, 50, 40, centers, gate2, 1.0 / size ** 2, mixed, cov)
    np.testing.assert_array_equal(mixed, by_size)


def test_two_touching_shoes_are_split_along_their_length_by_shape():
    """Two elongated blobs side by side, offset along their length so that they touch: the
    nearest-centre labelling cuts across both, the shapes' (``label_by_shape``) follows the
    seam between them. Truth: the two drawn ellipses."""
    a = _ellipse_map((60, 90), (38.0, 26.0), (18.0, 6.0), 0.0) > 0
    b = _ellipse_map((60, 90), (52.0, 37.0), (18.0, 6.0), 0.0) > 0
    skin = (a | b).astype(np.float32)
    assert cv2.connectedComponents(skin.astype(np.uint8))[0] == 2      # one region (+ background)
    own = np.stack([a & ~b, b & ~a])                                  # pixels only one shoe covers
    centers = np.array([[38.0, 26.0], [52.0, 37.0]])
    cov = np.array([[[81.0, 0.0], [0.0, 9.0]]] * 2)                  # (18/2)^2, (6/2)^2: the shoes' shapes
    correct = {}
    for name, shape in (("nearest", np.zeros((0, 2, 2))), ("shape", cov)):
        lab = np.full(skin.shape, -1)
        for y, x in zip(*np.nonzero(skin)):
            sums = np.zeros((2, 6))
            one = np.zeros_like(skin)
            one[y, x] = 1.0
            label_moments(one, x, y, x + 1, y + 1, centers, np.full(2, 1e6), np.ones(2), sums, shape)
            lab[y, x] = int(np.argmax(sums[:, 0]))
        correct[name] = sum(int(np.sum(own[k] & (lab == k))) for k in range(2)) / int(own.sum())
    assert correct["shape"] > 0.97
    assert correct["nearest"] < 0.9


@pytest.mark.parametrize("centre,axes,angle", [((40.3, 35.7), (12.0, 7.5), 30.0), ((50.0, 50.0), (20.0, 20.0), 0.0),
                                                ((33.6, 41.2), (6.0, 4.0), -70.0)])
def test_deformable_ellipse_recovers_region_from_a_wrong_initial_ellipse(centre, axes, angle):
    skin = _ellipse_map((90, 100), centre, axes, angle)
    true_area = np.pi * axes[0] * axes[1]
    ys, xs = np.nonzero(skin)
    pix_centroid = np.array([xs.mean(), ys.mean()])
    # initial ellipse: offset by 2 px and 30 % too large, wrong orientation
    mean = np.array(centre) + (1.5, -1.5)
    r = 0.5 * np.mean(axes) * 1.3
    cov = np.array([[r * r, 0.2 * r * r], [0.2 * r * r, r * r]])
    contour = np.zeros((24, 2))
    cx, cy, area = deform_ellipse(skin, np.zeros((1, 1), np.uint8), mean, cov, _kp(24, 0.5, 0), contour, _NO_SITES, 0)
    assert np.hypot(cx - pix_centroid[0], cy - pix_centroid[1]) < 0.35
    assert area == pytest.approx(skin.sum(), rel=0.08)     # the drawn (pixel) region
    assert area == pytest.approx(true_area, rel=0.15)
    # every contour point lies on the true boundary (within ~1 px)
    a, b = axes
    t = np.deg2rad(angle)
    d = contour - np.array(centre)
    u = d[:, 0] * np.cos(t) + d[:, 1] * np.sin(t)
    v = -d[:, 0] * np.sin(t) + d[:, 1] * np.cos(t)
    rho = np.sqrt((u / a) ** 2 + (v / b) ** 2)
    assert np.all(np.abs(rho - 1) * min(a, b) < 1.2)


def _hands_frame(hl, hr, head=(100, 30), size=(200, 160)):
    skin = np.zeros(size[::-1], np.float32)
    for c, r in ((head, 12), (hl, 6), (hr, 6)):
        cv2.circle(skin, (int(round(c[0])), int(round(c[1]))), r, 1.0, -1)
    return skin


def test_tracker_writes_into_the_given_arrays():
    """``step(..., out=...)`` writes the frame into the caller's arrays (the pipeline passes views
    of a camera's cue arrays) and returns them: the same figures as a step without them."""
    from mocap_rt.perception.blobs import BlobFrame

    a, b = BlobTracker(("head", "hand_l", "hand_r")), BlobTracker(("head", "hand_l", "hand_r"))
    xy, cov, area, conf = np.full((6, 2), -1.0), np.full((6, 2, 2), -1.0), np.full(6, -1.0), np.full(6, -1.0)
    hl, hr = np.array([150.0, 90.0]), np.array([50.0, 90.0])
    for f in range(4):
        skin = _hands_frame(hl + (2 * f, f), hr)
        plain = a.step(skin, (5, 7), (0, 0, 200, 160), (100.0, 10.0))
        out = BlobFrame(xy[:3], cov[:3], area[:3], conf[:3])
        assert b.step(skin, (5, 7), (0, 0, 200, 160), (100.0, 10.0), out=out) is out
        for got, want in ((xy[:3], plain.xy), (cov[:3], plain.cov), (area[:3], plain.area), (conf[:3], plain.confidence)):
            np.testing.assert_array_equal(got, want)
    assert (xy[3:] == -1).all() and (conf[3:] == -1).all()         # rows outside the views untouched
    b.step(skin, (5, 7), (0, 0, 0, 0), None, out=out)               # no person: the rows cleared
    assert np.isnan(xy[:3]).all() and (conf[:3] == 0).all()


def test_tracker_acquires_head_and_hands_then_follows_them():
    tr = BlobTracker(("head", "hand_l", "hand_r"), BlobParams())
    hl, hr = np.array([150.0, 90.0]), np.array([50.0, 90.0])
    for f in range(10):
        hl = hl + (2, 1)
        hr = hr + (-1, 2)
        out = tr.step(_hands_frame(hl, hr), (0, 0), (0, 0, 200, 160), (100.0, 10.0))
        np.testing.assert_allclose(out.xy[0], (100, 30), atol=0.3)
        # cold start: the person faces the camera -> their left hand is on the image right
        np.testing.assert_allclose(out.xy[1], hl, atol=0.5)
        np.testing.assert_allclose(out.xy[2], hr, atol=0.5)
    assert np.all(out.confidence == 1.0)
    # ROI offset is applied
    out = BlobTracker(("head",)).step(_hands_frame(hl, hr), (300, 200), (0, 0, 200, 160), (100.0, 10.0))
    np.testing.assert_allclose(out.xy[0], (400, 230), atol=0.3)


def test_identities_kept_through_a_crossing_with_predictions():
    """Hands cross in front of each other; the (3D) predictor supplies where each will be."""
    tr = BlobTracker(("head", "hand_l", "hand_r"))
    swaps = 0
    for f in range(40):
        t = f / 39.0
        hl = np.array([150 - 100 * t, 100 + 10 * np.sin(np.pi * t)])
        hr = np.array([50 + 100 * t, 100 - 10 * np.sin(np.pi * t)])
        pred = np.array([[100, 30], hl, hr], float)
        visible = np.ones(3, bool)
        if np.hypot(*(hl - hr)) < 12:        # overlapping: the farther hand is occluded (A.4)
            visible[2] = False
        out = tr.step(_hands_frame(hl, hr), (0, 0), (0, 0, 200, 160), (100.0, 10.0), pred, visible, np.full(3, 6.0))
        if np.isfinite(out.xy[1:]).all():
            d_same = np.hypot(*(out.xy[1] - hl)) + np.hypot(*(out.xy[2] - hr))
            d_swap = np.hypot(*(out.xy[1] - hr)) + np.hypot(*(out.xy[2] - hl))
            swaps += d_swap < d_same
    assert swaps == 0
    np.testing.assert_allclose(out.xy[1], hl, atol=0.5)
    np.testing.assert_allclose(out.xy[2], hr, atol=0.5)


def test_occluded_blob_keeps_initial_ellipse_and_lost_blob_is_reacquired():
    tr = BlobTracker(("head", "hand_l", "hand_r"))
    hl, hr = (150.0, 90.0), (50.0, 90.0)
    skin = _hands_frame(hl, hr)
    # predicted occluded: the cue is the mean of the initially labelled pixels (no deformation)
    pred = np.array([[100, 30], hl, hr], float)
    out = tr.step(skin, (0, 0), (0, 0, 200, 160), None, pred, np.array([True, False, True]), np.full(3, 6.0))
    contours = tr.last_contours()
    assert contours[1] is None and contours[2] is not None
    ys, xs = np.nonzero(skin[80:100, 140:160])
    np.testing.assert_allclose(out.xy[1], (xs.mean() + 140, ys.mean() + 80), atol=1e-9)
    assert out.confidence[1] == pytest.approx(0.5)
    # hand_r disappears (behind the body) for a while: lost, then re-acquired where it reappears
    for _ in range(6):
        out = tr.step(_hands_frame(hl, (-50, -50)), (0, 0), (0, 0, 200, 160), (100.0, 10.0))
        assert np.isnan(out.xy[2]).all() and out.confidence[2] == 0
    out = tr.step(_hands_frame(hl, (40, 120)), (0, 0), (0, 0, 200, 160), (100.0, 10.0))
    np.testing.assert_allclose(out.xy[2], (40, 120), atol=0.5)
    np.testing.assert_allclose(out.xy[1], hl, atol=0.5)


def test_occlusion_completion_moves_a_partly_hidden_blob_towards_its_true_centre():
    """A 'hand' (ellipse) whose wrist end is hidden under a 'sleeve' (silhouette, not skin)."""
    shape = (120, 120)
    centre, axes = (60.0, 60.0), (24.0, 10.0)
    full = _ellipse_map(shape, centre, axes, 0.0)
    sleeve = np.zeros(shape, np.uint8)
    cv2.rectangle(sleeve, (20, 45), (45, 75), 1, -1)            # hides x <= 45 (left 9 px of the blob)
    skin = full * (1 - sleeve)
    sil = ((full > 0) | (sleeve > 0)).astype(np.uint8)
    ys, xs = np.nonzero(skin)
    mean = np.array([xs.mean(), ys.mean()])
    cov = np.cov(np.stack([xs, ys]).astype(float))
    contour = np.zeros((32, 2))
    plain = deform_ellipse(skin, sil, mean, cov, _kp(32, 0.5, 0), contour, _NO_SITES, 0)
    completed = deform_ellipse(skin, sil, mean, cov, _kp(32, 0.5, 20), contour, _NO_SITES, 0)
    err_plain = np.hypot(plain[0] - centre[0], plain[1] - centre[1])
    err_completed = np.hypot(completed[0] - centre[0], completed[1] - centre[1])
    assert err_plain > 2.0                      # the visible part's centre is shifted right
    assert err_completed < 0.5 * err_plain
    assert abs(completed[1] - centre[1]) < 0.3  # and not moved across the axis
    # without a silhouette around it (no contact) completion changes nothing
    again = deform_ellipse(skin, (skin > 0).astype(np.uint8), mean, cov, _kp(32, 0.5, 20), contour,
                           _NO_SITES, 0)
    assert again[0] == pytest.approx(plain[0], abs=1e-9)


def test_touching_blobs_of_one_colour_do_not_merge():
    """Two shoes side by side: each blob's boundary search ignores the other's pixels."""
    a = _ellipse_map((80, 120), (45.0, 40.0), (16.0, 8.0), 0.0)
    b = _ellipse_map((80, 120), (75.0, 42.0), (16.0, 8.0), 0.0)      # touches a
    skin = np.maximum(a, b)
    sites = np.array([[45.0, 40.0], [75.0, 42.0]])
    contour = np.zeros((32, 2))
    mean = np.array([46.0, 40.5])
    cov = np.array([[64.0, 0.0], [0.0, 16.0]])
    ys, xs = np.nonzero(a)
    cx, cy, _ = deform_ellipse(skin, np.zeros((1, 1), np.uint8), mean, cov, _kp(32, 0.5, 0), contour, sites, 0)
    assert np.hypot(cx - xs.mean(), cy - ys.mean()) < 0.6
    merged = deform_ellipse(skin, np.zeros((1, 1), np.uint8), mean, cov, _kp(32, 0.5, 0), contour, _NO_SITES, 0)
    assert merged[0] > cx + 0.5            # without the assignment the search leaks into b


def _feet_frame(fl, fr, size=(200, 160), r=7):
    shoe = np.zeros(size[::-1], np.float32)
    for c in (fl, fr):
        if c is not None:
            cv2.circle(shoe, (int(round(c[0])), int(round(c[1]))), r, 1.0, -1)
    return shoe


@pytest.mark.parametrize("snap", [True, False])
def test_lagging_predictions_label_each_blob_from_its_own_region(snap):
    """A swinging foot moves faster than its prediction: the prediction lies between the two
    shoes, nearer the standing one's far side. Labelled by proximity alone, the swing shoe's
    pixels split between both feet; with the regions assigned as wholes, each cue is its shoe."""
    stand, swing = np.array([100.0, 100.0]), np.array([80.0, 96.0])
    pred = np.array([[103.0, 100.0], [96.0, 99.0]])         # foot_l = standing, foot_r lags 16 px
    tr = BlobTracker(("foot_l", "foot_r"), BlobParams(snap_to_regions=snap))
    out = tr.step(_feet_frame(stand, swing), (0, 0), (0, 0, 200, 160), None, pred, np.ones(2, bool),
                  np.full(2, 10.0))
    err = np.hypot(*(out.xy - [stand, swing]).T)
    if snap:
        assert err.max() < 0.5
    else:                                                   # the old behaviour this guards against
        assert err.max() > 2.0


def test_cold_start_acquires_a_lone_shoe_by_its_side():
    """Only one shoe visible at the first frame (the other hidden or out of the image): it
    is still found, labelled by the facing-the-camera convention (image-left = person's right)."""
    for pos, expect in (((60.0, 120.0), 1), ((140.0, 120.0), 0)):
        tr = BlobTracker(("foot_l", "foot_r"))
        out = tr.step(_feet_frame(pos, None), (0, 0), (0, 0, 200, 160), None)
        np.testing.assert_allclose(out.xy[expect], pos, atol=0.5)
        assert np.isnan(out.xy[1 - expect]).all() and out.confidence[1 - expect] == 0


def test_touching_shoes_are_labelled_by_the_shapes_they_had_apart():
    """Two shoes seen apart, then touching side by side, staggered along their length (one
    colour region): the tracker labels that region by the shapes it measured while the shoes
    were apart, and each cue stays on its shoe; by nearest centre (``label_by_shape`` off) one
    shoe takes the other's heel. Truth: the centroids of the drawn shoes."""
    a = _ellipse_map((160, 200), (90.0, 70.0), (18.0, 6.0), 0.0) > 0
    errors = {}
    for by_shape in (True, False):
        tr = BlobTracker(("foot_l", "foot_r"), BlobParams(label_by_shape=by_shape))
        for dy in (35.0, 29.0, 23.0, 17.0, 11.0):              # the second shoe comes closer
            b = _ellipse_map((160, 200), (104.0, 70.0 + dy), (18.0, 6.0), 0.0) > 0
            out = tr.step((a | b).astype(np.float32), (0, 0), (0, 0, 200, 160), None)
        assert cv2.connectedComponents((a | b).astype(np.uint8))[0] == 2     # touching: one region
        truth = np.array([np.argwhere(m)[:, ::-1].mean(axis=0) for m in (a, b)])
        d = np.linalg.norm(out.xy[:, None] - truth[None], axis=-1)           # (cue, shoe)
        errors[by_shape] = min(d[0, 0] + d[1, 1], d[0, 1] + d[1, 0]) / 2
    assert errors[True] < 1.0
    assert errors[False] > 2.0 * errors[True]


def test_shoes_never_seen_apart_are_labelled_by_size():
    """Shoes that touch from the first frame (a person standing, seen from the side) have no
    shape measured apart: the cues are those of the labelling by size, frame after frame (a
    shape taken from a merged region would feed its own wrong split)."""
    runs = []
    for by_shape in (True, False):
        tr = BlobTracker(("foot_l", "foot_r"), BlobParams(label_by_shape=by_shape))
        xy = []
        for x in (90.0, 92.0, 94.0, 96.0):
            centres = np.array([[x, 70.0], [x + 10.0, 74.0]])      # tracked from the start (fusion's prediction)
            a, b = (_ellipse_map((160, 200), c, (18.0, 6.0), 0.0) > 0 for c in centres)
            out = tr.step((a | b).astype(np.float32), (0, 0), (0, 0, 200, 160), None, centres, np.ones(2, bool),
                          np.full(2, 18.0))
            xy.append(out.xy)
        runs.append(np.array(xy))
    assert np.isfinite(runs[0]).all()
    np.testing.assert_array_equal(runs[0], runs[1])


def test_shoes_never_seen_apart_are_split_by_the_predicted_shapes():
    """Shoes touching side by side, staggered along their length, from the first frame, with
    fusion's prediction of each shoe's visible shape (``CuePrediction.shape_px``: a filled
    ellipse of semi-axes a, b has variances a^2 / 4, b^2 / 4): each cue is its shoe's centroid
    within a pixel (0.15 px); labelled by size (no shapes) one shoe takes the other's heel (1.7
    px). A shape that is not finite (NaN, a forged inf) is no shape."""
    shape = np.tile(np.diag([18.0 ** 2 / 4, 6.0 ** 2 / 4]), (2, 1, 1))
    errors = {}
    forged = shape.copy()
    forged[:, 0, 1] = np.inf
    for name, pred_shape in (("shapes", shape), ("none", None), ("nan", np.full((2, 2, 2), np.nan)),
                             ("forged", forged)):
        tr = BlobTracker(("foot_l", "foot_r"), BlobParams(label_by_shape=True))
        for x in (90.0, 92.0, 94.0, 96.0):
            centres = np.array([[x, 70.0], [x + 14.0, 81.0]])
            a, b = (_ellipse_map((160, 200), c, (18.0, 6.0), 0.0) > 0 for c in centres)
            out = tr.step((a | b).astype(np.float32), (0, 0), (0, 0, 200, 160), None, centres, np.ones(2, bool),
                          np.full(2, 18.0), pred_shape=pred_shape)
        assert cv2.connectedComponents((a | b).astype(np.uint8))[0] == 2     # touching: one region
        truth = np.array([np.argwhere(m)[:, ::-1].mean(axis=0) for m in (a, b)])
        errors[name] = np.linalg.norm(out.xy - truth, axis=1).max()
    assert errors["shapes"] < 0.5
    assert errors["none"] > 1.0
    assert errors["nan"] == errors["none"] == errors["forged"]


def _own_map(skin, sites, k):
    """Blob k's pixels of ``skin``: colour pixels not nearer (Mahalanobis) another site."""
    ys, xs = np.mgrid[0:skin.shape[0], 0:skin.shape[1]].astype(float)

    def mahal2(j):
        dx, dy = xs - sites[j, 0], ys - sites[j, 1]
        return sites[j, 2] * dx * dx + 2.0 * sites[j, 3] * dx * dy + sites[j, 4] * dy * dy

    dk = mahal2(k)
    other = np.zeros(skin.shape, bool)
    for j in range(len(sites)):
        if j != k and np.isfinite(sites[j, 0]):
            other |= mahal2(j) < dk
    return np.where(other & (skin > 0), 0.0, skin).astype(np.float32)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_exclusive_boundary_search_equals_search_on_the_blobs_own_pixels(seed):
    """deform_ellipse with sites tests each pixel's owner once around the ellipse: the same
    as searching a map that holds only the blob's own pixels (here also near the image edge)."""
    rng = np.random.default_rng(seed)
    h, w = 60, 80
    skin = np.zeros((h, w), np.float32)
    sites = np.full((3, 5), np.nan)
    for j in range(3):
        c = rng.uniform([-5, -5], [w + 5, h + 5]) if j == 0 else sites[0, :2] + rng.uniform(-20, 20, 2)
        a, b = rng.uniform(3, 12, 2)
        cv2.ellipse(skin, (int(c[0]), int(c[1])), (int(a), int(b)), float(rng.uniform(0, 180)), 0, 360, 1.0, -1)
        sites[j] = (c[0], c[1], 1 / (a * a / 4 + 1), rng.uniform(-0.002, 0.002), 1 / (b * b / 4 + 1))
    if rng.random() < 0.3:
        sites[2] = np.nan                                         # an absent blob
    k = int(rng.integers(0, 2))
    mean = sites[k, :2] + rng.uniform(-2, 2, 2)
    cov = np.diag(rng.uniform(4, 30, 2))
    sil = (rng.random((h, w)) < 0.5).astype(np.uint8)
    got_contour, ref_contour = np.zeros((32, 2)), np.zeros((32, 2))
    got = deform_ellipse(skin, sil, mean, cov, _kp(32, 0.4, 20), got_contour, sites, k)
    ref = deform_ellipse(_own_map(skin, sites, k), sil, mean, cov, _kp(32, 0.4, 20), ref_contour, _NO_SITES, 0)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(got_contour, ref_contour, rtol=1e-12, atol=1e-9)


def _random_regions(rng, shape=(70, 90), n=6):
    skin = np.zeros(shape, np.float32)
    for _ in range(n):
        c = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        cv2.circle(skin, c, int(rng.integers(1, 9)), 1.0, -1)
    return skin


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([np.uint8, np.float32]))
def test_colour_regions_match_opencv_in_its_label_order(seed, dtype):
    """Every region's box, area and centroid, row r = OpenCV's label r (its order: the first
    2 x 2 block of each region, which decides ties in the snap and re-acquisition), on
    windows of discs and of random pixel noise (many regions touching diagonally)."""
    rng = np.random.default_rng(seed)
    if rng.random() < 0.5:
        skin = _random_regions(rng)
    else:
        skin = (rng.random((int(rng.integers(1, 60)), int(rng.integers(1, 60)))) < rng.uniform(0, 0.6)).astype(np.float32)
    H, W = skin.shape
    x0, y0 = int(rng.integers(0, max(1, W // 3))), int(rng.integers(0, max(1, H // 3)))
    x1, y1 = int(rng.integers(x0 + 1, W + 1)), int(rng.integers(y0 + 1, H + 1))
    mask = (skin[y0:y1, x0:x1] >= 0.5).view(np.uint8)
    n, labels, ref, ref_centroids = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    got_n, stats = colour_regions(skin.astype(dtype), x0, y0, x1, y1)
    assert got_n == n
    np.testing.assert_array_equal(stats[1:, :2], ref[1:, :2])                    # x_min, y_min
    np.testing.assert_array_equal(stats[1:, 2:4] - stats[1:, :2] + 1, ref[1:, 2:4])  # width, height
    np.testing.assert_array_equal(stats[1:, 4], ref[1:, 4])
    np.testing.assert_allclose(stats[1:, 5:7] / stats[1:, 4:5], ref_centroids[1:])
    np.testing.assert_array_equal(stats[0], [x1 - x0, y1 - y0, -1, -1, 0, 0, 0])


def _reference_snap(skin, box, centers, gate, min_area):
    """Region snap in NumPy + itertools (the tracker's earlier implementation)."""
    have = np.isfinite(centers).all(axis=1)
    if have.sum() < 2:
        return centers
    ks = np.flatnonzero(have)
    cs, gs = centers[ks], gate[ks]
    d2 = ((cs[:, None, :] - cs[None, :, :]) ** 2).sum(-1)
    if (d2 < (SNAP_NEAR_GATES * (gs[:, None] + gs[None, :])) ** 2).sum() <= len(ks):
        return centers
    x0, y0, x1, y1 = box
    reach_px = SNAP_WINDOW_GATES * gs.max()
    wx0, wy0 = max(x0, int(cs[:, 0].min() - reach_px)), max(y0, int(cs[:, 1].min() - reach_px))
    wx1, wy1 = min(x1, int(cs[:, 0].max() + reach_px) + 1), min(y1, int(cs[:, 1].max() + reach_px) + 1)
    if wx1 - wx0 < 2 or wy1 - wy0 < 2:
        return centers
    mask = (skin[wy0:wy1, wx0:wx1] >= 0.5).view(np.uint8)
    _, _, stats, cent = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    big = np.flatnonzero(stats[1:, 4] >= min_area) + 1
    if len(big) < len(ks):
        return centers
    cc = cent[big] + (wx0, wy0)
    half = 0.5 * np.maximum(stats[big, 2], stats[big, 3])
    d = np.sqrt(((cs[:, None, :] - cc[None, :, :]) ** 2).sum(-1))
    reach = d <= gs[:, None] + half[None, :]
    cand = np.flatnonzero(reach.any(axis=0))
    if len(cand) < len(ks):
        return centers
    if len(cand) > SNAP_MAX_REGIONS:
        cand = cand[np.argsort(d[:, cand].min(axis=0), kind="stable")[:SNAP_MAX_REGIONS]]
    best, best_cost = None, np.inf
    for perm in itertools.permutations(range(len(cand)), len(ks)):
        if all(reach[i, cand[r]] for i, r in enumerate(perm)):
            cost = sum(d[i, cand[r]] for i, r in enumerate(perm))
            if cost < best_cost:
                best, best_cost = perm, cost
    if best is None:
        return centers
    out = centers.copy()
    out[ks] = cc[cand[list(best)]]
    return out


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_region_snap_matches_reference(seed):
    rng = np.random.default_rng(seed)
    skin = _random_regions(rng, n=int(rng.integers(1, 10)))
    K = int(rng.integers(2, 4))
    centers = rng.uniform((0, 0), (90, 70), (K, 2))
    if rng.random() < 0.3:
        centers[0] = np.nan
    gate = rng.uniform(4, 20, K)
    box = (int(rng.integers(0, 10)), int(rng.integers(0, 10)), int(rng.integers(60, 91)), int(rng.integers(50, 71)))
    min_area = BlobParams().acquire_min_area_px
    got = centers.copy()
    apart = snap_centres(skin, *box, got, gate, SNAP_NEAR_GATES, SNAP_WINDOW_GATES, min_area, SNAP_MAX_REGIONS)
    ref = _reference_snap(skin, box, centers, gate, min_area)
    np.testing.assert_array_equal(got, ref)
    wx0, _, wx1, _ = snap_window(centers, gate, *box, SNAP_NEAR_GATES, SNAP_WINDOW_GATES)
    assert apart == (wx1 <= wx0 or not np.array_equal(ref, centers, equal_nan=True))   # no blob near another, or snapped


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_acquire_candidates_match_reference(seed):
    """Unclaimed regions, largest first (ties in label order), at most four."""
    rng = np.random.default_rng(seed)
    skin = _random_regions(rng, n=int(rng.integers(1, 12)))
    x0, y0 = int(rng.integers(0, 5)), int(rng.integers(0, 5))
    mask = (skin[y0:, x0:] >= 0.5).view(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    sums = np.zeros((3, 6))
    sums[:, 0] = 10.0
    sums[:, 1:3] = rng.uniform((0, 0), (90, 70), (3, 2)) * 10.0
    found = rng.random(3) < 0.7
    ref = []
    for r in range(1, n):
        xa, ya, bw, bh, area = stats[r]
        xb, yb = xa + bw - 1, ya + bh - 1
        claimed = any(found[k] and x0 + xa - 1 <= sums[k, 1] / sums[k, 0] <= x0 + xb + 1
                      and y0 + ya - 1 <= sums[k, 2] / sums[k, 0] <= y0 + yb + 1 for k in range(3))
        if area >= 10 and not claimed:
            ref.append((area, x0 + 0.5 * (xa + xb), y0 + 0.5 * (ya + yb), 0.5 * max(xb - xa, yb - ya) + 1.0))
    ref = sorted(ref, key=lambda t: -t[0])[:4]
    cand = np.empty((4, 4))
    m = acquire_candidates(*colour_regions(skin, x0, y0, skin.shape[1], skin.shape[0])[::-1], x0, y0, sums, found,
                           10.0, cand)
    assert m == len(ref)
    np.testing.assert_array_equal(cand[:m], np.array(ref).reshape(-1, 4))
    # the blob tracker's one call: the regions of the box and their candidates
    cand2 = np.full((4, 4), np.nan)
    assert acquire_regions(skin, x0, y0, skin.shape[1], skin.shape[0], sums, found, 10.0, cand2) == m
    np.testing.assert_array_equal(cand2[:m], cand[:m])
