"""The fused silhouette clean-up + colour pass (``perception.silhouette``) against its two
separate references: OpenCV morphology for the boundary rule, the NumPy colour model; the
compact silhouette's cells against a plain count and OpenCV's area mean."""

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.cues import CompactSilhouette
from mocap_rt.perception.colour_model import ColourModel, chroma_table, default_colour_model
from mocap_rt.perception.silhouette import _chroma_boxes, half_cells, silhouette_colour

TRUE_COEFFS = np.array([[-0.0025, 1.70], [0.0002, 0.92], [0.0023, 0.38]])


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_silhouette_colour_equals_morphology_and_numpy_colour_model(seed):
    rng = np.random.default_rng(seed)
    H, W = 60, 70
    skin = ColourModel("a", TRUE_COEFFS, 4e-4, 4e-3, 30.0, 230.0)
    shoe = default_colour_model("shoe")
    img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    # patches of each model's colour (and near it), so both maps have pixels on both sides
    grey = rng.uniform(40, 220, (H, W))
    model_bgr = np.clip(skin.model_rgb(grey.ravel())[:, ::-1].reshape(H, W, 3) + rng.normal(0, 3, (H, W, 3)), 0, 255)
    img[10:30] = model_bgr[10:30].astype(np.uint8)
    img[30:40, :20] = np.clip(np.array([40, 150, 45]) + rng.normal(0, 6, (10, 20, 3)), 0, 255).astype(np.uint8)
    member = np.zeros((H, W), np.uint8)
    member[20:38, 6:25] = 255                     # over both colour patches
    for _ in range(4):
        cv2.circle(member, (int(rng.integers(0, W)), int(rng.integers(0, H))), int(rng.integers(3, 20)), 255, -1)
    change = rng.choice(np.array([0, 128, 255], np.uint8), (H, W))
    x0, y0, w, h = 4, 6, 55, 48                   # the person box inside the image
    box = np.s_[y0:y0 + h, x0:x0 + w]
    sil, map_a, map_b, n_sil = silhouette_colour(member[box], change[box], img, (x0, y0, w, h),
                                                 chroma_table(skin.kernel_params(), shoe.kernel_params()),
                                                 skin.max_error, shoe.max_error)
    # boundary rule: interior (3x3 cross erosion, border replicated) or strongly changed
    core = cv2.erode(member[box], cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)), borderType=cv2.BORDER_REPLICATE)
    ref_sil = np.where((core > 0) | ((member[box] > 0) & (change[box] == 255)), 255, 0).astype(np.uint8)
    np.testing.assert_array_equal(sil, ref_sil)
    assert n_sil == np.count_nonzero(ref_sil)
    # colour: eq. 2 error of the NumPy model on silhouette pixels, in the model's grey range
    rgb = img[box][..., ::-1].reshape(-1, 3)
    for model, got in ((skin, map_a), (shoe, map_b)):
        grey_ok = (rgb.sum(1) / 3.0 >= model.grey_min) & (rgb.sum(1) / 3.0 <= model.grey_max)
        err = model.error_rgb(rgb)
        ref = ((err <= model.max_error) & grey_ok).reshape(h, w) & (ref_sil > 0)
        # float32 (kernel) vs float64 (NumPy): ignore pixels within rounding of a threshold
        g = rgb.sum(1) / 3.0
        near = ((np.abs(err - model.max_error) < 1e-6) | (np.abs(g - model.grey_min) < 1e-4) |
                (np.abs(g - model.grey_max) < 1e-4)).reshape(h, w)
        assert np.array_equal((got > 0)[~near], ref[~near])
        assert set(np.unique(got)) <= {0.0, 1.0}
    assert map_a.sum() > 0 and map_b.sum() > 0 and (sil == 0).sum() > 0


def test_chroma_table_rows_are_the_model_chromaticity():
    skin = ColourModel("a", TRUE_COEFFS, 4e-4, 4e-3, 30.0, 230.0)
    shoe = default_colour_model("shoe")
    t = chroma_table(skin.kernel_params(), shoe.kernel_params())
    s = np.arange(766)
    for m, model in enumerate((skin, shoe)):
        rgb = model.model_rgb(np.maximum(s, 1) / 3.0)                       # (766, 3) R, G, B
        i = s.astype(np.float32) * np.float32(1.0 / 3.0)                # the kernels' grey level (float32)
        inside = (i >= model.grey_min) & (i <= model.grey_max) & (s > 0)
        np.testing.assert_array_equal((t[:, 4].astype(int) >> m) & 1, inside)
        np.testing.assert_allclose(t[inside, 2 * m], (rgb[:, 0] / rgb.sum(1))[inside], rtol=1e-6)
        np.testing.assert_allclose(t[inside, 2 * m + 1], (rgb[:, 1] / rgb.sum(1))[inside], rtol=1e-6)


def test_chroma_boxes_hold_every_pixel_a_model_accepts():
    """The pre-test of the colour pass: every BGR value of a dense sample that the NumPy colour
    model accepts lies in its model's box, and the boxes are small (they skip the table test
    for most pixels); a model without a grey level in range has an empty box."""
    from mocap_rt.perception.colour_model import colour_maps_binary

    skin = ColourModel("a", TRUE_COEFFS, 4e-4, 4e-3, 30.0, 230.0)
    shoe = default_colour_model("shoe")
    rng = np.random.default_rng(7)
    grey = rng.uniform(0, 255, 200_000)
    near = skin.model_rgb(grey)[:, ::-1] + rng.normal(0, 3, (grey.size, 3))       # around the skin locus
    img = np.clip(np.concatenate([near, rng.uniform(0, 255, (200_000, 3))]), 0, 255).astype(np.uint8)[None]
    a, b = colour_maps_binary(img, skin, shoe, np.ones(img.shape[:2], np.uint8))
    box = np.array(_chroma_boxes(chroma_table(skin.kernel_params(), shoe.kernel_params()),
                                 skin.max_error, shoe.max_error)).reshape(2, 4)
    px = img[0].astype(np.float32)
    s = np.maximum(px.sum(axis=1), 1)
    rn, gn = px[:, 2] / s, px[:, 1] / s
    for accepted, (r0, r1, g0, g1) in zip((a[0] > 0, b[0] > 0), box):
        assert accepted.sum() > 1000
        inside = (rn >= r0) & (rn <= r1) & (gn >= g0) & (gn <= g1)
        assert inside[accepted].all()
        assert inside[200_000:].mean() < 0.2                     # of the uniform sample
    out_of_range = ColourModel("c", TRUE_COEFFS, 4e-4, 4e-3, 300.0, 310.0)     # grey levels past 255
    empty = _chroma_boxes(chroma_table(out_of_range.kernel_params(), shoe.kernel_params()), 1e-3, 1e-3)
    assert empty[0] > empty[1] and empty[2] > empty[3]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 23), st.integers(1, 19))
def test_silhouette_colour_is_exactly_the_two_stages(seed, w, h):
    """Bit-identical to the two separate kernels it fuses (``keep_strong_boundary``, then
    ``colour_maps_binary`` on its pixels), at every box size down to one pixel: the row
    passes and their ends (border replicated) and the per-row chromaticities."""
    from mocap_rt.perception.background import keep_strong_boundary
    from mocap_rt.perception.colour_model import colour_maps_binary

    rng = np.random.default_rng(seed)
    skin = ColourModel("a", TRUE_COEFFS, 4e-4, 4e-3, 30.0, 230.0)
    shoe = default_colour_model("shoe")
    H, W = h + 5, w + 7
    grey = rng.uniform(0, 255, (H, W))
    img = np.clip(skin.model_rgb(grey.ravel())[:, ::-1].reshape(H, W, 3) + rng.normal(0, 4, (H, W, 3)), 0, 255)
    img = img.astype(np.uint8)
    img[rng.random((H, W)) < 0.3] = np.array([40, 150, 45], np.uint8)    # shoe green
    img[rng.random((H, W)) < 0.1] = 0                                    # black: grey sum 0
    member = np.where(rng.random((h, w)) < 0.7, 255, 0).astype(np.uint8)
    change = rng.choice(np.array([0, 128, 255], np.uint8), (h, w))
    x0, y0 = 3, 2
    sil, map_a, map_b, n_sil = silhouette_colour(member, change, img, (x0, y0, w, h),
                                                 chroma_table(skin.kernel_params(), shoe.kernel_params()),
                                                 skin.max_error, shoe.max_error)
    ref_sil = keep_strong_boundary(member, change)
    assert n_sil == np.count_nonzero(ref_sil)
    ref_a, ref_b = colour_maps_binary(np.ascontiguousarray(img[y0:y0 + h, x0:x0 + w]), skin, shoe, ref_sil)
    np.testing.assert_array_equal(sil, ref_sil)
    np.testing.assert_array_equal(map_a, ref_a)
    np.testing.assert_array_equal(map_b, ref_b)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 120), st.integers(1, 120), st.integers(2, 5), st.floats(0.0, 1.0), st.integers(0, 2**31 - 1))
def test_half_cells_equal_the_compact_silhouettes_area_mean(bh, bw, step, density, seed):
    """``half_cells`` (counting) gives the cells of ``CompactSilhouette.from_box_mask``
    (OpenCV's area mean >= 0.5) and of a plain count over the zero-padded box."""
    rng = np.random.default_rng(seed)
    sil = (rng.random((bh, bw)) < density).astype(np.uint8) * 255
    got = half_cells(sil, step)
    h, w = -(-bh // step), -(-bw // step)
    pad = np.zeros((h * step, w * step), np.int64)
    pad[:bh, :bw] = sil > 0
    counts = pad.reshape(h, step, w, step).sum(axis=(1, 3))
    np.testing.assert_array_equal(got, 2 * counts >= step * step)
    max_bytes = h * ((w + 7) // 8)              # a budget that this step fits
    compact = CompactSilhouette.from_box_mask(sil, (3, 4, bw, bh), max_bytes)
    assert compact.step <= step
    np.testing.assert_array_equal(half_cells(sil, compact.step), compact.mask)
