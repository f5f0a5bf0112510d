"""A small OSC 1.0 reader for the tests, independent of python-osc (which encodes the stream):
bundles, messages with s/i/f arguments, the VMC messages of a bundle, and what a Unity
receiver (EVMC4U) does with them: local position/rotation chained from the root."""

import struct

import numpy as np


def _osc_string(data: bytes, i: int) -> tuple[str, int]:
    end = data.index(b"\0", i)
    return data[i:end].decode(), (end + 4) & ~3          # padded to a multiple of 4 bytes


def decode_message(data: bytes) -> tuple[str, list]:
    address, i = _osc_string(data, 0)
    tags, i = _osc_string(data, i)
    assert tags.startswith(",")
    args = []
    for t in tags[1:]:
        if t == "s":
            v, i = _osc_string(data, i)
        elif t == "f":
            v, i = struct.unpack(">f", data[i:i + 4])[0], i + 4
        elif t == "i":
            v, i = struct.unpack(">i", data[i:i + 4])[0], i + 4
        else:
            raise AssertionError(f"unexpected OSC type tag {t!r}")
        args.append(v)
    assert i == len(data), "trailing bytes in a message"
    return address, args


def decode_bundle(data: bytes) -> list[tuple[str, list]]:
    assert data[:8] == b"#bundle\0" and len(data) % 4 == 0
    assert struct.unpack(">Q", data[8:16])[0] == 1        # time tag "immediately"
    out, i = [], 16
    while i < len(data):
        (size,) = struct.unpack(">i", data[i:i + 4])
        out.append(decode_message(data[i + 4:i + 4 + size]))
        i += 4 + size
    return out


def bones_of(data: bytes) -> tuple[dict, list, dict]:
    """(bones name -> (pos (3,), quat xyzw (4,)), root args, other messages)."""
    bones, root, other = {}, None, {}
    for address, args in decode_bundle(data):
        if address == "/VMC/Ext/Bone/Pos":
            bones[args[0]] = (np.array(args[1:4]), np.array(args[4:8]))
        elif address == "/VMC/Ext/Root/Pos":
            root = args
        else:
            other[address] = args
    return bones, root, other


# ------------------------------------------------------------ quaternion maths (Unity's)


def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def qrot(q, v):
    x, y, z, w = q
    u = np.array([x, y, z])
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def unity(p):
    """World (right-handed, Z up) -> Unity (left-handed, Y up, +Z forward = world +Y)."""
    p = np.asarray(p)
    return np.stack([p[..., 0], p[..., 2], p[..., 1]], axis=-1)


PARENT = {"Hips": None, "Spine": "Hips", "Chest": "Spine", "UpperChest": "Chest", "Neck": "UpperChest",
          "Head": "Neck", "LeftShoulder": "UpperChest", "LeftUpperArm": "LeftShoulder",
          "LeftLowerArm": "LeftUpperArm", "LeftHand": "LeftLowerArm", "RightShoulder": "UpperChest",
          "RightUpperArm": "RightShoulder", "RightLowerArm": "RightUpperArm", "RightHand": "RightLowerArm",
          "LeftUpperLeg": "Hips", "LeftLowerLeg": "LeftUpperLeg", "LeftFoot": "LeftLowerLeg",
          "RightUpperLeg": "Hips", "RightLowerLeg": "RightUpperLeg", "RightFoot": "RightLowerLeg"}
JOINT = {"Hips": "pelvis", "Spine": "torso", "Neck": "neck", "Head": "head", "LeftUpperArm": "shoulder_l",
         "LeftLowerArm": "elbow_l", "LeftHand": "wrist_l", "RightUpperArm": "shoulder_r",
         "RightLowerArm": "elbow_r", "RightHand": "wrist_r", "LeftUpperLeg": "hip_l", "LeftLowerLeg": "knee_l",
         "LeftFoot": "ankle_l", "RightUpperLeg": "hip_r", "RightLowerLeg": "knee_r", "RightFoot": "ankle_r"}


def receiver_fk(bones, root):
    """What a Unity receiver does with the bundle: world position and rotation of every bone."""
    world = {}
    for name in PARENT:                                   # parents first
        pos, q = bones[name]
        if PARENT[name] is None:
            P, W = np.array(root[1:4]), np.array(root[4:8])
        else:
            P, W = world[PARENT[name]]
        world[name] = (P + qrot(W, pos), qmul(W, q))
    return world
