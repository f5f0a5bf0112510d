"""The reader of the recorded multi-view stream format (``mocap_rt.io.recording_format``).

Owns ``Recording``: opening a recording directory, checking it (``RecordingError`` naming
the file and field), and reading its frames, backgrounds and truth. ``RecordingWriter``
(``mocap_rt.io.recording_writer``) is importable from here too.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import zipfile
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from mocap_rt.config import read_toml
from mocap_rt.geometry.rig import RigFileError, read_rig
from mocap_rt.io.recording_format import (CODEC_EXT, FORMAT_NAME, SUPPORTED_VERSIONS, RecordingError,
                                          segment_name)
from mocap_rt.io.recording_writer import RecordingWriter

__all__ = ["Recording", "RecordingError", "RecordingWriter"]

log = logging.getLogger(__name__)

# Forward skips up to this many frames are read through instead of seeking.
_MAX_GRAB_SKIP = 8


def _toml_value(v) -> str:
    """A value as it reads in the TOML file (``true``, ``nan``, ``0``)."""
    return str(v).lower() if isinstance(v, bool) or (isinstance(v, float) and not math.isfinite(v)) else repr(v)


class Recording:
    """Read a recording directory; validates it on open (``RecordingError`` if bad).

    Attributes: ``path``, ``rig``, ``camera_names``, ``fps``, ``codec``, ``n_frames``,
    ``frames`` (F,) int64, ``timestamps`` (F, C) float64 seconds (NaN where unknown).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"recording directory not found: {self.path}")
        self._read_meta()
        try:
            self.rig = read_rig(self.path / "rig.toml")
        except FileNotFoundError:
            raise RecordingError(f"{self.path / 'rig.toml'}: missing (every recording has its rig)") from None
        except RigFileError as exc:           # its message names the file
            raise RecordingError(str(exc)) from None
        if list(self.rig.names) != self.camera_names:
            raise RecordingError(f"{self.path / 'recording.toml'}: field 'cameras' {self.camera_names} "
                                 f"does not match the rig's cameras {list(self.rig.names)}")
        self._read_table()
        self._segments = {name: self._scan_segments(name) for name in self.camera_names}
        self._limit_to_complete_segments()
        self._cap: dict[str, tuple[int, cv2.VideoCapture, int]] = {}  # name -> (segment, cap, next pos)
        self._truth: dict | None = None

    # -- validation
    def _read_meta(self) -> None:
        p = self.path / "recording.toml"
        try:
            meta = read_toml(p, "recording.toml", RecordingError)
        except FileNotFoundError:
            raise RecordingError(f"{p}: missing; {self.path} is not a recording") from None
        rec = meta.get("recording")
        if not isinstance(rec, dict):
            raise RecordingError(f"{p}: no [recording] table")
        if rec.get("format") != FORMAT_NAME:
            raise RecordingError(f"{p}: field 'format' is {rec.get('format')!r}, expected {FORMAT_NAME!r}")
        version = rec.get("version")
        if version not in SUPPORTED_VERSIONS:
            raise RecordingError(f"{p}: field 'version' = {version!r} is not supported "
                                 f"(this reader knows {list(SUPPORTED_VERSIONS)})")
        for key, typ in (("fps", (int, float)), ("cameras", list), ("codec", str), ("segment_frames", int)):
            if not isinstance(rec.get(key), typ):
                raise RecordingError(f"{p}: field {key!r} missing or of the wrong type")
        fps, seg = rec["fps"], rec["segment_frames"]
        if isinstance(fps, bool) or not (math.isfinite(fps) and fps > 0):
            raise RecordingError(f"{p}: field 'fps' must be a positive finite number, got {_toml_value(fps)}")
        if isinstance(seg, bool) or seg <= 0:
            raise RecordingError(f"{p}: field 'segment_frames' must be an integer > 0, got {_toml_value(seg)}")
        if rec["codec"] not in CODEC_EXT:
            raise RecordingError(f"{p}: field 'codec' = {rec['codec']!r} unknown")
        self.fps = float(rec["fps"])
        self.camera_names = [str(c) for c in rec["cameras"]]
        self.codec = rec["codec"]
        self.segment_frames = int(rec["segment_frames"])
        self.source = str(rec.get("source", ""))
        self._ext = CODEC_EXT[self.codec]

    def _read_table(self) -> None:
        p = self.path / "frames.csv"
        try:
            text = p.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise RecordingError(f"{p}: missing (the per-frame table)") from None
        lines = text.split("\n")
        if lines and lines[-1] != "":
            lines = lines[:-1]  # a crash mid-row: drop the incomplete last line
        rows = list(csv.reader(io.StringIO("\n".join(lines))))
        if not rows or rows[0] != ["frame", *self.camera_names]:
            raise RecordingError(f"{p}: header must be 'frame,{','.join(self.camera_names)}', "
                                 f"got {','.join(rows[0]) if rows else '(empty)'!r}")
        frames, stamps = [], []
        for k, row in enumerate(rows[1:], start=2):
            if len(row) != len(self.camera_names) + 1:
                raise RecordingError(f"{p}, line {k}: {len(row)} fields, expected {len(self.camera_names) + 1}")
            try:
                frames.append(int(row[0]))
                stamps.append([float(v) if v else math.nan for v in row[1:]])
            except ValueError:
                raise RecordingError(f"{p}, line {k}: not a number") from None
        self.frames = np.array(frames, dtype=np.int64)
        self.timestamps = np.array(stamps, dtype=np.float64).reshape(-1, len(self.camera_names))
        step = np.diff(self.frames)
        if np.any(step <= 0):
            k = int(np.flatnonzero(step <= 0)[0])
            raise RecordingError(f"{p}, line {k + 3}: frame {self.frames[k + 1]} after {self.frames[k]}: "
                                 f"frame indices must increase")
        # a live recording skips the frames no camera answered; any other has every frame
        if self.source != "live" and np.any(step != 1):
            k = int(np.flatnonzero(step != 1)[0])
            raise RecordingError(f"{p}, line {k + 3}: frame {self.frames[k + 1]} follows {self.frames[k]} "
                                 f"({step[k] - 1} rows missing): rows no longer match the video frames")

    def _scan_segments(self, name: str) -> list[Path]:
        d = self.path / "video" / name
        if not d.is_dir():
            raise RecordingError(f"{d}: video folder of camera {name!r} is missing")
        segs = sorted(d.glob("seg_[0-9][0-9][0-9][0-9][0-9][0-9]" + self._ext))
        for i, s in enumerate(segs):
            if s.name != segment_name(i, self._ext):
                raise RecordingError(f"{d}: segment {segment_name(i, self._ext)} is missing")
        return segs

    def _limit_to_complete_segments(self) -> None:
        n_rows = len(self.frames)
        n_seg = min(len(s) for s in self._segments.values()) if self._segments else 0
        n = min(n_rows, n_seg * self.segment_frames)
        if n < n_rows:
            log.warning("%s: %d of %d frames have no closed video segment (interrupted recording); "
                        "using the first %d", self.path, n_rows - n, n_rows, n)
        self.n_frames = n
        self.frames = self.frames[:n]
        self.timestamps = self.timestamps[:n]
        if n == 0 and n_rows > 0:
            raise RecordingError(f"{self.path / 'video'}: no complete video segment")
        if n_seg and n_rows <= (n_seg - 1) * self.segment_frames:
            raise RecordingError(f"{self.path / 'frames.csv'}: {n_rows} rows, but the video has {n_seg} segments "
                                 f"of {self.segment_frames} frames: rows are missing")
        self._check_last_segments(n_rows)
        for name, segs in self._segments.items():
            for s in segs[: math.ceil(n / self.segment_frames) if n else 0]:
                if s.stat().st_size == 0:
                    raise RecordingError(f"{s}: empty video file")

    def _check_last_segments(self, n_rows: int) -> None:
        """Each camera's last closed segment: its image size is the rig's, and it holds no more
        frames than ``frames.csv`` has rows for (a table with missing rows no longer says which
        image is which frame)."""
        for name, segs in self._segments.items():
            if not segs:
                continue
            cap = cv2.VideoCapture(str(segs[-1]), cv2.CAP_FFMPEG)
            try:
                size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
                count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            finally:
                cap.release()
            if size == (0, 0):
                continue             # unreadable: reported when its frames are read
            if size != tuple(self.rig[name].size):
                raise RecordingError(f"{segs[-1]}: images are {size[0]}x{size[1]}, the rig's camera {name!r} "
                                     f"is {self.rig[name].size[0]}x{self.rig[name].size[1]} (rig.toml 'size')")
            rows_in_last = n_rows - (len(segs) - 1) * self.segment_frames
            if count > rows_in_last:
                raise RecordingError(f"{self.path / 'frames.csv'}: {n_rows} rows, but the video of {name!r} "
                                     f"has {(len(segs) - 1) * self.segment_frames + count} frames: rows are missing")

    def _expected_len(self, segment: int) -> int:
        return min(self.segment_frames, self.n_frames - segment * self.segment_frames)

    def validate(self) -> None:
        """Demux every frame of every segment; ``RecordingError`` names a truncated file.

        Costs about a tenth of a full decode; ``Recording(...)`` itself only checks
        what is cheap (files present, table, headers).
        """
        for name in self.camera_names:
            for seg in range(math.ceil(self.n_frames / self.segment_frames)):
                cap = self._open(name, seg)
                try:
                    for pos in range(self._expected_len(seg)):
                        if not cap.grab():
                            raise RecordingError(f"{self._segments[name][seg]}: truncated video, "
                                                 f"frame {pos} of {self._expected_len(seg)} is missing")
                finally:
                    cap.release()

    # -- frames
    def _cam_name(self, camera: str | int) -> str:
        if isinstance(camera, (int, np.integer)):
            if not 0 <= camera < len(self.camera_names):
                raise IndexError(f"camera index {camera} out of range 0..{len(self.camera_names) - 1}")
            return self.camera_names[int(camera)]
        if camera not in self.camera_names:
            raise KeyError(f"{self.path}: no camera named {camera!r} (cameras: {self.camera_names})")
        return camera

    def _open(self, name: str, segment: int) -> cv2.VideoCapture:
        path = self._segments[name][segment]
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            raise RecordingError(f"{path}: cannot be opened as video")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if count < self._expected_len(segment):
            cap.release()
            raise RecordingError(f"{path}: truncated video, {count} frames but the table needs "
                                 f"{self._expected_len(segment)}")
        return cap

    def read_frame(self, camera: str | int, frame_index: int) -> np.ndarray:
        """Image of one camera at stream position ``frame_index`` (0..n_frames-1).

        Returns (H, W, 3) uint8 BGR. Sequential reads decode without seeking.
        """
        name = self._cam_name(camera)
        if not 0 <= frame_index < self.n_frames:
            raise IndexError(f"frame_index {frame_index} out of range 0..{self.n_frames - 1}")
        seg, pos = divmod(int(frame_index), self.segment_frames)
        cur = self._cap.get(name)
        if cur is None or cur[0] != seg:
            if cur is not None:
                cur[1].release()
            cur = (seg, self._open(name, seg), 0)
        cap = cur[1]
        if 0 < pos - cur[2] <= _MAX_GRAB_SKIP:
            for _ in range(pos - cur[2]):  # a short skip forward: demuxing beats a seek
                cap.grab()
        elif cur[2] != pos:
            cap.set(cv2.CAP_PROP_POS_FRAMES, pos)
        ok, img = cap.read()
        if not ok or img is None:
            raise RecordingError(f"{self._segments[name][seg]}: cannot decode frame {pos} (truncated video?)")
        self._cap[name] = (seg, cap, pos + 1)
        return img

    def iter_frames(self, camera: str | int) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (frame_index, image) for one camera, sequentially."""
        name = self._cam_name(camera)
        for seg in range(math.ceil(self.n_frames / self.segment_frames)):
            cap = self._open(name, seg)
            try:
                for pos in range(self._expected_len(seg)):
                    ok, img = cap.read()
                    if not ok:
                        raise RecordingError(f"{self._segments[name][seg]}: cannot decode frame {pos}")
                    yield seg * self.segment_frames + pos, img
            finally:
                cap.release()

    def backgrounds(self, camera: str | int) -> np.ndarray:
        """Empty-scene frames of one camera: (B, H, W, 3) uint8 BGR (B may be 0)."""
        name = self._cam_name(camera)
        cam = self.rig[name]
        files = sorted((self.path / "backgrounds" / name).glob("*.png"))
        out = np.empty((len(files), cam.height, cam.width, 3), np.uint8)
        for i, f in enumerate(files):
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is None or img.shape != out.shape[1:]:
                raise RecordingError(f"{f}: unreadable or not {cam.width}x{cam.height}")
            out[i] = img
        return out

    @property
    def truth(self) -> dict | None:
        """Ground truth from ``truth.npz`` (studio only), loaded on first access; else None."""
        if self._truth is None:
            p = self.path / "truth.npz"
            if not p.exists():
                return None
            try:
                with np.load(p, allow_pickle=False) as z:
                    self._truth = {k: z[k] for k in z.files}
            except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
                raise RecordingError(f"{p}: unreadable ({type(exc).__name__}: {exc}); a truncated or "
                                     f"damaged file?") from None
        return self._truth

    def close(self) -> None:
        for _, cap, _ in self._cap.values():
            cap.release()
        self._cap.clear()

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"Recording({str(self.path)!r}, cameras={self.camera_names}, fps={self.fps}, "
                f"n_frames={self.n_frames})")
