"""Writing BVH files: a whole clip at once (``write_bvh``) and the crash-safe stream writer
the recorder appends frames to (``BvhStreamWriter``); the format is ``mocap_rt.io.bvh``'s.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mocap_rt.io.bvh import BvhSkeleton
from mocap_rt.io.files import atomic_write

# Stream writer: seconds of motion kept in memory before it is written and flushed.
STREAM_FLUSH_INTERVAL_S = 1.0
# Width of the "Frames:" count field of a streamed file, rewritten in place on flush.
_FRAMES_FIELD_WIDTH = 12


def _fmt(v: float) -> str:
    return format(float(v), ".9g")


def hierarchy_text(skeleton: BvhSkeleton) -> str:
    """The HIERARCHY section of ``skeleton`` (tab-indented, LF line ends)."""
    children: dict[int, list[int]] = {i: [] for i in range(-1, len(skeleton))}
    for i, j in enumerate(skeleton.joints):
        children[j.parent].append(i)
    if len(children[-1]) != 1:
        raise ValueError("a BVH skeleton needs exactly one root")
    out = ["HIERARCHY"]

    def emit(i: int, depth: int) -> None:
        j = skeleton.joints[i]
        ind = "\t" * depth
        out.append(f"{ind}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {' '.join(_fmt(v) for v in j.offset)}")
        out.append(f"{ind}\tCHANNELS {len(j.channels)} {' '.join(j.channels)}")
        for c in children[i]:
            emit(c, depth + 1)
        if j.end_site is not None:
            out.append(f"{ind}\tEnd Site")
            out.append(f"{ind}\t{{")
            out.append(f"{ind}\t\tOFFSET {' '.join(_fmt(v) for v in j.end_site)}")
            out.append(f"{ind}\t}}")
        out.append(f"{ind}}}")

    emit(children[-1][0], 0)
    return "\n".join(out) + "\n"


def _motion_lines(motion: np.ndarray) -> str:
    return "".join(" ".join(_fmt(v) for v in row) + "\n" for row in motion)


def _check_motion(skeleton: BvhSkeleton, motion: np.ndarray) -> np.ndarray:
    motion = np.atleast_2d(np.asarray(motion, dtype=np.float64))
    if motion.ndim != 2 or motion.shape[1] != skeleton.n_channels:
        raise ValueError(f"motion must be (F, {skeleton.n_channels}), got {motion.shape}")
    if not np.isfinite(motion).all():
        raise ValueError("motion contains NaN/inf; BVH cannot store them")
    return motion


def write_bvh(path: str | Path, skeleton: BvhSkeleton, motion: np.ndarray, frame_time_s: float) -> None:
    """Write a whole clip (atomically: a temporary file renamed over ``path``)."""
    motion = _check_motion(skeleton, motion)
    if frame_time_s <= 0:
        raise ValueError(f"frame_time_s must be > 0, got {frame_time_s}")
    with atomic_write(path) as fh:
        fh.write(hierarchy_text(skeleton))
        fh.write(f"MOTION\nFrames: {motion.shape[0]}\nFrame Time: {_fmt(frame_time_s)}\n")
        fh.write(_motion_lines(motion))


class BvhStreamWriter:
    """Append frames to a BVH file as they come, crash-safe.

    Frames are buffered for ``flush_interval_s`` of motion, then appended and flushed;
    only after that is the fixed-width ``Frames:`` count rewritten in place. After a
    SIGKILL the file therefore always parses (``read_bvh`` ignores complete lines past
    the count), losing at most the last ``flush_interval_s`` of motion.
    """

    def __init__(self, path: str | Path, skeleton: BvhSkeleton, frame_time_s: float,
                 flush_interval_s: float = STREAM_FLUSH_INTERVAL_S) -> None:
        if frame_time_s <= 0:
            raise ValueError(f"frame_time_s must be > 0, got {frame_time_s}")
        self.path = Path(path)
        self.skeleton = skeleton
        self.frame_time_s = float(frame_time_s)
        self._flush_every = max(1, int(round(flush_interval_s / frame_time_s)))
        self._pending: list[np.ndarray] = []
        self.n_written = 0
        self._fh = open(self.path, "w+b")
        self._fh.write(self._header(skeleton, 0))
        self._count_pos = self._header_count_pos(skeleton)
        self._data_pos = self._fh.tell()
        self._fh.flush()

    def _header(self, skeleton: BvhSkeleton, n_frames: int) -> bytes:
        return (hierarchy_text(skeleton) + "MOTION\n" + f"Frames: {n_frames:<{_FRAMES_FIELD_WIDTH}d}\n"
                f"Frame Time: {_fmt(self.frame_time_s)}\n").encode()

    @staticmethod
    def _header_count_pos(skeleton: BvhSkeleton) -> int:
        return len((hierarchy_text(skeleton) + "MOTION\nFrames: ").encode())

    def set_skeleton(self, skeleton: BvhSkeleton) -> None:
        """Give the file a new hierarchy (same channels, e.g. the subject's calibrated bone
        lengths) for the frames written so far and to come. The file is rewritten beside
        the old one and swapped in by rename, so it parses at every instant."""
        if self._fh is None:
            raise ValueError(f"{self.path}: writer is closed")
        if hierarchy_text(skeleton) == hierarchy_text(self.skeleton):
            return
        if skeleton.n_channels != self.skeleton.n_channels:
            raise ValueError(f"{self.path}: new skeleton has {skeleton.n_channels} channels, "
                             f"the file {self.skeleton.n_channels}")
        self.flush()
        self._fh.seek(self._data_pos)
        motion = self._fh.read()
        with atomic_write(self.path, "wb") as out:
            out.write(self._header(skeleton, self.n_written))
            data_pos = out.tell()
            out.write(motion)
        self._fh.close()
        self._fh = open(self.path, "r+b")
        self._fh.seek(0, os.SEEK_END)
        self.skeleton, self._data_pos = skeleton, data_pos
        self._count_pos = self._header_count_pos(skeleton)

    def write(self, frame_values: np.ndarray) -> None:
        """Append one frame: (n_channels,) float64 motion values."""
        if self._fh is None:
            raise ValueError(f"{self.path}: writer is closed")
        row = _check_motion(self.skeleton, np.asarray(frame_values, dtype=np.float64).reshape(1, -1))
        self._pending.append(row[0])
        if len(self._pending) >= self._flush_every:
            self.flush()

    def flush(self) -> None:
        """Write the buffered frames, flush them, then update the frame count."""
        if self._fh is None or not self._pending:
            return
        self._fh.seek(0, os.SEEK_END)
        self._fh.write(_motion_lines(np.array(self._pending)).encode())
        self._fh.flush()
        self.n_written += len(self._pending)
        self._pending.clear()
        end = self._fh.tell()
        self._fh.seek(self._count_pos)
        self._fh.write(f"{self.n_written:<{_FRAMES_FIELD_WIDTH}d}".encode())
        self._fh.flush()
        self._fh.seek(end)

    def close(self) -> None:
        if self._fh is None:
            return
        self.flush()
        self._fh.close()
        self._fh = None

    def __enter__(self) -> "BvhStreamWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
