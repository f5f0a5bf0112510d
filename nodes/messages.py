"""Versioned msgpack messages of the capture service and their Zenoh key expressions.

Every message travels as a msgpack map ``{"v": SCHEMA_VERSION, "t": <type>, "b": <body>}``.
Arrays inside a body are ``{"dtype": "<f8", "shape": [..], "data": <bytes>}`` (always
little-endian, C order). Each message class is a frozen, slotted dataclass with an explicit
``to_msgpack()`` and ``from_msgpack(payload)``; ``from_msgpack`` raises ``MessageError``.

Nodes never call ``from_msgpack`` on the hot path directly: they use a ``Decoder``, which turns
every bad payload (wrong version, wrong type, oversized, truncated, malformed) into a counted,
logged drop and returns ``None`` — a bad message can never kill a node.

Key expressions (all under ``mocap/<rig>/``, defined only in ``Keys``):

=====================  ============  =====================================================
key                    message       publisher -> subscribers
=====================  ============  =====================================================
trigger                Trigger       sync -> workers, fusion, launcher
cues/<camera>          Cues          camera worker -> fusion, viewer
prediction/<camera>    Prediction    fusion -> camera worker
pose                   Pose          fusion -> recorder, viewer, launcher
status/<node>          Status        every node -> launcher
preview/<camera>       Preview       camera worker (JPEG, when a viewer runs) -> viewer
frame/<camera>         Frame         live camera worker (raw image) -> recorder
background/<camera>    Background    live camera worker -> recorder
=====================  ============  =====================================================

Times: ``*_mono_ns`` are ``time.monotonic_ns()`` (one clock for all processes of a host;
latency is only computed between stamps of one host), ``*_wall_ns`` are ``time.time_ns()``.
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from typing import ClassVar

import msgpack
import numpy as np

from mocap_rt.body.skeleton import N_BONE_VALUES
from mocap_rt.cues import N_CUES, SILHOUETTE_MAX_BYTES, CameraCues, CompactSilhouette, CuePrediction
from mocap_rt.names import JOINT_NAMES

log = logging.getLogger(__name__)

SCHEMA_VERSION = 3          # 2: Pose carries the bone lengths of its skeleton; 3: Cues may carry a silhouette
KEY_ROOT = "mocap"
# names that become key-expression chunks: no '/', '*', '$', '?', '#' or spaces
_NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
# dtypes an array field may carry (little-endian or byte-order free only)
_ALLOWED_DTYPES = frozenset({"<f8", "<f4", "<i8", "<i4", "|u1", "|b1", "<u2"})
N_JOINTS = len(JOINT_NAMES)
MAX_BVH_CHANNELS = 4096


class MessageError(ValueError):
    """A payload that is not a valid message of the expected type and version."""


def check_name(name: str, what: str = "name") -> str:
    """Return ``name`` if it is usable as one key-expression chunk, else raise ValueError."""
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ValueError(f"{what} {name!r} must match {_NAME_RE.pattern} (used in Zenoh keys)")
    return name


class Keys:
    """All key expressions of one rig, in one place."""

    def __init__(self, rig: str) -> None:
        self.rig = check_name(rig, "rig name")
        self.root = f"{KEY_ROOT}/{rig}"

    @property
    def trigger(self) -> str:
        return f"{self.root}/trigger"

    @property
    def pose(self) -> str:
        return f"{self.root}/pose"

    def cues(self, camera: str = "*") -> str:
        return f"{self.root}/cues/{camera}"

    def prediction(self, camera: str = "*") -> str:
        return f"{self.root}/prediction/{camera}"

    def status(self, node: str = "*") -> str:
        return f"{self.root}/status/{node}"

    def preview(self, camera: str = "*") -> str:
        return f"{self.root}/preview/{camera}"

    def frame(self, camera: str = "*") -> str:
        return f"{self.root}/frame/{camera}"

    def background(self, camera: str = "*") -> str:
        return f"{self.root}/background/{camera}"

    def all(self) -> str:
        return f"{self.root}/**"


# ---------------------------------------------------------------- field codecs

def encode_array(a: np.ndarray) -> dict:
    """numpy array -> msgpack-friendly dict, little-endian, C order."""
    a = np.asarray(a)
    if a.dtype.byteorder == ">" or (a.dtype.byteorder == "=" and np.little_endian is False):
        a = a.astype(a.dtype.newbyteorder("<"))
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}


def decode_array(d, name: str, shape: tuple[int | None, ...] | None = None,
                 dtype: str | None = None) -> np.ndarray:
    """msgpack dict -> numpy array (a writable copy), checking dtype, shape and byte count.

    shape : expected shape; ``None`` entries match any length.
    """
    if not isinstance(d, dict) or set(d) != {"dtype", "shape", "data"}:
        raise MessageError(f"field {name!r} is not an array record")
    dt, shp, data = d["dtype"], d["shape"], d["data"]
    if not isinstance(dt, str) or dt not in _ALLOWED_DTYPES:
        raise MessageError(f"field {name!r} has unsupported dtype {dt!r}")
    if dtype is not None and dt != dtype:
        raise MessageError(f"field {name!r} must have dtype {dtype}, got {dt}")
    if not isinstance(shp, list) or len(shp) > 6 or not all(_is_int(s) and 0 <= s < 2**31 for s in shp):
        raise MessageError(f"field {name!r} has a bad shape {shp!r}")
    if shape is not None and (len(shape) != len(shp)
                              or any(e is not None and e != s for e, s in zip(shape, shp))):
        raise MessageError(f"field {name!r} must have shape {shape}, got {tuple(shp)}")
    if not isinstance(data, bytes):
        raise MessageError(f"field {name!r} data is not bytes")
    itemsize = np.dtype(dt).itemsize
    if len(data) != math.prod(shp) * itemsize:         # exact: Python ints (np.prod: 30 us)
        raise MessageError(f"field {name!r}: {len(data)} bytes do not fit shape {shp} of {dt}")
    return np.frombuffer(data, dtype=dt).reshape(shp).copy()


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _int(b: dict, key: str, lo: int = -(2**63), hi: int = 2**63 - 1) -> int:
    v = b.get(key)
    if not _is_int(v) or not lo <= v <= hi:
        raise MessageError(f"field {key!r} must be an int in [{lo}, {hi}], got {v!r}")
    return v


def _float(b: dict, key: str) -> float:
    v = b.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MessageError(f"field {key!r} must be a number, got {type(v).__name__}")
    return float(v)


def _str(b: dict, key: str, name: bool = False) -> str:
    v = b.get(key)
    if not isinstance(v, str) or len(v) > 256:
        raise MessageError(f"field {key!r} must be a short string")
    if name and not _NAME_RE.match(v):
        raise MessageError(f"field {key!r} = {v!r} is not a valid name")
    return v


def _names(b: dict, key: str) -> tuple[str, ...]:
    v = b.get(key)
    if not isinstance(v, list) or len(v) > 256 or not all(isinstance(s, str) and _NAME_RE.match(s) for s in v):
        raise MessageError(f"field {key!r} must be a list of names")
    return tuple(v)


def _float_map(b: dict, key: str) -> dict[str, float]:
    v = b.get(key)
    if not isinstance(v, dict) or len(v) > 64:
        raise MessageError(f"field {key!r} must be a small map")
    out = {}
    for k, x in v.items():
        if not isinstance(k, str) or isinstance(x, bool) or not isinstance(x, (int, float)):
            raise MessageError(f"field {key!r} must map str -> number")
        out[k] = float(x)
    return out


def _bytes(b: dict, key: str) -> bytes:
    v = b.get(key)
    if not isinstance(v, bytes):
        raise MessageError(f"field {key!r} must be bytes")
    return v


# ---------------------------------------------------------------- envelope

class _Message:
    """Mixin: envelope encode/decode shared by every message class."""

    __slots__ = ()
    TYPE: ClassVar[str] = ""
    MAX_BYTES: ClassVar[int] = 0
    OPTIONAL_FIELDS: ClassVar[tuple[str, ...]] = ()   # body keys a message may leave out

    def body(self) -> dict:  # pragma: no cover - each class overrides
        raise NotImplementedError

    @classmethod
    def from_body(cls, b: dict):  # pragma: no cover - each class overrides
        raise NotImplementedError

    def to_msgpack(self) -> bytes:
        payload = msgpack.packb({"v": SCHEMA_VERSION, "t": self.TYPE, "b": self.body()}, use_bin_type=True)
        if len(payload) > self.MAX_BYTES:
            raise MessageError(f"{self.TYPE} message of {len(payload)} B exceeds {self.MAX_BYTES} B")
        return payload

    @classmethod
    def from_msgpack(cls, payload: bytes):
        if not isinstance(payload, (bytes, bytearray, memoryview)):
            raise MessageError(f"payload must be bytes, got {type(payload).__name__}")
        if len(payload) > cls.MAX_BYTES:
            raise MessageError(f"oversized {cls.TYPE} payload: {len(payload)} B > {cls.MAX_BYTES} B")
        try:
            env = msgpack.unpackb(payload, raw=False, strict_map_key=True, use_list=True)
        except Exception as exc:  # msgpack raises several types for truncated/garbage input
            raise MessageError(f"undecodable {cls.TYPE} payload ({type(exc).__name__}: {exc})") from None
        if not isinstance(env, dict) or set(env) != {"v", "t", "b"}:
            raise MessageError("payload is not a message envelope")
        if env["v"] != SCHEMA_VERSION:
            raise MessageError(f"schema version {env['v']!r} != {SCHEMA_VERSION}")
        if env["t"] != cls.TYPE:
            raise MessageError(f"message type {env['t']!r}, expected {cls.TYPE!r}")
        if not isinstance(env["b"], dict):
            raise MessageError("message body is not a map")
        try:
            return cls.from_body(env["b"])
        except MessageError:
            raise
        except (ValueError, TypeError, KeyError, IndexError, OverflowError) as exc:
            raise MessageError(f"bad {cls.TYPE} body: {exc}") from None


# ---------------------------------------------------------------- messages

@dataclass(frozen=True, slots=True)
class Trigger(_Message):
    """Sync -> everyone: capture frame ``frame`` now.

    period_ns : the nominal frame period (0 when free-running, ``--speed max``).
    """

    TYPE: ClassVar[str] = "trigger"
    MAX_BYTES: ClassVar[int] = 1024
    rig: str
    frame: int
    t_mono_ns: int
    t_wall_ns: int
    period_ns: int

    def body(self) -> dict:
        return {"rig": self.rig, "frame": self.frame, "t_mono_ns": self.t_mono_ns,
                "t_wall_ns": self.t_wall_ns, "period_ns": self.period_ns}

    @classmethod
    def from_body(cls, b: dict) -> "Trigger":
        return cls(_str(b, "rig", True), _int(b, "frame", 0), _int(b, "t_mono_ns", 0),
                   _int(b, "t_wall_ns", 0), _int(b, "period_ns", 0))


@dataclass(frozen=True, slots=True)
class Cues(_Message):
    """Camera worker -> fusion: one camera's cues for one triggered frame.

    The cues may carry the camera's compact silhouette (body key ``sil``: cell origin,
    step, width and the packed bits, <= ``SILHOUETTE_MAX_BYTES``; schema 3).

    t_trigger_mono_ns : the trigger's stamp (copied); t_grab_mono_ns : when the image was
    taken (replay: when it was read); processing_ms : grab + perception time.
    """

    TYPE: ClassVar[str] = "cues"
    MAX_BYTES: ClassVar[int] = 8192
    OPTIONAL_FIELDS: ClassVar[tuple[str, ...]] = ("sil",)
    rig: str
    cues: CameraCues
    t_trigger_mono_ns: int
    t_grab_mono_ns: int
    processing_ms: float

    @property
    def camera(self) -> str:
        return self.cues.camera

    @property
    def frame(self) -> int:
        return self.cues.frame

    def body(self) -> dict:
        c = self.cues
        return {"rig": self.rig, "camera": c.camera, "frame": int(c.frame), "xy": encode_array(c.xy),
                "cov": encode_array(c.cov), "area": encode_array(c.area),
                "confidence": encode_array(c.confidence), "bbox": [int(v) for v in c.bbox],
                "timings_ms": {str(k): float(v) for k, v in c.timings_ms.items()},
                "t_trigger_mono_ns": self.t_trigger_mono_ns, "t_grab_mono_ns": self.t_grab_mono_ns,
                "processing_ms": float(self.processing_ms),
                **({} if c.silhouette is None else {"sil": _silhouette_body(c.silhouette)})}

    @classmethod
    def from_body(cls, b: dict) -> "Cues":
        bbox = b.get("bbox")
        if not isinstance(bbox, list) or len(bbox) != 4 or not all(_is_int(v) for v in bbox):
            raise MessageError("field 'bbox' must be 4 ints")
        cues = CameraCues(_str(b, "camera", True), _int(b, "frame", 0),
                          decode_array(b.get("xy"), "xy", (N_CUES, 2), "<f8"),
                          decode_array(b.get("cov"), "cov", (N_CUES, 2, 2), "<f8"),
                          decode_array(b.get("area"), "area", (N_CUES,), "<f8"),
                          decode_array(b.get("confidence"), "confidence", (N_CUES,), "<f8"),
                          tuple(bbox), _float_map(b, "timings_ms"),
                          _silhouette_from_body(b["sil"]) if "sil" in b else None)
        return cls(_str(b, "rig", True), cues, _int(b, "t_trigger_mono_ns", 0),
                   _int(b, "t_grab_mono_ns", 0), _float(b, "processing_ms"))


# largest silhouette cell count per side a Cues message may carry
MAX_SILHOUETTE_CELLS = 4096


def _silhouette_body(sil: CompactSilhouette) -> dict:
    return {"x0": sil.x0, "y0": sil.y0, "step": sil.step, "w": int(sil.mask.shape[1]),
            "bits": encode_array(sil.packed())}


def _silhouette_from_body(d) -> CompactSilhouette:
    """The optional compact silhouette of a Cues body; sizes and shape checked."""
    if not isinstance(d, dict):
        raise MessageError("field 'sil' must be a map")
    x0, y0 = _int(d, "x0", -(2**20), 2**20), _int(d, "y0", -(2**20), 2**20)
    step, w = _int(d, "step", 1, 256), _int(d, "w", 0, MAX_SILHOUETTE_CELLS)
    bits = decode_array(d.get("bits"), "sil.bits", (None, (w + 7) // 8), "|u1")
    if bits.shape[0] > MAX_SILHOUETTE_CELLS or bits.nbytes > 2 * SILHOUETTE_MAX_BYTES:
        raise MessageError(f"field 'sil.bits' too large: {bits.shape}")
    return CompactSilhouette.from_packed(x0, y0, step, w, bits)


@dataclass(frozen=True, slots=True)
class Prediction(_Message):
    """Fusion -> camera worker: where the cues should be in ``prediction.frame`` (seed A.4)."""

    TYPE: ClassVar[str] = "prediction"
    MAX_BYTES: ClassVar[int] = 4096
    rig: str
    prediction: CuePrediction

    def body(self) -> dict:
        p = self.prediction
        return {"rig": self.rig, "camera": p.camera, "frame": int(p.frame), "xy": encode_array(p.xy),
                "visible": encode_array(p.visible), "radius_px": encode_array(p.radius_px)}

    @classmethod
    def from_body(cls, b: dict) -> "Prediction":
        p = CuePrediction(_str(b, "camera", True), _int(b, "frame", 0),
                          decode_array(b.get("xy"), "xy", (N_CUES, 2), "<f8"),
                          decode_array(b.get("visible"), "visible", (N_CUES,), "|b1"),
                          decode_array(b.get("radius_px"), "radius_px", (N_CUES,), "<f8"))
        return cls(_str(b, "rig", True), p)


@dataclass(frozen=True, slots=True)
class Pose(_Message):
    """Fusion -> recorder, viewer: the body for one frame.

    cues_3d : (6, 3) float64 metres, world (Z up), NaN where not reconstructed.
    cue_valid : (6,) bool.  joints : (20, 3) float64 metres, world, JOINT_NAMES order.
    bvh_frame : (n_channels,) float64 BVH motion values of the tracker's skeleton.
    cameras_used : cameras whose cues went into this frame; cameras_missing : rig cameras
    that did not answer before the deadline (dead or late).
    bones : (N_BONE_VALUES,) float64, ``BoneLengths.as_array()`` of the skeleton that
    ``joints`` and ``bvh_frame`` belong to (it changes once, when the tracker has estimated
    the subject's lengths; the recorder writes the BVH hierarchy from it).
    """

    TYPE: ClassVar[str] = "pose"
    MAX_BYTES: ClassVar[int] = 65536
    rig: str
    frame: int
    t_trigger_mono_ns: int
    t_pub_mono_ns: int
    cues_3d: np.ndarray
    cue_valid: np.ndarray
    joints: np.ndarray
    bvh_frame: np.ndarray
    cameras_used: tuple[str, ...]
    cameras_missing: tuple[str, ...]
    bones: np.ndarray
    timings_ms: dict = field(default_factory=dict)

    def body(self) -> dict:
        return {"rig": self.rig, "frame": self.frame, "t_trigger_mono_ns": self.t_trigger_mono_ns,
                "t_pub_mono_ns": self.t_pub_mono_ns,
                "cues_3d": encode_array(np.asarray(self.cues_3d, np.float64)),
                "cue_valid": encode_array(np.asarray(self.cue_valid, bool)),
                "joints": encode_array(np.asarray(self.joints, np.float64)),
                "bvh_frame": encode_array(np.asarray(self.bvh_frame, np.float64)),
                "cameras_used": list(self.cameras_used), "cameras_missing": list(self.cameras_missing),
                "bones": encode_array(np.asarray(self.bones, np.float64)),
                "timings_ms": {str(k): float(v) for k, v in self.timings_ms.items()}}

    @classmethod
    def from_body(cls, b: dict) -> "Pose":
        bvh = decode_array(b.get("bvh_frame"), "bvh_frame", (None,), "<f8")
        if bvh.shape[0] > MAX_BVH_CHANNELS:
            raise MessageError("field 'bvh_frame' is too long")
        return cls(_str(b, "rig", True), _int(b, "frame", 0), _int(b, "t_trigger_mono_ns", 0),
                   _int(b, "t_pub_mono_ns", 0),
                   decode_array(b.get("cues_3d"), "cues_3d", (N_CUES, 3), "<f8"),
                   decode_array(b.get("cue_valid"), "cue_valid", (N_CUES,), "|b1"),
                   decode_array(b.get("joints"), "joints", (N_JOINTS, 3), "<f8"), bvh,
                   _names(b, "cameras_used"), _names(b, "cameras_missing"),
                   decode_array(b.get("bones"), "bones", (N_BONE_VALUES,), "<f8"), _float_map(b, "timings_ms"))


@dataclass(frozen=True, slots=True)
class Status(_Message):
    """Every node -> launcher, about once a second.

    state : "starting" | "ready" | "running" | "stopping".  fps : frames handled per second
    over the last report interval.  processing_ms : median per-frame work.  frames : total
    frames handled.  drops : frames skipped or lost by this node.  decode_drops : received
    payloads rejected by its decoders.  cpu_s : process CPU seconds.  extra : free numbers.
    """

    TYPE: ClassVar[str] = "status"
    MAX_BYTES: ClassVar[int] = 16384
    STATES: ClassVar[tuple[str, ...]] = ("starting", "ready", "running", "stopping")
    rig: str
    node: str
    role: str
    pid: int
    t_mono_ns: int
    state: str
    fps: float
    processing_ms: float
    frames: int
    drops: int
    decode_drops: int
    cpu_s: float
    extra: dict = field(default_factory=dict)

    def body(self) -> dict:
        return {"rig": self.rig, "node": self.node, "role": self.role, "pid": self.pid,
                "t_mono_ns": self.t_mono_ns, "state": self.state, "fps": float(self.fps),
                "processing_ms": float(self.processing_ms), "frames": self.frames, "drops": self.drops,
                "decode_drops": self.decode_drops, "cpu_s": float(self.cpu_s),
                "extra": {str(k): float(v) for k, v in self.extra.items()}}

    @classmethod
    def from_body(cls, b: dict) -> "Status":
        state = _str(b, "state")
        if state not in cls.STATES:
            raise MessageError(f"unknown state {state!r}")
        return cls(_str(b, "rig", True), _str(b, "node", True), _str(b, "role", True),
                   _int(b, "pid", 0), _int(b, "t_mono_ns", 0), state, _float(b, "fps"),
                   _float(b, "processing_ms"), _int(b, "frames", 0), _int(b, "drops", 0),
                   _int(b, "decode_drops", 0), _float(b, "cpu_s"), _float_map(b, "extra"))


@dataclass(frozen=True, slots=True)
class Preview(_Message):
    """Camera worker -> viewer: a JPEG of the image a cue message came from."""

    TYPE: ClassVar[str] = "preview"
    MAX_BYTES: ClassVar[int] = 4 << 20
    rig: str
    camera: str
    frame: int
    jpeg: bytes

    def body(self) -> dict:
        return {"rig": self.rig, "camera": self.camera, "frame": self.frame, "jpeg": bytes(self.jpeg)}

    @classmethod
    def from_body(cls, b: dict) -> "Preview":
        return cls(_str(b, "rig", True), _str(b, "camera", True), _int(b, "frame", 0), _bytes(b, "jpeg"))


@dataclass(frozen=True, slots=True)
class Frame(_Message):
    """Live camera worker -> recorder: the raw image of one triggered frame.

    image : (H, W, 3) uint8 BGR.  t_grab_wall_ns : when the grabber received it.
    """

    TYPE: ClassVar[str] = "frame"
    MAX_BYTES: ClassVar[int] = 64 << 20
    rig: str
    camera: str
    frame: int
    t_grab_wall_ns: int
    image: np.ndarray

    def body(self) -> dict:
        return {"rig": self.rig, "camera": self.camera, "frame": self.frame,
                "t_grab_wall_ns": self.t_grab_wall_ns, "image": encode_array(np.asarray(self.image, np.uint8))}

    @classmethod
    def from_body(cls, b: dict) -> "Frame":
        return cls(_str(b, "rig", True), _str(b, "camera", True), _int(b, "frame", 0),
                   _int(b, "t_grab_wall_ns", 0), decode_array(b.get("image"), "image", (None, None, 3), "|u1"))


@dataclass(frozen=True, slots=True)
class Background(_Message):
    """Live camera worker -> recorder: the empty-scene frames its perceiver uses.

    images : (B, H, W, 3) uint8 BGR.
    """

    TYPE: ClassVar[str] = "background"
    MAX_BYTES: ClassVar[int] = 256 << 20
    rig: str
    camera: str
    images: np.ndarray

    def body(self) -> dict:
        return {"rig": self.rig, "camera": self.camera, "images": encode_array(np.asarray(self.images, np.uint8))}

    @classmethod
    def from_body(cls, b: dict) -> "Background":
        return cls(_str(b, "rig", True), _str(b, "camera", True),
                   decode_array(b.get("images"), "images", (None, None, None, 3), "|u1"))


MESSAGE_TYPES: tuple[type, ...] = (Trigger, Cues, Prediction, Pose, Status, Preview, Frame, Background)


# ---------------------------------------------------------------- decoder with drop accounting

class Decoder:
    """Decode payloads of one node; every rejected payload is a counted, logged drop.

    ``decode(payload, cls)`` accepts bytes or a ``zenoh.ZBytes`` (anything with
    ``to_bytes()``) and returns a message or ``None``. ``drops`` counts by reason
    (the message type that was expected); ``total_drops`` sums them.
    """

    LOG_FIRST = 5          # log every one of the first drops ...
    LOG_EVERY = 100        # ... then one in this many

    def __init__(self, node: str = "") -> None:
        self.node = node
        self.drops: dict[str, int] = {}

    @property
    def total_drops(self) -> int:
        return sum(self.drops.values())

    def decode(self, payload, cls: type):
        try:
            if hasattr(payload, "to_bytes"):
                payload = payload.to_bytes()
            return cls.from_msgpack(payload)
        except Exception as exc:  # never let a bad payload escape into a node's loop
            n = self.drops.get(cls.TYPE, 0) + 1
            self.drops[cls.TYPE] = n
            total = self.total_drops
            if total <= self.LOG_FIRST or total % self.LOG_EVERY == 0:
                log.warning("%s: dropped %s message (%d dropped so far): %s",
                            self.node or "node", cls.TYPE, total, exc)
            return None
