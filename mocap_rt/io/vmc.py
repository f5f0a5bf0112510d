"""VMC protocol (OSC over UDP) packets of a humanoid pose, and stream targets.

The VMC protocol (https://protocol.vmc.info, "Performer -> Marionette") moves a VRM avatar:
per frame one OSC bundle holding

* ``/VMC/Ext/Root/Pos (s)"root" (f)p.x p.y p.z (f)q.x q.y q.z q.w`` — the model root;
* ``/VMC/Ext/Bone/Pos (s)<HumanBodyBones name> (f)p.x p.y p.z (f)q.x q.y q.z q.w`` per bone —
  the bone's ``localPosition`` / ``localRotation`` (Unity axes, metres; see
  ``mocap_rt.body.humanoid`` for the T-pose and the axes);
* ``/VMC/Ext/OK (i)loaded=1 (i)calibration state=3 (calibrated) (i)calibration mode=0``;
* ``/VMC/Ext/T (f)time`` — the sender's relative time, seconds.

Receivers (EVMC4U's ``ExternalReceiver``, VSeeFace, Warudo, VMC4UE, VMC4B) listen on UDP
39539 by default. Packets are encoded with python-osc's OSC type writers (float32 arguments,
bundle time tag "immediately").
"""

from __future__ import annotations

import ipaddress
import socket
from functools import lru_cache

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY
from pythonosc.parsing import osc_types

from mocap_rt.body.humanoid import BONE_NAMES, HumanoidPose

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 39539
CALIBRATED = 3           # /VMC/Ext/OK calibration state "Calibrated"


@lru_cache(maxsize=256)
def _head(address: str, typetags: str, name: str | None) -> bytes:
    """Address, type tags and (VMC messages start with one) the leading string argument."""
    head = osc_types.write_string(address) + osc_types.write_string("," + typetags)
    return head if name is None else head + osc_types.write_string(name)


def _message(address: str, typetags: str, args) -> bytes:
    """One OSC message: address, type tags (``s``, ``i``, ``f``), arguments; a leading string
    argument (bone name) is encoded once and cached with the address."""
    name = args[0] if typetags[:1] == "s" else None
    out = [_head(address, typetags, name)]
    for tag, value in zip(typetags[name is not None:], args[name is not None:]):
        out.append(_WRITERS[tag](value))
    return b"".join(out)


_WRITERS = {"s": osc_types.write_string, "i": osc_types.write_int, "f": osc_types.write_float}
_POS_TAGS = "s" + "f" * 7


def vmc_bundle(pose: HumanoidPose, time_s: float) -> bytes:
    """One OSC bundle (bytes) of ``pose`` at sender time ``time_s`` (seconds).

    python-osc's own type writers encode every field; its ``OscMessageBuilder`` /
    ``OscBundleBuilder`` are not used because they parse every datagram back after building
    it (5 ms per bundle on the 2-core machine, against a 1 ms budget).
    """
    contents = [_message("/VMC/Ext/Root/Pos", _POS_TAGS,
                         ["root", *pose.root_position.tolist(), *pose.root_rotation.tolist()])]
    for name, p, q in zip(BONE_NAMES, pose.local_positions.tolist(), pose.local_rotations.tolist()):
        contents.append(_message("/VMC/Ext/Bone/Pos", _POS_TAGS, [name, *p, *q]))
    contents.append(_message("/VMC/Ext/OK", "iii", [1, CALIBRATED, 0]))
    contents.append(_message("/VMC/Ext/T", "f", [float(time_s)]))
    out = [osc_types.write_string("#bundle"), osc_types.write_date(IMMEDIATELY)]
    for c in contents:
        out += [osc_types.write_int(len(c)), c]
    return b"".join(out)


class VmcEncoder:
    """``vmc_bundle`` for one skeleton at a fraction of the cost, for the stream's hot path.

    Per skeleton (``local_positions`` (B, 3) metres, Unity axes, e.g. ``HumanoidRig.local_positions``)
    the whole bundle is built once by ``vmc_bundle`` (python-osc's writers); per pose only
    the float fields that change — root position, bone rotations, time — are written in
    place, as big-endian float32 like python-osc writes them, so ``encode`` returns the very
    bytes of ``vmc_bundle`` (tested). Not thread-safe: one encoder per sending thread.
    """

    def __init__(self, local_positions: np.ndarray) -> None:
        self.local_positions = np.asarray(local_positions, np.float64)
        n = len(BONE_NAMES)
        if self.local_positions.shape != (n, 3):
            raise ValueError(f"VmcEncoder: local_positions must be ({n}, 3), got {self.local_positions.shape}")
        rest = HumanoidPose(np.zeros(3), np.array([0.0, 0, 0, 1]), self.local_positions, np.tile([0.0, 0, 0, 1], (n, 1)))
        self._buf = bytearray(vmc_bundle(rest, 0.0))
        self._f32 = np.frombuffer(self._buf, ">f4")            # every field is 4-byte aligned
        ends, pos = [], 16                                      # "#bundle\0" + time tag
        while pos < len(self._buf):
            size = int.from_bytes(self._buf[pos:pos + 4], "big")
            ends.append((pos + 4 + size) // 4)                  # message end, in float32 slots
            pos += 4 + size
        root = ends[0] - 7                                      # Root/Pos: "root" p.xyz q.xyzw
        self._root = np.arange(root, root + 3)
        self._quats = (np.array(ends[1:1 + n])[:, None] - 4 + np.arange(4)).reshape(-1)   # (B * 4,)
        self._time = ends[-1] - 1                               # /VMC/Ext/T's one float

    def encode(self, root_position: np.ndarray, local_rotations: np.ndarray, time_s: float) -> bytearray:
        """The bundle of a pose: root_position (3,) pelvis, Unity axes, metres; local_rotations
        (B, 4) x, y, z, w in ``BONE_NAMES`` order; ``time_s`` seconds. The returned buffer is
        reused by the next call (send it before encoding the next pose)."""
        self._f32[self._root] = root_position
        self._f32[self._quats] = np.asarray(local_rotations).reshape(-1)
        self._f32[self._time] = time_s
        return self._buf

    def encode_pose(self, pose: HumanoidPose, time_s: float) -> bytearray:
        """``encode`` of a ``HumanoidPose`` of this skeleton (ValueError for another skeleton's)."""
        if pose.local_positions is not self.local_positions and not np.array_equal(pose.local_positions,
                                                                                   self.local_positions):
            raise ValueError("VmcEncoder: the pose's bone positions are not this encoder's skeleton")
        return self.encode(pose.root_position, pose.local_rotations, time_s)


def parse_vmc_target(spec: str, allow_remote: bool = False) -> tuple[str, int]:
    """``"vmc"``, ``"vmc:HOST"``, ``"vmc:HOST:PORT"`` or ``"vmc::PORT"`` -> (IP address, port).

    HOST defaults to 127.0.0.1 and PORT to 39539. A HOST that is not a loopback address is a
    ValueError unless ``allow_remote`` (the stream is unauthenticated UDP: sending it off the
    host must be asked for).
    """
    kind, _, rest = str(spec).partition(":")
    if kind != "vmc":
        raise ValueError(f"--stream {spec!r}: expected vmc[:HOST[:PORT]]")
    parts = rest.split(":") if rest else []
    if len(parts) > 2:
        raise ValueError(f"--stream {spec!r}: expected vmc[:HOST[:PORT]] (IPv6: not supported)")
    host = (parts[0] if parts else "") or DEFAULT_HOST
    port_text = parts[1] if len(parts) == 2 else ""
    try:
        port = int(port_text) if port_text else DEFAULT_PORT
    except ValueError:
        raise ValueError(f"--stream {spec!r}: port {port_text!r} is not a number") from None
    if not 0 < port < 65536:
        raise ValueError(f"--stream {spec!r}: port {port} out of range")
    try:
        addr = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][0]
    except socket.gaierror as exc:
        raise ValueError(f"--stream {spec!r}: cannot resolve host {host!r} ({exc})") from None
    if not ipaddress.ip_address(addr).is_loopback and not allow_remote:
        raise ValueError(f"--stream {spec!r}: {host} ({addr}) is not this host; sending poses over the "
                         f"network must be asked for with --allow-remote-stream")
    return addr, port
