"""Message schemas: round trips, and every kind of bad payload on every key is a counted drop."""

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap_rt.body.skeleton import N_BONE_VALUES
from mocap_rt.cues import CameraCues, CompactSilhouette, CuePrediction
from nodes.messages import (MESSAGE_TYPES, SCHEMA_VERSION, Background, Cues, Decoder, Frame, Keys,
                            MessageError, Pose, Prediction, Preview, Status, Trigger, decode_array,
                            encode_array)

names = st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,20}", fullmatch=True)
u63 = st.integers(0, 2**62)
floats = st.floats(allow_nan=True, allow_infinity=False, width=64)


def arr(shape, elements=floats):
    return st.lists(elements, min_size=int(np.prod(shape)), max_size=int(np.prod(shape))).map(
        lambda v: np.asarray(v, np.float64).reshape(shape))


def bools(shape):
    return st.lists(st.booleans(), min_size=int(np.prod(shape)), max_size=int(np.prod(shape))).map(
        lambda v: np.asarray(v, bool).reshape(shape))


small_map = st.dictionaries(st.text(max_size=8), st.floats(allow_nan=False, width=64), max_size=4)

triggers = st.builds(Trigger, names, u63, u63, u63, u63)
silhouettes = st.none() | st.builds(CompactSilhouette, st.integers(-8, 700), st.integers(-8, 500), st.integers(1, 8),
                                    st.tuples(st.integers(0, 30), st.integers(0, 50)).flatmap(bools))
cues = st.builds(lambda rig, cam, f, xy, cov, area, conf, bbox, tim, sil, a, b, p: Cues(
    rig, CameraCues(cam, f, xy, cov, area, conf, bbox, tim, sil), a, b, p),
    names, names, u63, arr((6, 2)), arr((6, 2, 2)), arr((6,)), arr((6,)),
    st.tuples(*[st.integers(-10**6, 10**6)] * 4), small_map, silhouettes, u63, u63, floats)
predictions = st.builds(lambda rig, cam, f, xy, vis, rad, off, shape: Prediction(
    rig, CuePrediction(cam, f, xy, vis, rad, off, shape)),
    names, names, u63, arr((6, 2)), bools((6,)), arr((6,)), st.none() | arr((6, 2)), st.none() | arr((6, 2, 2)))
poses = st.builds(Pose, names, u63, u63, u63, arr((6, 3)), bools((6,)), arr((20, 3)),
                  st.integers(0, 120).flatmap(lambda n: arr((n,))),
                  st.lists(names, max_size=6).map(tuple), st.lists(names, max_size=6).map(tuple),
                  arr((N_BONE_VALUES,)), small_map)
statuses = st.builds(Status, names, names, names, u63, u63, st.sampled_from(Status.STATES), floats, floats,
                     u63, u63, u63, floats, small_map)
previews = st.builds(Preview, names, names, u63, st.binary(max_size=2000))
frames = st.builds(Frame, names, names, u63, u63,
                   st.tuples(st.integers(1, 8), st.integers(1, 8)).flatmap(
                       lambda hw: st.binary(min_size=hw[0] * hw[1] * 3, max_size=hw[0] * hw[1] * 3).map(
                           lambda b: np.frombuffer(b, np.uint8).reshape(hw[0], hw[1], 3))))
backgrounds = st.builds(Background, names, names,
                        st.integers(1, 3).map(lambda b: np.random.default_rng(b).integers(
                            0, 255, (b, 4, 5, 3), dtype=np.uint8)))
STRATEGIES = {Trigger: triggers, Cues: cues, Prediction: predictions, Pose: poses, Status: statuses,
              Preview: previews, Frame: frames, Background: backgrounds}
SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def same(a, b) -> bool:
    """Field-wise equality, NaN == NaN, arrays compared with dtype."""
    if hasattr(a, "__dataclass_fields__"):
        return type(a) is type(b) and all(same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    if isinstance(a, np.ndarray):
        return (isinstance(b, np.ndarray) and a.shape == b.shape and a.dtype == b.dtype
                and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (np.isnan(a) and np.isnan(b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    return a == b


def test_every_message_type_has_a_strategy():
    assert set(STRATEGIES) == set(MESSAGE_TYPES)


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.TYPE)
def test_round_trip(cls):
    @SETTINGS
    @given(STRATEGIES[cls])
    def check(msg):
        payload = msg.to_msgpack()
        assert isinstance(payload, bytes)
        back = cls.from_msgpack(payload)
        assert same(msg, back)
        # a decoded array is writable (a copy, not a view on the payload)
        for f in back.__dataclass_fields__:
            v = getattr(back, f)
            if isinstance(v, np.ndarray):
                v.flags.writeable  # noqa: B018
                assert v.flags.writeable
    check()


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.TYPE)
def test_truncated_payloads_are_dropped_and_counted(cls):
    @SETTINGS
    @given(STRATEGIES[cls], st.data())
    def check(msg, data):
        payload = msg.to_msgpack()
        cut = data.draw(st.integers(0, len(payload) - 1))
        dec = Decoder("t")
        assert dec.decode(payload[:cut], cls) is None
        assert dec.drops == {cls.TYPE: 1}
    check()


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.TYPE)
def test_garbage_wrong_version_wrong_type_oversized_are_dropped(cls):
    @SETTINGS
    @given(STRATEGIES[cls], st.binary(max_size=300), st.integers(-2**63, 2**63 - 1).filter(lambda v: v != SCHEMA_VERSION))
    def check(msg, junk, version):
        dec = Decoder("t")
        env = msgpack.unpackb(msg.to_msgpack(), raw=False)
        bad_version = msgpack.packb({**env, "v": version}, use_bin_type=True)
        other = next(c for c in MESSAGE_TYPES if c is not cls)
        wrong_type = msgpack.packb({**env, "t": other.TYPE}, use_bin_type=True)
        payload = msg.to_msgpack()
        # the same message under a cap just below its size (the real caps: test_real_size_caps)
        capped = type("Capped", (cls,), {"MAX_BYTES": len(payload) - 1})
        assert dec.decode(payload, capped) is None
        extra_bytes = msg.to_msgpack() + b"\xc0"          # valid message followed by junk
        n = 0
        for bad in (bad_version, wrong_type, extra_bytes, junk, b"", "text", None, 12):
            got = dec.decode(bad, cls)
            if bad is junk and got is not None:   # a random blob is (very rarely) a valid message
                continue
            assert got is None, bad[:40] if isinstance(bad, bytes) else bad
            n += 1
        assert dec.total_drops == n + 1
    check()


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.TYPE)
def test_real_size_caps(cls):
    """A payload one byte over the type's cap is refused before it is unpacked."""
    dec = Decoder("t")
    assert dec.decode(b"\x00" * (cls.MAX_BYTES + 1), cls) is None
    assert dec.total_drops == 1


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.TYPE)
def test_body_fields_with_wrong_types_are_dropped(cls):
    """Replace one body field with a value of another type: always a drop, never an exception."""
    wrong_values = [None, "x", 1.5, -1, True, [1, 2], {"a": 1}, b"\x01\x02",
                    {"dtype": ">f8", "shape": [6, 2], "data": b"\x00" * 96},
                    {"dtype": "<f8", "shape": [5, 2], "data": b"\x00" * 80},
                    {"dtype": "<f8", "shape": [6, 2], "data": b"\x00" * 95},
                    {"dtype": "O", "shape": [1], "data": b"\x00" * 8}]

    @SETTINGS
    @given(STRATEGIES[cls], st.data())
    def check(msg, data):
        env = msgpack.unpackb(msg.to_msgpack(), raw=False)
        key = data.draw(st.sampled_from(sorted(env["b"])))
        value = data.draw(st.sampled_from(wrong_values))
        body = dict(env["b"])
        original = body[key]
        body[key] = value
        payload = msgpack.packb({**env, "b": body}, use_bin_type=True)
        dec = Decoder("t")
        got = dec.decode(payload, cls)
        if got is None:
            assert dec.total_drops == 1
        else:
            # accepted only if the value is still valid for that field (e.g. an int where any int goes)
            assert type(value) is type(original) or isinstance(original, (int, float))
            assert dec.total_drops == 0
        # removing the field is a drop, unless the field is optional
        del body[key]
        back = dec.decode(msgpack.packb({**env, "b": body}, use_bin_type=True), cls)
        assert back is None if key not in cls.OPTIONAL_FIELDS else back is not None
    check()


def test_decoder_accepts_zbytes_like_objects():
    class FakeZBytes:
        def __init__(self, b):
            self._b = b

        def to_bytes(self):
            return self._b

    t = Trigger("rig", 5, 1, 2, 3)
    assert Decoder().decode(FakeZBytes(t.to_msgpack()), Trigger) == t


def test_array_codec_is_little_endian_and_checks_shape():
    a = np.arange(6, dtype=">f8").reshape(2, 3)
    d = encode_array(a)
    assert d["dtype"] == "<f8" and d["shape"] == [2, 3]
    assert d["data"] == a.astype("<f8").tobytes()
    np.testing.assert_array_equal(decode_array(d, "a", (2, None)), a)
    with pytest.raises(MessageError, match="shape"):
        decode_array(d, "a", (3, 2))
    with pytest.raises(MessageError, match="bytes"):
        decode_array({**d, "data": d["data"][:-1]}, "a")


def test_oversized_message_refused_at_encode():
    big = Preview("r", "c", 0, b"\x00" * (Preview.MAX_BYTES + 10))
    with pytest.raises(MessageError, match="exceeds"):
        big.to_msgpack()


def test_keys_are_under_the_rig_and_names_are_checked():
    k = Keys("studio_1")
    assert k.trigger == "mocap/studio_1/trigger"
    assert k.cues("cam_2") == "mocap/studio_1/cues/cam_2"
    assert k.cues() == "mocap/studio_1/cues/*"
    assert k.prediction("cam_2") == "mocap/studio_1/prediction/cam_2"
    assert k.pose == "mocap/studio_1/pose"
    assert k.status("fusion") == "mocap/studio_1/status/fusion"
    for bad in ("a/b", "a*", "", "x y", "$x"):
        with pytest.raises(ValueError):
            Keys(bad)


def test_a_whole_image_silhouette_fits_a_cues_message_under_4_kb():
    """Worst case: the person fills the 640x480 image; the packed silhouette keeps its byte
    budget (the step grows) and the whole Cues message, the legs' attachments too, stays under 4 KB."""
    sil = CompactSilhouette.from_box_mask(np.ones((480, 640), np.uint8), (0, 0, 640, 480))
    assert sil.nbytes <= 3072 and sil.mask.all()
    cc = CameraCues("cam_1", 7, np.zeros((6, 2)), np.zeros((6, 2, 2)), np.ones(6), np.ones(6), (0, 0, 640, 480),
                    {"total": 1.0}, sil, np.zeros((2, 2)))
    payload = Cues("studio", cc, 1, 2, 3.0).to_msgpack()
    assert len(payload) <= 4096
    assert same(Cues.from_msgpack(payload).cues.silhouette, sil)


def test_a_silhouette_whose_bits_do_not_fit_its_width_is_a_counted_drop():
    cc = CameraCues("cam_1", 7, np.zeros((6, 2)), np.zeros((6, 2, 2)), np.ones(6), np.ones(6), (0, 0, 20, 20), {},
                    CompactSilhouette(0, 0, 2, np.ones((10, 10), bool)))
    env = msgpack.unpackb(Cues("studio", cc, 1, 2, 3.0).to_msgpack(), raw=False)
    env["b"]["sil"]["w"] = 30                       # 30 cells need 4 bytes a row, the rows have 2
    dec = Decoder("t")
    assert dec.decode(msgpack.packb(env, use_bin_type=True), Cues) is None
    assert dec.drops == {"cues": 1}


def test_legs_of_the_wrong_shape_are_a_counted_drop():
    cc = CameraCues("cam_1", 7, np.zeros((6, 2)), np.zeros((6, 2, 2)), np.ones(6), np.ones(6), leg_xy=np.zeros((2, 2)))
    env = msgpack.unpackb(Cues("studio", cc, 1, 2, 3.0).to_msgpack(), raw=False)
    env["b"]["leg"]["shape"] = [4]                 # 4 floats, but not (2, 2)
    dec = Decoder("t")
    assert dec.decode(msgpack.packb(env, use_bin_type=True), Cues) is None
    assert dec.drops == {"cues": 1}
