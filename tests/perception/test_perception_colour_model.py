"""Parametric colour model (seed digest A.1, eq. 1-2): fit, error, kernel, TOML, real skin data."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.perception.colour_model import (ColourModel, ColourModelError, default_colour_model,
                                              fit_colour_model, likelihood_map, load_colour_model,
                                              loads_colour_model, read_uci_skin_table, save_colour_model)

# rows R, G, B; the c2 column sums to 0 and the c1 column to 3, so a model colour's grey
# level (R+G+B)/3 is exactly i and noiseless model pixels must give these coefficients back
TRUE_COEFFS = np.array([[-0.0025, 1.70], [0.0002, 0.92], [0.0023, 0.38]])


def _model_pixels(coeffs, grey):
    g = grey[:, None]
    return coeffs[:, 0] * g * g + coeffs[:, 1] * g


def test_fit_recovers_exact_coefficients_from_noiseless_pixels():
    grey = np.linspace(60, 220, 200)
    rgb = _model_pixels(TRUE_COEFFS, grey)
    np.testing.assert_allclose(rgb.mean(axis=1), grey, rtol=1e-12)
    model = fit_colour_model(rgb, "t")
    np.testing.assert_allclose(model.coeffs, TRUE_COEFFS, rtol=1e-8, atol=1e-12)
    # with noise the fit is still close
    rng = np.random.default_rng(0)
    noisy = fit_colour_model(rgb + rng.normal(0, 1.0, rgb.shape), "t")
    np.testing.assert_allclose(noisy.model_rgb(grey), rgb, atol=1.5)


def test_error_is_zero_on_model_colour_and_chromaticity_hand_computed():
    m = ColourModel("t", TRUE_COEFFS, 1e-3, 1e-2)
    grey = np.array([80.0, 150.0])
    col = m.model_rgb(grey)
    # a pixel with the model's own chromaticity at any brightness near i has ~zero error
    assert np.all(m.error_rgb(col) < 1e-6)
    px = np.array([[200.0, 100.0, 60.0]])
    i = px.mean()
    M = m.model_rgb(np.array([i]))[0]
    expected = (200 / 360 - M[0] / M.sum()) ** 2 + (100 / 360 - M[1] / M.sum()) ** 2
    assert m.error_rgb(px)[0] == pytest.approx(expected, rel=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.booleans())
def test_numba_kernel_matches_numpy_reference(seed, binary):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (23, 31, 3), dtype=np.uint8)
    mask = rng.random((23, 31)) < 0.8
    m = ColourModel("t", TRUE_COEFFS, 4e-4, 3e-3, 40.0, 230.0)
    got = likelihood_map(img, m, mask, binary=binary)
    rgb = img[..., ::-1].reshape(-1, 3).astype(np.float64)
    p = m.likelihood_rgb(rgb)
    ok = (m.error_rgb(rgb) <= m.max_error) & (p > 0) & mask.ravel()
    ref = np.where(ok, 1.0 if binary else p, 0.0).reshape(23, 31)
    np.testing.assert_allclose(got, ref, atol=2e-4)


def test_toml_round_trip_is_exact(tmp_path):
    m = ColourModel("shoe", TRUE_COEFFS * 1.0000001, 3.3e-4, 2.1e-3, 33.3, 222.2)
    save_colour_model(m, tmp_path / "m.toml")
    back = load_colour_model(tmp_path / "m.toml")
    assert back.name == "shoe"
    np.testing.assert_array_equal(back.coeffs, m.coeffs)
    assert (back.sigma2, back.max_error, back.grey_min, back.grey_max) == (m.sigma2, m.max_error, 33.3, 222.2)


def test_bad_model_files_name_file_and_field(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('[colour_model]\nR = [1.0, 2.0]\nG = [1.0, 2.0]\nB = [1.0, 2.0]\nmax_error = 0.1\n')
    with pytest.raises(ColourModelError, match=r"bad\.toml.*sigma2"):
        load_colour_model(p)
    p.write_text('[colour_model]\nR = [1.0, 2.0]\nG = [1.0, 2.0]\nB = [1.0, 2.0]\nsigma2 = 1.0\nmax_error = 0.1\nextra = 1\n')
    with pytest.raises(ColourModelError, match="unknown keys.*extra"):
        load_colour_model(p)
    with pytest.raises(ColourModelError, match="not valid TOML"):
        loads_colour_model("[colour_model\n", "x.toml")
    with pytest.raises(FileNotFoundError):
        load_colour_model(tmp_path / "missing.toml")


def test_shipped_skin_model_separates_real_uci_skin(data_dir):
    rgb, is_skin = read_uci_skin_table(data_dir / "skin" / "uci_skin_segmentation" / "Skin_NonSkin.txt")
    assert is_skin.sum() == 50859 and (~is_skin).sum() == 194198
    model = default_colour_model("skin")
    acc = model.likelihood_rgb(rgb) >= model.min_likelihood
    assert acc[is_skin].mean() > 0.93
    assert acc[~is_skin].mean() < 0.03
    # the shipped file is what fitting the real table gives
    refit = fit_colour_model(rgb[is_skin], "skin")
    np.testing.assert_allclose(refit.coeffs, model.coeffs, rtol=1e-9)


def test_colour_model_cli_fits_images_and_masks(tmp_path):
    import cv2

    from mocap_rt.cli import main

    rng = np.random.default_rng(3)
    img = np.full((40, 50, 3), (200, 200, 200), np.uint8)
    mask = np.zeros((40, 50), np.uint8)
    grey = rng.uniform(70, 200, (20, 20))
    patch = _model_pixels(TRUE_COEFFS, grey.ravel()).reshape(20, 20, 3)
    img[10:30, 10:30] = np.clip(patch[..., ::-1], 0, 255).astype(np.uint8)
    mask[10:30, 10:30] = 255
    cv2.imwrite(str(tmp_path / "a.png"), img)
    cv2.imwrite(str(tmp_path / "a_mask.png"), mask)
    assert main(["colour-model", "fit", "--images", str(tmp_path / "a.png"), "--masks",
                 str(tmp_path / "a_mask.png"), "--name", "x", "--out", str(tmp_path / "x.toml")]) == 0
    m = load_colour_model(tmp_path / "x.toml")
    # model colour matches the drawn chromaticity (rounding to uint8 only)
    assert np.median(m.error_rgb(img[mask > 0][:, ::-1])) < 1e-5
    assert main(["colour-model", "fit", "--images", str(tmp_path / "a.png"), "--masks",
                 "--out", str(tmp_path / "y.toml")]) == 2


def test_two_model_pass_equals_two_single_maps():
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (37, 41, 3), dtype=np.uint8)
    mask = rng.random((37, 41)) < 0.7
    a = ColourModel("a", TRUE_COEFFS, 4e-4, 4e-3, 30.0, 230.0)
    b = default_colour_model("shoe")
    # make sure both models accept something
    img[:5, :5] = np.clip(a.model_rgb(np.array([120.0]))[0][::-1], 0, 255).astype(np.uint8)
    img[5:10, :5] = (40, 150, 45)
    from mocap_rt.perception.colour_model import colour_maps_binary
    ma, mb = colour_maps_binary(img, a, b, mask)
    np.testing.assert_array_equal(ma, likelihood_map(img, a, mask, binary=True))
    np.testing.assert_array_equal(mb, likelihood_map(img, b, mask, binary=True))
    assert ma.sum() > 0 and mb.sum() > 0
