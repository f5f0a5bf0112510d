"""Planar 4:2:0 -> BGR as swscale converts it (mocap_rt.io.yuv). Bit-exactness against OpenCV's
own FFmpeg decoder is tested through GStreamer in tests/nodes/test_nodes_gst.py."""

import numpy as np
import pytest

from mocap_rt.io.yuv import i420_to_bgr, i420_to_bgr_reference, swscale_coefficients


def _planes(rng, h, w):
    return (rng.integers(0, 256, (h, w), dtype=np.uint8), rng.integers(0, 256, ((h + 1) // 2, (w + 1) // 2),
                                                                         dtype=np.uint8),
            rng.integers(0, 256, ((h + 1) // 2, (w + 1) // 2), dtype=np.uint8))


@pytest.mark.parametrize("matrix", ["bt601", "bt709"])
@pytest.mark.parametrize("full_range", [True, False])
@pytest.mark.parametrize("size", [(48, 64), (37, 51)])
def test_kernel_equals_numpy_reference(matrix, full_range, size):
    y, u, v = _planes(np.random.default_rng(3), *size)
    out = np.zeros((*size, 3), np.uint8)
    got = i420_to_bgr(y, u, v, matrix, full_range, out=out)
    assert got is out
    np.testing.assert_array_equal(got, i420_to_bgr_reference(y, u, v, matrix, full_range))


def test_full_range_bt601_is_jfif_within_truncation():
    """JFIF (JPEG) YCbCr -> RGB: R = Y + 1.402 (Cr-128), G = Y - 0.344136 (Cb-128) - 0.714136 (Cr-128),
    B = Y + 1.772 (Cb-128); each chroma 2x2 block shares its sample. swscale truncates its
    fixed-point terms, so every channel is within 2 levels of the rounded real value, and grey
    (Cb = Cr = 128) is exact."""
    rng = np.random.default_rng(5)
    y, u, v = _planes(rng, 40, 60)
    U = np.repeat(np.repeat(u.astype(float), 2, 0), 2, 1) - 128
    V = np.repeat(np.repeat(v.astype(float), 2, 0), 2, 1) - 128
    Y = y.astype(float)
    jfif = np.clip(np.rint(np.stack([Y + 1.772 * U, Y - 0.344136 * U - 0.714136 * V, Y + 1.402 * V], -1)), 0, 255)
    got = i420_to_bgr(y, u, v)
    assert np.abs(got - jfif).max() <= 2
    grey = i420_to_bgr(y, np.full_like(u, 128), np.full_like(v, 128))
    np.testing.assert_array_equal(grey, np.repeat(y[:, :, None], 3, axis=2))


def test_video_range_maps_16_235_to_0_255():
    y = np.array([[16, 16], [235, 126]], np.uint8)
    c = np.full((1, 1), 128, np.uint8)
    got = i420_to_bgr(y, c, c, full_range=False)
    # (Y * 8 - 128) * round(255/219 * 8192) >> 16: 16 -> 0, 235 -> 255, 126 -> 128
    np.testing.assert_array_equal(got[..., 0], [[0, 0], [255, 128]])
    assert (got == got[..., :1]).all()


def test_coefficients_are_swscales():
    # ff_yuv2rgb_c_init_tables, full-range BT.601: 104597 * 224 // 255 = 91881 -> 11485 (1.402 * 2^13)
    assert swscale_coefficients("bt601", True).tolist() == [0, 8192, 11485, -2819, -5850, 14516]


def test_bad_planes_and_matrix_are_named():
    y, u, v = _planes(np.random.default_rng(0), 8, 8)
    with pytest.raises(ValueError, match="chroma planes"):
        i420_to_bgr(y, u[:3], v)
    with pytest.raises(ValueError, match="out must be"):
        i420_to_bgr(y, u, v, out=np.zeros((8, 8, 3), np.float32))
    with pytest.raises(ValueError, match="bt2020"):
        i420_to_bgr(y, u, v, matrix="bt2020")
