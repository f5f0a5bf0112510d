"""Silhouette: shadow/flicker-robust change test (B.8), largest component, holes filled."""

import cv2
import numpy as np
import pytest
from perception_scenes import make_background, make_scene
from hypothesis import example, given, settings
from hypothesis import strategies as st

from mocap_rt.perception.background import (BackgroundModel, ChangeThresholds, change_mask,
                                            keep_strong_boundary, largest_component_filled)


def _reference_change(img, model, th):
    """Plain NumPy version of the change test (module docstring)."""
    I = img.astype(np.float64)
    E = model.mean_bgr.astype(np.float64)
    ee = (E * E).sum(axis=2) + 1.0
    a = (I * E).sum(axis=2) / ee
    cd2 = ((I - a[..., None] * E) ** 2).sum(axis=2)
    thr = np.maximum(th.cd_sigmas * model.noise, th.cd_min_grey)
    d2 = ((I - E) ** 2).sum(axis=2)
    fg = (cd2 > thr ** 2) | (((a < th.alpha_min) | (a > th.alpha_max)) & (d2 > thr ** 2))
    return fg, np.stack([cd2, d2]), thr ** 2


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
@example(1412676)        # a colour distance within float32 rounding of the threshold
def test_change_kernel_matches_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    bgs = rng.integers(0, 256, (3, 30, 40, 3), dtype=np.uint8)
    model = BackgroundModel.from_frames(bgs)
    img = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    th = ChangeThresholds()
    roi = (3, 5, 30, 20)
    code = change_mask(img, model, roi, th)
    ref, dist2, t2 = _reference_change(img, model, th)     # dist2: (colour distortion, distance)^2
    # strongly changed: the same test with edge_strength^2 times the squared threshold
    strong_th = ChangeThresholds(cd_sigmas=th.cd_sigmas * th.edge_strength,
                                 cd_min_grey=th.cd_min_grey * th.edge_strength)
    strong, _, st2 = _reference_change(img, model, strong_th)
    win = np.s_[5:25, 3:33]
    # float32 vs float64: ignore pixels whose colour distortion or colour distance is within
    # rounding of a threshold
    near = ((np.abs(dist2 - t2) < 1e-3 * t2 + 1e-2) | (np.abs(dist2 - st2) < 1e-3 * st2 + 1e-2)).any(axis=0)[win]
    assert np.array_equal((code > 0)[~near], ref[win][~near])
    assert np.array_equal((code == 255)[~near], (ref & strong)[win][~near])
    assert set(np.unique(code)) <= {0, 128, 255}


def test_background_statistics_from_frames():
    rng = np.random.default_rng(0)
    base = rng.uniform(40, 200, (20, 30, 3))
    frames = np.clip(base[None] + rng.normal(0, 3.0, (40, 20, 30, 3)), 0, 255).astype(np.uint8)
    model = BackgroundModel.from_frames(frames)
    np.testing.assert_allclose(model.mean_bgr, frames.mean(axis=0), atol=1e-3)
    # colour distortion of isotropic noise sigma: two of three dimensions -> sqrt(2) * 3
    assert np.median(model.noise) == pytest.approx(np.sqrt(2) * 3.0, rel=0.15)


def test_shadow_and_flicker_are_not_foreground():
    bgs = make_background(seed=4)
    model = BackgroundModel.from_frames(bgs)
    img = bgs[0].astype(np.float32)
    yy, xx = np.mgrid[0:480, 0:640]
    shadow = (xx - 300) ** 2 / 150 ** 2 + (yy - 400) ** 2 / 40 ** 2 < 1
    img[shadow] *= 0.5                    # a shadow at half brightness
    for flicker in (0.9, 1.0, 1.12):      # global illumination change
        im = np.clip(img * flicker, 0, 255).astype(np.uint8)
        fg = change_mask(im, model) > 0
        assert fg[shadow].mean() < 0.01
        assert fg.mean() < 0.005
    # an object of a different colour at the same brightness is foreground
    obj = bgs[0].copy()
    cv2.rectangle(obj, (100, 100), (160, 200), (40, 150, 200), -1)
    fg = change_mask(obj, model) > 0
    assert fg[100:201, 100:161].mean() > 0.99
    # a much darker object than any shadow is foreground even if grey
    dark = (bgs[0] * 0.2).astype(np.uint8)
    assert (change_mask(dark, model) > 0).mean() > 0.95


def test_largest_component_with_holes_filled():
    m = np.zeros((100, 120), np.uint8)
    cv2.circle(m, (50, 50), 30, 255, -1)
    cv2.circle(m, (50, 50), 10, 0, -1)           # a hole
    cv2.rectangle(m, (100, 10), (110, 20), 255, -1)   # a smaller blob
    m[90, 5] = 255                                 # speckle
    out, box = largest_component_filled(m)
    truth = np.zeros_like(m)
    cv2.circle(truth, (50, 50), 30, 255, -1)
    assert np.array_equal(out > 0, truth > 0)
    assert box == cv2.boundingRect(truth)
    # 8-connectivity: a diagonal neighbour joins the component
    m2 = np.zeros((10, 10), np.uint8)
    m2[2:5, 2:5] = 255
    m2[5, 5] = 255
    m2[6:9, 6:9] = 255
    out2, box2 = largest_component_filled(m2)
    assert (out2 > 0).sum() == 19 and box2 == (2, 2, 7, 7)
    assert largest_component_filled(np.zeros((5, 5), np.uint8))[1] == (0, 0, 0, 0)
    assert largest_component_filled(m2, min_area_px=100)[1] == (0, 0, 0, 0)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_keep_strong_boundary_matches_opencv_morphology(seed):
    rng = np.random.default_rng(seed)
    sil = np.zeros((40, 50), np.uint8)
    for _ in range(4):
        cv2.circle(sil, (int(rng.integers(0, 50)), int(rng.integers(0, 40))), int(rng.integers(2, 15)), 255, -1)
    change = rng.choice(np.array([0, 128, 255], np.uint8), sil.shape)
    box = np.s_[3:37, 2:45]                       # views, as the pipeline passes them
    core = cv2.erode(sil[box], cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)), borderType=cv2.BORDER_REPLICATE)
    ref = cv2.bitwise_or(core, cv2.bitwise_and(sil[box], cv2.compare(change[box], 255, cv2.CMP_EQ)))
    np.testing.assert_array_equal(keep_strong_boundary(sil[box], change[box]), ref)


@pytest.mark.parametrize("flicker", [0.92, 1.0, 1.08])
def test_person_silhouette_iou_with_shadow(flicker):
    from mocap_rt.geometry.rig import ring_rig
    from mocap_rt.perception.pipeline import CameraPerceiver

    sc = make_scene(shadow=0.5, flicker=flicker)
    p = CameraPerceiver(ring_rig()[0], sc.background)
    cues = p.process(sc.image, 0)
    sil = p.last_silhouette
    iou = (sil & sc.mask).sum() / (sil | sc.mask).sum()
    assert iou > 0.99
    x, y, w, h = cv2.boundingRect(sc.mask.astype(np.uint8))
    assert abs(cues.bbox[0] - x) <= 1 and abs(cues.bbox[1] - y) <= 1
    assert abs(cues.bbox[2] - w) <= 2 and abs(cues.bbox[3] - h) <= 2


def test_slow_background_update_absorbs_a_static_change():
    bgs = make_background(seed=2)
    model = BackgroundModel.from_frames(bgs)
    changed = bgs[0].copy()
    cv2.rectangle(changed, (10, 10), (60, 60), (20, 200, 20), -1)     # e.g. a moved object
    assert (change_mask(changed, model)[10:61, 10:61] > 0).all()
    for _ in range(300):
        model.update(changed, np.zeros((480, 640), bool), 0.05)
    assert (change_mask(changed, model)[10:61, 10:61] > 0).mean() < 0.01
