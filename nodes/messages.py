"""The service's message schemas (one ``SCHEMA_VERSION``) and their Zenoh key expressions.

Each message class is a frozen, slotted dataclass with ``to_msgpack()`` and
``from_msgpack(payload)`` (raises ``MessageError``); the wire format (envelope
``{"v": SCHEMA_VERSION, "t": <type>, "b": <body>}``, array records, field checks) is
``nodes/codec.py``. The cue and prediction fields are those of ``CameraCues.to_dict`` and
``CuePrediction.to_dict`` (``mocap_rt/cues.py``), checked here on the way in.

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

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from mocap_rt.body.skeleton import N_BONE_VALUES
from mocap_rt.cues import N_CUES, SILHOUETTE_MAX_BYTES, CameraCues, CuePrediction
from mocap_rt.names import JOINT_NAMES
from nodes.codec import (Decoder, Envelope, MessageError, check_name, decode_array, encode_array,  # noqa: F401
                         encode_fields, get_bytes, get_float, get_float_map, get_int, get_names, get_str, is_int)

SCHEMA_VERSION = 7          # 2: Pose carries the bone lengths of its skeleton; 3: Cues may carry a silhouette;
                            # 4: ... and where the legs meet the shoes; 5: Prediction may carry the offsets
                            # of the parts' visible centres; 6: ... and the shapes of the visible shoes;
                            # 7: the bone lengths carry where the torso cue lies on the trunk
KEY_ROOT = "mocap"
N_JOINTS = len(JOINT_NAMES)
MAX_BVH_CHANNELS = 4096


def _sub_key(kind: str):
    """A ``Keys`` method: ``<root>/<kind>/<name>`` for one camera or node, ``"*"`` for all."""
    def key(self, name: str = "*") -> str:
        return f"{self.root}/{kind}/{name}"
    key.__name__ = key.__qualname__ = kind
    return key


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

    # per camera (per node for ``status``); ``"*"``: all of them
    cues = _sub_key("cues")
    prediction = _sub_key("prediction")
    status = _sub_key("status")
    preview = _sub_key("preview")
    frame = _sub_key("frame")
    background = _sub_key("background")


# ---------------------------------------------------------------- messages

class Message(Envelope):
    """Base of the messages of this schema version."""

    __slots__ = ()
    VERSION: ClassVar[int] = SCHEMA_VERSION


@dataclass(frozen=True, slots=True)
class Trigger(Message):
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
        return cls(get_str(b, "rig", True), get_int(b, "frame", 0), get_int(b, "t_mono_ns", 0),
                   get_int(b, "t_wall_ns", 0), get_int(b, "period_ns", 0))


@dataclass(frozen=True, slots=True)
class Cues(Message):
    """Camera worker -> fusion: one camera's cues for one triggered frame.

    The cues may carry the camera's compact silhouette (body key ``sil``: cell origin,
    step, width and the packed bits, <= ``SILHOUETTE_MAX_BYTES``; schema 3) and where the legs
    meet the two shoe blobs (``leg``: (2, 2) float64 px, NaN = not measured; schema 4).

    t_trigger_mono_ns : the trigger's stamp (copied); t_grab_mono_ns : when the image was
    taken (replay: when it was read); processing_ms : grab + perception time.
    """

    TYPE: ClassVar[str] = "cues"
    MAX_BYTES: ClassVar[int] = 8192
    OPTIONAL_FIELDS: ClassVar[tuple[str, ...]] = ("sil", "leg")
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
        fields = encode_fields(self.cues.to_dict())
        optional = {k: fields.pop(k) for k in self.OPTIONAL_FIELDS if k in fields}
        return {"rig": self.rig, **fields, "t_trigger_mono_ns": self.t_trigger_mono_ns,
                "t_grab_mono_ns": self.t_grab_mono_ns, "processing_ms": float(self.processing_ms), **optional}

    @classmethod
    def from_body(cls, b: dict) -> "Cues":
        bbox = b.get("bbox")
        if not isinstance(bbox, list) or len(bbox) != 4 or not all(is_int(v) for v in bbox):
            raise MessageError("field 'bbox' must be 4 ints")
        fields = {"camera": get_str(b, "camera", True), "frame": get_int(b, "frame", 0),
                  "xy": decode_array(b.get("xy"), "xy", (N_CUES, 2), "<f8"),
                  "cov": decode_array(b.get("cov"), "cov", (N_CUES, 2, 2), "<f8"),
                  "area": decode_array(b.get("area"), "area", (N_CUES,), "<f8"),
                  "confidence": decode_array(b.get("confidence"), "confidence", (N_CUES,), "<f8"),
                  "bbox": bbox, "timings_ms": get_float_map(b, "timings_ms")}
        if "sil" in b:
            fields["sil"] = _silhouette_fields(b["sil"])
        if "leg" in b:
            fields["leg"] = decode_array(b["leg"], "leg", (2, 2), "<f8")
        return cls(get_str(b, "rig", True), CameraCues.from_dict(fields), get_int(b, "t_trigger_mono_ns", 0),
                   get_int(b, "t_grab_mono_ns", 0), get_float(b, "processing_ms"))


# largest silhouette cell count per side a Cues message may carry
MAX_SILHOUETTE_CELLS = 4096


def _silhouette_fields(d) -> dict:
    """The optional compact silhouette of a Cues body (``CompactSilhouette.to_dict`` fields),
    sizes and shape checked."""
    if not isinstance(d, dict):
        raise MessageError("field 'sil' must be a map")
    w = get_int(d, "w", 0, MAX_SILHOUETTE_CELLS)
    bits = decode_array(d.get("bits"), "sil.bits", (None, (w + 7) // 8), "|u1")
    if bits.shape[0] > MAX_SILHOUETTE_CELLS or bits.nbytes > 2 * SILHOUETTE_MAX_BYTES:
        raise MessageError(f"field 'sil.bits' too large: {bits.shape}")
    return {"x0": get_int(d, "x0", -(2**20), 2**20), "y0": get_int(d, "y0", -(2**20), 2**20),
            "step": get_int(d, "step", 1, 256), "w": w, "bits": bits}


@dataclass(frozen=True, slots=True)
class Prediction(Message):
    """Fusion -> camera worker: where the cues should be in ``prediction.frame`` (seed A.4),
    since schema 5 (optional ``offset_px``) where the head's and hands' visible centres lie
    from their cue points, and since schema 6 (optional ``shape_px``) the covariances of the
    visible shoes (``mocap_rt.body.visible``)."""

    TYPE: ClassVar[str] = "prediction"
    MAX_BYTES: ClassVar[int] = 4096
    OPTIONAL_FIELDS: ClassVar[tuple[str, ...]] = ("offset_px", "shape_px")
    rig: str
    prediction: CuePrediction

    def body(self) -> dict:
        return {"rig": self.rig, **encode_fields(self.prediction.to_dict())}

    @classmethod
    def from_body(cls, b: dict) -> "Prediction":
        fields = {"camera": get_str(b, "camera", True), "frame": get_int(b, "frame", 0),
                  "xy": decode_array(b.get("xy"), "xy", (N_CUES, 2), "<f8"),
                  "visible": decode_array(b.get("visible"), "visible", (N_CUES,), "|b1"),
                  "radius_px": decode_array(b.get("radius_px"), "radius_px", (N_CUES,), "<f8")}
        if "offset_px" in b:
            fields["offset_px"] = decode_array(b["offset_px"], "offset_px", (N_CUES, 2), "<f8")
        if "shape_px" in b:
            fields["shape_px"] = decode_array(b["shape_px"], "shape_px", (N_CUES, 2, 2), "<f8")
        return cls(get_str(b, "rig", True), CuePrediction.from_dict(fields))


@dataclass(frozen=True, slots=True)
class Pose(Message):
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
        return cls(get_str(b, "rig", True), get_int(b, "frame", 0), get_int(b, "t_trigger_mono_ns", 0),
                   get_int(b, "t_pub_mono_ns", 0),
                   decode_array(b.get("cues_3d"), "cues_3d", (N_CUES, 3), "<f8"),
                   decode_array(b.get("cue_valid"), "cue_valid", (N_CUES,), "|b1"),
                   decode_array(b.get("joints"), "joints", (N_JOINTS, 3), "<f8"), bvh,
                   get_names(b, "cameras_used"), get_names(b, "cameras_missing"),
                   decode_array(b.get("bones"), "bones", (N_BONE_VALUES,), "<f8"), get_float_map(b, "timings_ms"))


@dataclass(frozen=True, slots=True)
class Status(Message):
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
        state = get_str(b, "state")
        if state not in cls.STATES:
            raise MessageError(f"unknown state {state!r}")
        return cls(get_str(b, "rig", True), get_str(b, "node", True), get_str(b, "role", True),
                   get_int(b, "pid", 0), get_int(b, "t_mono_ns", 0), state, get_float(b, "fps"),
                   get_float(b, "processing_ms"), get_int(b, "frames", 0), get_int(b, "drops", 0),
                   get_int(b, "decode_drops", 0), get_float(b, "cpu_s"), get_float_map(b, "extra"))


@dataclass(frozen=True, slots=True)
class Preview(Message):
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
        return cls(get_str(b, "rig", True), get_str(b, "camera", True), get_int(b, "frame", 0), get_bytes(b, "jpeg"))


@dataclass(frozen=True, slots=True)
class Frame(Message):
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
        return cls(get_str(b, "rig", True), get_str(b, "camera", True), get_int(b, "frame", 0),
                   get_int(b, "t_grab_wall_ns", 0), decode_array(b.get("image"), "image", (None, None, 3), "|u1"))


@dataclass(frozen=True, slots=True)
class Background(Message):
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
        return cls(get_str(b, "rig", True), get_str(b, "camera", True),
                   decode_array(b.get("images"), "images", (None, None, None, 3), "|u1"))


MESSAGE_TYPES: tuple[type, ...] = (Trigger, Cues, Prediction, Pose, Status, Preview, Frame, Background)
