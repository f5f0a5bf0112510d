"""The wire format of cues and predictions, pinned by hand-built payloads (schema 3).

The bodies are written out here key by key, independently of ``CameraCues.to_dict`` and the
codec, so a change of the encoding that would break a peer running the previous code fails.
"""

import msgpack
import numpy as np

from mocap_rt.cues import CameraCues, CompactSilhouette, CuePrediction
from nodes.messages import SCHEMA_VERSION, Cues, Prediction


def record(a: np.ndarray, dtype: str) -> dict:
    a = np.ascontiguousarray(a, dtype=np.dtype(dtype))
    return {"dtype": dtype, "shape": list(a.shape), "data": a.tobytes()}


def envelope(t: str, body: dict) -> bytes:
    return msgpack.packb({"v": 7, "t": t, "b": body}, use_bin_type=True)


RNG = np.random.default_rng(15)
XY = RNG.normal(300, 50, (6, 2))
XY[2] = np.nan
COV = np.tile(np.eye(2) * 4.0, (6, 1, 1))
AREA = np.arange(6, dtype=float) * 10
CONF = np.array([1.0, 0.5, 0.0, 1.0, 0.9, 0.3])
MASK = RNG.random((5, 11)) > 0.5


def test_schema_version_is_7():
    assert SCHEMA_VERSION == 7


LEG = np.array([[101.5, 220.25], [np.nan, np.nan]])


def test_cues_with_a_silhouette_encode_to_the_pinned_bytes_and_back():
    sil = CompactSilhouette(-3, 40, 4, MASK)
    cues = CameraCues("cam_2", 17, XY, COV, AREA, CONF, (10, 20, 30, 40), {"total": 2.5}, sil, LEG)
    body = {"rig": "studio", "camera": "cam_2", "frame": 17, "xy": record(XY, "<f8"), "cov": record(COV, "<f8"),
            "area": record(AREA, "<f8"), "confidence": record(CONF, "<f8"), "bbox": [10, 20, 30, 40],
            "timings_ms": {"total": 2.5}, "t_trigger_mono_ns": 111, "t_grab_mono_ns": 222,
            "processing_ms": 3.25,
            "sil": {"x0": -3, "y0": 40, "step": 4, "w": 11, "bits": record(np.packbits(MASK, axis=1), "|u1")},
            "leg": record(LEG, "<f8")}
    wire = envelope("cues", body)
    assert Cues("studio", cues, 111, 222, 3.25).to_msgpack() == wire
    back = Cues.from_msgpack(wire)
    assert (back.rig, back.camera, back.frame, back.cues.bbox) == ("studio", "cam_2", 17, (10, 20, 30, 40))
    np.testing.assert_array_equal(back.cues.xy, XY)
    np.testing.assert_array_equal(back.cues.silhouette.mask, MASK)
    assert (back.cues.silhouette.x0, back.cues.silhouette.y0, back.cues.silhouette.step) == (-3, 40, 4)
    np.testing.assert_array_equal(back.cues.leg_xy, LEG)


def test_cues_without_a_silhouette_have_no_sil_key():
    """... and without the legs' attachments no ``leg`` key."""
    cues = CameraCues("cam_1", 0, XY, COV, AREA, CONF)
    body = {"rig": "r", "camera": "cam_1", "frame": 0, "xy": record(XY, "<f8"), "cov": record(COV, "<f8"),
            "area": record(AREA, "<f8"), "confidence": record(CONF, "<f8"), "bbox": [0, 0, 0, 0],
            "timings_ms": {}, "t_trigger_mono_ns": 1, "t_grab_mono_ns": 2, "processing_ms": 0.0}
    assert Cues("r", cues, 1, 2, 0.0).to_msgpack() == envelope("cues", body)
    back = Cues.from_msgpack(envelope("cues", body)).cues
    assert back.silhouette is None and back.leg_xy is None


def test_prediction_encodes_to_the_pinned_bytes_and_back():
    vis = np.array([True, False, True, True, False, True])
    rad = np.linspace(5, 30, 6)
    body = {"rig": "r", "camera": "cam_3", "frame": 9, "xy": record(XY, "<f8"), "visible": record(vis, "|b1"),
            "radius_px": record(rad, "<f8")}
    wire = envelope("prediction", body)
    assert Prediction("r", CuePrediction("cam_3", 9, XY, vis, rad)).to_msgpack() == wire
    back = Prediction.from_msgpack(wire).prediction
    np.testing.assert_array_equal(back.visible, vis)
    np.testing.assert_array_equal(back.radius_px, rad)
    assert back.offset_px is None
    # with the offsets of the parts' visible centres (schema 5)
    off = np.array([[0.25, -1.5], [1.0, 2.0], [np.nan, np.nan], [0.0, 0.0], [-3.0, 0.5], [np.nan, np.nan]])
    wire = envelope("prediction", {**body, "offset_px": record(off, "<f8")})
    assert Prediction("r", CuePrediction("cam_3", 9, XY, vis, rad, off)).to_msgpack() == wire
    np.testing.assert_array_equal(Prediction.from_msgpack(wire).prediction.offset_px, off)
    # and the shapes of the visible shoes (schema 6)
    shape = np.full((6, 2, 2), np.nan)
    shape[3:5] = [[[30.5, -4.0], [-4.0, 9.25]], [[12.0, 1.5], [1.5, 20.0]]]
    wire = envelope("prediction", {**body, "offset_px": record(off, "<f8"), "shape_px": record(shape, "<f8")})
    assert Prediction("r", CuePrediction("cam_3", 9, XY, vis, rad, off, shape)).to_msgpack() == wire
    back = Prediction.from_msgpack(wire).prediction
    np.testing.assert_array_equal(back.offset_px, off)
    np.testing.assert_array_equal(back.shape_px, shape)
