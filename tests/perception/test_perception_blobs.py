"""Blob kernels and tracker (seed digest A.2, A.4): labelling, deformable ellipse, identities."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.perception.blob_kernels import deform_ellipse, label_moments
from mocap_rt.perception.blobs import BlobParams, BlobTracker

_NO_SITES = np.full((1, 2), np.nan)


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
    sums = np.zeros((3, 6))
    label_moments(skin, 2, 3, 45, 38, centers, gate * gate, sums)
    ys, xs = np.nonzero(skin[3:38, 2:45])
    xs, ys = xs + 2.0, ys + 3.0
    d = (xs[:, None] - centers[None, :, 0]) ** 2 + (ys[:, None] - centers[None, :, 1]) ** 2
    d = np.where(np.isfinite(d) & (d < gate * gate), d, np.inf)
    lab = np.where(np.isfinite(d.min(axis=1)), d.argmin(axis=1), -1)
    for k in range(3):
        sel = lab == k
        x, y = xs[sel], ys[sel]
        ref = [sel.sum(), x.sum(), y.sum(), (x * x).sum(), (x * y).sum(), (y * y).sum()]
        np.testing.assert_allclose(sums[k], ref)


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
    cx, cy, area = deform_ellipse(skin, np.zeros((1, 1), np.uint8), mean, cov, 2.0, 24, 0.5, 3.0, 2, 0, contour, _NO_SITES, 0)
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
    assert out.contours[1] is None and out.contours[2] is not None
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
    plain = deform_ellipse(skin, sil, mean, cov, 2.0, 32, 0.5, 3.0, 2, 0, contour, _NO_SITES, 0)
    completed = deform_ellipse(skin, sil, mean, cov, 2.0, 32, 0.5, 3.0, 2, 20, contour, _NO_SITES, 0)
    err_plain = np.hypot(plain[0] - centre[0], plain[1] - centre[1])
    err_completed = np.hypot(completed[0] - centre[0], completed[1] - centre[1])
    assert err_plain > 2.0                      # the visible part's centre is shifted right
    assert err_completed < 0.5 * err_plain
    assert abs(completed[1] - centre[1]) < 0.3  # and not moved across the axis
    # without a silhouette around it (no contact) completion changes nothing
    again = deform_ellipse(skin, (skin > 0).astype(np.uint8), mean, cov, 2.0, 32, 0.5, 3.0, 2, 20, contour,
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
    cx, cy, _ = deform_ellipse(skin, np.zeros((1, 1), np.uint8), mean, cov, 2.0, 32, 0.5, 3.0, 2, 0, contour, sites, 0)
    assert np.hypot(cx - xs.mean(), cy - ys.mean()) < 0.6
    merged = deform_ellipse(skin, np.zeros((1, 1), np.uint8), mean, cov, 2.0, 32, 0.5, 3.0, 2, 0, contour, _NO_SITES, 0)
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
