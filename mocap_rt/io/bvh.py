"""BVH motion files: the skeleton and clip types, the reader, forward kinematics and
resampling (writing: ``mocap_rt.io.bvh_writer``).

A BVH file is a joint hierarchy (offsets in the parent's frame, channel lists) plus a
motion table of ``F`` frames by ``n_channels`` values. Rotation channels are Euler
angles in degrees, applied in the order they are listed (intrinsic): channels
``Zrotation Yrotation Xrotation`` mean ``R = Rz @ Ry @ Rx``, and a child point ``p``
maps to the parent frame as ``T + R @ p``. When a joint has position channels they
replace its offset (the usual reading, used by CMU roots and the Bandai-Namco files,
whose per-joint position channels equal their offsets).

Positions come out in the file's own units and axes (CMU: Y up, 1 unit = 0.056444 m;
Bandai-Namco: Y up, cm); ``mocap_rt.studio.body_map`` converts to the world frame.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.config import FileFormatError

log = logging.getLogger(__name__)

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
_VALID_CHANNELS = POSITION_CHANNELS + ROTATION_CHANNELS
# offsets (cm or m) and angles (deg) of any real clip are far below this; 1e300 or NaN in a
# clip would put NaN joints in a recording
MAX_BVH_VALUE = 1e6


class BvhError(FileFormatError):
    """A BVH file that cannot be parsed; the message names the file and line."""


@dataclass(frozen=True)
class BvhJoint:
    """One joint of the hierarchy.

    name : joint name as in the file.
    parent : index of the parent joint, -1 for the root.
    offset : (3,) float64, position in the parent's frame (file units).
    channels : channel names in file order, e.g. ("Zrotation", "Yrotation", "Xrotation").
    end_site : (3,) float64 offset of the joint's End Site in its own frame, or None.
    """

    name: str
    parent: int
    offset: np.ndarray
    channels: tuple[str, ...]
    end_site: np.ndarray | None = None


@dataclass(frozen=True)
class BvhSkeleton:
    """The hierarchy, joints in file order (every parent precedes its children)."""

    joints: tuple[BvhJoint, ...]
    _index: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_index", {j.name: i for i, j in enumerate(self.joints)})
        for i, j in enumerate(self.joints):
            if not -1 <= j.parent < i:
                raise ValueError(f"joint {j.name!r}: parent index {j.parent} must precede it")

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def parents(self) -> np.ndarray:
        """(J,) int, parent index, -1 for the root."""
        return np.array([j.parent for j in self.joints], dtype=np.int64)

    @property
    def offsets(self) -> np.ndarray:
        """(J, 3) float64 offsets in the parent frame, file units."""
        return np.array([j.offset for j in self.joints], dtype=np.float64).reshape(-1, 3)

    @property
    def n_channels(self) -> int:
        return sum(len(j.channels) for j in self.joints)

    @property
    def channel_starts(self) -> np.ndarray:
        """(J,) int, first motion column of each joint."""
        counts = [len(j.channels) for j in self.joints]
        return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)

    @property
    def end_site_joints(self) -> list[int]:
        """Indices of the joints that carry an End Site, in file order."""
        return [i for i, j in enumerate(self.joints) if j.end_site is not None]

    @property
    def end_site_names(self) -> list[str]:
        """Names for the end sites: ``<joint>_end``."""
        return [self.joints[i].name + "_end" for i in self.end_site_joints]

    def index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"no joint named {name!r} in the skeleton") from None

    def __len__(self) -> int:
        return len(self.joints)


@dataclass(frozen=True)
class BvhClip:
    """A parsed file: ``motion`` (F, n_channels) float64, ``frame_time_s`` seconds."""

    skeleton: BvhSkeleton
    motion: np.ndarray
    frame_time_s: float

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time_s


# ----------------------------------------------------------------------------- reading

def _tokens(text: str):
    """Yield (token, line_number) over whitespace-separated tokens (CRLF/LF agnostic)."""
    for lineno, line in enumerate(text.splitlines(), start=1):
        for tok in line.split():
            yield tok, lineno


def _parse_hierarchy(text: str, where: str) -> tuple[BvhSkeleton, int]:
    """Parse the HIERARCHY section; returns the skeleton and the line where MOTION is."""
    toks = _tokens(text)
    joints: list[dict] = []
    stack: list[int] = []  # open joint indices; -2 marks an open End Site
    lineno = 0

    def nxt(expect: str | None = None) -> str:
        nonlocal lineno
        try:
            tok, lineno = next(toks)
        except StopIteration:
            raise BvhError(f"{where}: unexpected end of file in the hierarchy") from None
        if expect is not None and tok != expect:
            raise BvhError(f"{where}, line {lineno}: expected {expect!r}, got {tok!r}")
        return tok

    def floats(n: int) -> np.ndarray:
        vals = []
        for _ in range(n):
            tok = nxt()
            try:
                vals.append(float(tok))
            except ValueError:
                raise BvhError(f"{where}, line {lineno}: expected a number, got {tok!r}") from None
        return np.array(vals, dtype=np.float64)

    tok = nxt()
    if tok != "HIERARCHY":
        raise BvhError(f"{where}, line {lineno}: file must start with HIERARCHY, got {tok!r}")
    nxt("ROOT")
    pending_parent = -1
    pending_name = nxt()
    pending_end = False
    while True:
        nxt("{")
        if pending_end:
            nxt("OFFSET")
            off = floats(3)
            if pending_parent < 0:
                raise BvhError(f"{where}, line {lineno}: End Site outside a joint")
            if joints[pending_parent]["end_site"] is not None:
                log.debug("%s:%d: joint %s has several End Sites; keeping the first",
                          where, lineno, joints[pending_parent]["name"])
            else:
                joints[pending_parent]["end_site"] = off
            nxt("}")
        else:
            nxt("OFFSET")
            off = floats(3)
            nxt("CHANNELS")
            try:
                n = int(nxt())
            except ValueError:
                raise BvhError(f"{where}, line {lineno}: CHANNELS count is not an integer") from None
            chans = tuple(nxt() for _ in range(n))
            for c in chans:
                if c not in _VALID_CHANNELS:
                    raise BvhError(f"{where}, line {lineno}: unknown channel {c!r}")
            joints.append({"name": pending_name, "parent": pending_parent, "offset": off,
                           "channels": chans, "end_site": None})
            stack.append(len(joints) - 1)
        # children or close
        while True:
            tok = nxt()
            if tok == "}":
                if not stack:
                    raise BvhError(f"{where}, line {lineno}: unbalanced '}}'")
                stack.pop()
                if not stack:
                    tok = nxt()
                    if tok == "ROOT":
                        raise BvhError(f"{where}, line {lineno}: several ROOTs are not supported")
                    if tok != "MOTION":
                        raise BvhError(f"{where}, line {lineno}: expected MOTION, got {tok!r}")
                    skel = BvhSkeleton(tuple(
                        BvhJoint(j["name"], j["parent"], j["offset"], j["channels"], j["end_site"])
                        for j in joints))
                    return skel, lineno
                continue
            if tok == "JOINT":
                pending_parent, pending_name, pending_end = stack[-1], nxt(), False
                break
            if tok == "End":
                nxt("Site")
                pending_parent, pending_end = stack[-1], True
                break
            raise BvhError(f"{where}, line {lineno}: expected JOINT, End Site or '}}', got {tok!r}")


def read_bvh(path: str | Path) -> BvhClip:
    """Read a BVH file; raises ``BvhError`` naming the file and line on bad input.

    A file whose motion table holds more complete lines than ``Frames:`` declares keeps
    the declared count (a stream writer killed between writing and counting); fewer
    lines is an error.
    """
    path = Path(path)
    where = str(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise FileNotFoundError(f"BVH file not found: {path}") from None
    skeleton, motion_line = _parse_hierarchy(text, where)
    lines = text.splitlines()[motion_line:]  # after the MOTION line
    header: dict[str, str] = {}
    i = 0
    while i < len(lines) and len(header) < 2:
        line = lines[i].strip()
        i += 1
        if not line:
            continue
        key, _, value = line.partition(":")
        key = " ".join(key.split())
        if key not in ("Frames", "Frame Time"):
            raise BvhError(f"{where}, line {motion_line + i}: expected 'Frames:' / 'Frame Time:', got {line[:40]!r}")
        header[key] = value.strip()
    if len(header) < 2:
        raise BvhError(f"{where}: MOTION section lacks 'Frames:' or 'Frame Time:'")
    try:
        n_frames = int(header["Frames"])
        frame_time = float(header["Frame Time"])
    except ValueError:
        raise BvhError(f"{where}: bad 'Frames:' or 'Frame Time:' value {header}") from None
    if not (math.isfinite(frame_time) and frame_time > 0) or n_frames < 0:
        raise BvhError(f"{where}: Frames must be >= 0 and Frame Time a number > 0, got {header}")
    n_ch = skeleton.n_channels
    data_lines = [ln for ln in lines[i:] if ln.strip()]
    if len(data_lines) < n_frames:
        raise BvhError(f"{where}: 'Frames: {n_frames}' but only {len(data_lines)} motion lines "
                       "(truncated file?)")
    if len(data_lines) > n_frames:
        log.warning("%s: %d motion lines beyond the declared %d frames ignored",
                    where, len(data_lines) - n_frames, n_frames)
        data_lines = data_lines[:n_frames]
    try:
        flat = np.array(" ".join(data_lines).split(), dtype=np.float64)
    except ValueError:
        flat = None
    if flat is None or flat.size != n_frames * n_ch:
        first = motion_line + i + 1
        for k, ln in enumerate(data_lines):
            parts = ln.split()
            if len(parts) != n_ch:
                raise BvhError(f"{where}: motion line {k + 1} has {len(parts)} values, "
                               f"the hierarchy has {n_ch} channels")
            try:
                [float(p) for p in parts]
            except ValueError:
                raise BvhError(f"{where}: motion line {k + 1} (after line {first}) has a non-number") from None
        raise BvhError(f"{where}: motion table malformed")
    motion = flat.reshape(n_frames, n_ch)
    _check_magnitudes(where, skeleton, motion)
    return BvhClip(skeleton, motion, frame_time)


def _check_magnitudes(where: str, skeleton: BvhSkeleton, motion: np.ndarray) -> None:
    """BvhError naming the first offset or motion value that is NaN/inf or beyond ``MAX_BVH_VALUE``."""
    offsets = skeleton.offsets
    bad = ~np.isfinite(offsets) | (np.abs(offsets) > MAX_BVH_VALUE)
    if bad.any():
        j = int(np.flatnonzero(bad.any(axis=1))[0])
        raise BvhError(f"{where}: OFFSET of {skeleton.names[j]!r} is {offsets[j].tolist()}: "
                       f"values must be finite and within +-{MAX_BVH_VALUE:g}")
    bad = ~np.isfinite(motion) | (np.abs(motion) > MAX_BVH_VALUE)
    if bad.any():
        f, c = (int(v) for v in np.argwhere(bad)[0])
        raise BvhError(f"{where}: motion line {f + 1} value {c + 1} is {motion[f, c]:g}: "
                       f"values must be finite and within +-{MAX_BVH_VALUE:g}")


# ----------------------------------------------------------------------------- kinematics

def joint_transforms(skeleton: BvhSkeleton, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global rotation and position of every joint frame.

    motion : (F, n_channels) float64, degrees for rotations, file units for positions.
    Returns ``(rotations (F, J, 3, 3), positions (F, J, 3))``, file units and axes.
    """
    motion = np.atleast_2d(np.asarray(motion, dtype=np.float64))
    if motion.shape[1] != skeleton.n_channels:
        raise ValueError(f"motion must have {skeleton.n_channels} columns, got {motion.shape[1]}")
    F, J = motion.shape[0], len(skeleton)
    rots = np.empty((F, J, 3, 3))
    pos = np.empty((F, J, 3))
    starts = skeleton.channel_starts
    for j, joint in enumerate(skeleton.joints):
        s = int(starts[j])
        local_t = np.broadcast_to(joint.offset, (F, 3)).copy()
        rot_axes, rot_cols = [], []
        for k, ch in enumerate(joint.channels):
            if ch in POSITION_CHANNELS:
                local_t[:, POSITION_CHANNELS.index(ch)] = motion[:, s + k]
            else:
                rot_axes.append(ch[0])
                rot_cols.append(s + k)
        if rot_axes:
            # intrinsic rotations in listed order: uppercase axes in scipy
            local_r = Rotation.from_euler("".join(rot_axes).upper(), motion[:, rot_cols],
                                          degrees=True).as_matrix()
        else:
            local_r = np.broadcast_to(np.eye(3), (F, 3, 3))
        if joint.parent < 0:
            rots[:, j] = local_r
            pos[:, j] = local_t
        else:
            pr = rots[:, joint.parent]
            rots[:, j] = pr @ local_r
            pos[:, j] = pos[:, joint.parent] + np.einsum("fij,fj->fi", pr, local_t)
    return rots, pos


def forward_kinematics(skeleton: BvhSkeleton, motion: np.ndarray,
                       include_end_sites: bool = False) -> np.ndarray:
    """World positions of the joints, file units and axes.

    Returns (F, J, 3) float64; with ``include_end_sites`` (F, J + E, 3), the end sites
    appended in ``skeleton.end_site_joints`` order (names ``skeleton.end_site_names``).
    """
    rots, pos = joint_transforms(skeleton, motion)
    if not include_end_sites:
        return pos
    idx = skeleton.end_site_joints
    if not idx:
        return pos
    ends = np.array([skeleton.joints[i].end_site for i in idx])  # (E, 3)
    end_pos = pos[:, idx] + np.einsum("feij,ej->fei", rots[:, idx], ends)
    return np.concatenate([pos, end_pos], axis=1)


def resample_motion(skeleton: BvhSkeleton, motion: np.ndarray, frame_time_s: float,
                    times_s: np.ndarray) -> np.ndarray:
    """Motion values at arbitrary times: rotations by slerp, positions linearly.

    motion : (F, n_channels) sampled at ``k * frame_time_s``; times_s : (T,) seconds,
    clamped to the clip. Returns (T, n_channels); Euler angles are re-extracted in each
    joint's channel order, so bone lengths stay exact (unlike interpolating positions).
    """
    from scipy.spatial.transform import Slerp

    motion = np.atleast_2d(np.asarray(motion, dtype=np.float64))
    F = motion.shape[0]
    src_t = np.arange(F) * float(frame_time_s)
    t = np.clip(np.asarray(times_s, dtype=np.float64), 0.0, src_t[-1])
    out = np.empty((t.size, motion.shape[1]))
    starts = skeleton.channel_starts
    for j, joint in enumerate(skeleton.joints):
        s = int(starts[j])
        rot_axes, rot_cols = [], []
        for k, ch in enumerate(joint.channels):
            if ch in POSITION_CHANNELS:
                out[:, s + k] = np.interp(t, src_t, motion[:, s + k])
            else:
                rot_axes.append(ch[0])
                rot_cols.append(s + k)
        if rot_axes:
            seq = "".join(rot_axes).upper()
            if F == 1 or len(set(seq)) != 3:  # 1-2 rotation axes: interpolate the angles
                for c in rot_cols:
                    out[:, c] = np.interp(t, src_t, motion[:, c])
                continue
            rots = Rotation.from_euler(seq, motion[:, rot_cols], degrees=True)
            out[:, rot_cols] = Slerp(src_t, rots)(t).as_euler(seq, degrees=True)
    return out
