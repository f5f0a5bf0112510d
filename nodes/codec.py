"""The wire format of the service's messages: envelope, array and field codecs, drop-counting decoder.

A message travels as a msgpack map ``{"v": VERSION, "t": <type>, "b": <body>}``; arrays in a
body are ``{"dtype": "<f8", "shape": [..], "data": <bytes>}`` (little-endian, C order). The
schemas themselves (and their version) are ``nodes/messages.py``; this module knows no message.
"""

from __future__ import annotations

import logging
import math
import re
from typing import ClassVar

import msgpack
import numpy as np

log = logging.getLogger(__name__)

# names that become key-expression chunks: no '/', '*', '$', '?', '#' or spaces
NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
# dtypes an array field may carry (little-endian or byte-order free only)
_ALLOWED_DTYPES = frozenset({"<f8", "<f4", "<i8", "<i4", "|u1", "|b1", "<u2"})


class MessageError(ValueError):
    """A payload that is not a valid message of the expected type and version."""


def check_name(name: str, what: str = "name") -> str:
    """Return ``name`` if it is usable as one key-expression chunk, else raise ValueError."""
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise ValueError(f"{what} {name!r} must match {NAME_RE.pattern} (used in Zenoh keys)")
    return name


# ---------------------------------------------------------------- field codecs

def encode_array(a: np.ndarray) -> dict:
    """numpy array -> msgpack-friendly dict, little-endian, C order."""
    a = np.asarray(a)
    if a.dtype.byteorder == ">" or (a.dtype.byteorder == "=" and np.little_endian is False):
        a = a.astype(a.dtype.newbyteorder("<"))
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}


def encode_fields(d: dict) -> dict:
    """A dict of fields with every numpy array (also in nested dicts) as an array record."""
    return {k: encode_array(v) if isinstance(v, np.ndarray) else encode_fields(v) if isinstance(v, dict) else v
            for k, v in d.items()}


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
    if not isinstance(shp, list) or len(shp) > 6 or not all(is_int(s) and 0 <= s < 2**31 for s in shp):
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


def is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def get_int(b: dict, key: str, lo: int = -(2**63), hi: int = 2**63 - 1) -> int:
    v = b.get(key)
    if not is_int(v) or not lo <= v <= hi:
        raise MessageError(f"field {key!r} must be an int in [{lo}, {hi}], got {v!r}")
    return v


def get_float(b: dict, key: str) -> float:
    v = b.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MessageError(f"field {key!r} must be a number, got {type(v).__name__}")
    return float(v)


def get_str(b: dict, key: str, name: bool = False) -> str:
    v = b.get(key)
    if not isinstance(v, str) or len(v) > 256:
        raise MessageError(f"field {key!r} must be a short string")
    if name and not NAME_RE.match(v):
        raise MessageError(f"field {key!r} = {v!r} is not a valid name")
    return v


def get_names(b: dict, key: str) -> tuple[str, ...]:
    v = b.get(key)
    if not isinstance(v, list) or len(v) > 256 or not all(isinstance(s, str) and NAME_RE.match(s) for s in v):
        raise MessageError(f"field {key!r} must be a list of names")
    return tuple(v)


def get_float_map(b: dict, key: str) -> dict[str, float]:
    v = b.get(key)
    if not isinstance(v, dict) or len(v) > 64:
        raise MessageError(f"field {key!r} must be a small map")
    out = {}
    for k, x in v.items():
        if not isinstance(k, str) or isinstance(x, bool) or not isinstance(x, (int, float)):
            raise MessageError(f"field {key!r} must map str -> number")
        out[k] = float(x)
    return out


def get_bytes(b: dict, key: str) -> bytes:
    v = b.get(key)
    if not isinstance(v, bytes):
        raise MessageError(f"field {key!r} must be bytes")
    return v


# ---------------------------------------------------------------- envelope

class Envelope:
    """Mixin: envelope encode/decode shared by every message class (``VERSION``: its schema's)."""

    __slots__ = ()
    VERSION: ClassVar[int] = 0
    TYPE: ClassVar[str] = ""
    MAX_BYTES: ClassVar[int] = 0
    OPTIONAL_FIELDS: ClassVar[tuple[str, ...]] = ()   # body keys a message may leave out

    def body(self) -> dict:  # pragma: no cover - each class overrides
        raise NotImplementedError

    @classmethod
    def from_body(cls, b: dict):  # pragma: no cover - each class overrides
        raise NotImplementedError

    def to_msgpack(self) -> bytes:
        payload = msgpack.packb({"v": self.VERSION, "t": self.TYPE, "b": self.body()}, use_bin_type=True)
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
        if env["v"] != cls.VERSION:
            raise MessageError(f"schema version {env['v']!r} != {cls.VERSION}")
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
