"""The crash-safe writer of the recorded multi-view stream format (``recording_format``).

Owns ``RecordingWriter``: frame-by-frame writing of a recording directory (studio renders,
live cameras), each video segment renamed into place when closed and each table row
flushed as it is written.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from mocap_rt.config import dumps_toml
from mocap_rt.geometry.rig import Rig, write_rig
from mocap_rt.io.files import atomic_write, atomic_write_text
from mocap_rt.io.recording_format import (CODEC_EXT, DEFAULT_CODEC, DEFAULT_JPEG_QUALITY, DEFAULT_SEGMENT_S,
                                          FORMAT_NAME, FORMAT_VERSION, segment_name)


class RecordingWriter:
    """Write a recording directory frame by frame (studio renders or live cameras).

    rig : the cameras, in the order ``write_frame`` receives images.
    fps : nominal frame rate, Hz.
    codec : FOURCC of ``cv2.VideoWriter`` (MJPG, XVID, mp4v, FFV1).
    segment_s : video segment length in seconds (the most a crash can lose).
    """

    def __init__(self, path: str | Path, rig: Rig, fps: float, codec: str = DEFAULT_CODEC,
                 segment_s: float = DEFAULT_SEGMENT_S, jpeg_quality: int = DEFAULT_JPEG_QUALITY,
                 source: str = "studio") -> None:
        if codec not in CODEC_EXT:
            raise ValueError(f"codec must be one of {sorted(CODEC_EXT)}, got {codec!r}")
        if fps <= 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.path = Path(path)
        self.rig = rig
        self.fps = float(fps)
        self.codec = codec
        self.ext = CODEC_EXT[codec]
        self.segment_frames = max(1, int(round(segment_s * fps)))
        self.jpeg_quality = int(jpeg_quality)
        self.path.mkdir(parents=True, exist_ok=True)
        if (self.path / "recording.toml").exists():
            raise FileExistsError(f"{self.path} already holds a recording; refusing to overwrite it")
        for cam in rig.cameras:
            (self.path / "video" / cam.name).mkdir(parents=True, exist_ok=True)
        write_rig(rig, self.path / "rig.toml")
        meta = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "fps": self.fps,
                "cameras": list(rig.names), "codec": codec, "segment_frames": self.segment_frames,
                "source": source}
        atomic_write_text(self.path / "recording.toml", dumps_toml({"recording": meta}))
        self._table = open(self.path / "frames.csv", "w", newline="", encoding="utf-8")
        self._table.write("frame," + ",".join(rig.names) + "\n")
        self._table.flush()
        self._writers: list[cv2.VideoWriter] | None = None
        self._segment = -1
        self.n_frames = 0
        self._last_frame: int | None = None

    # -- video segments
    def _open_segment(self) -> None:
        self._segment += 1
        fourcc = cv2.VideoWriter_fourcc(*self.codec)
        self._writers = []
        for cam in self.rig.cameras:
            p = self.path / "video" / cam.name / segment_name(self._segment, self.ext, part=True)
            w = cv2.VideoWriter(str(p), cv2.CAP_FFMPEG, fourcc, self.fps, (cam.width, cam.height))
            if not w.isOpened():
                raise OSError(f"cv2.VideoWriter could not open {p} with codec {self.codec}")
            if self.codec == "MJPG":
                w.set(cv2.VIDEOWRITER_PROP_QUALITY, self.jpeg_quality)
            self._writers.append(w)

    def _close_segment(self) -> None:
        if self._writers is None:
            return
        for cam, w in zip(self.rig.cameras, self._writers):
            w.release()
            d = self.path / "video" / cam.name
            (d / segment_name(self._segment, self.ext, part=True)).replace(
                d / segment_name(self._segment, self.ext))
        self._writers = None

    # -- public API
    def write_backgrounds(self, camera: str | int, frames: np.ndarray) -> None:
        """Empty-scene frames of one camera: (B, H, W, 3) uint8 BGR, stored lossless (PNG)."""
        cam = self.rig[camera]
        frames = np.asarray(frames)
        if frames.ndim == 3:
            frames = frames[None]
        if frames.ndim != 4 or frames.shape[1:] != (cam.height, cam.width, 3) or frames.dtype != np.uint8:
            raise ValueError(f"backgrounds of {cam.name} must be (B, {cam.height}, {cam.width}, 3) uint8, "
                             f"got {frames.shape} {frames.dtype}")
        d = self.path / "backgrounds" / cam.name
        d.mkdir(parents=True, exist_ok=True)
        for i, img in enumerate(frames):
            if not cv2.imwrite(str(d / f"{i:03d}.png"), img):
                raise OSError(f"could not write {d / f'{i:03d}.png'}")

    def write_frame(self, frame_index: int, images: Sequence[np.ndarray],
                    timestamps_s: Sequence[float]) -> None:
        """Append one synchronised frame.

        images : one (H, W, 3) uint8 BGR image per camera, in rig order.
        timestamps_s : per-camera capture time in seconds (NaN if unknown), rig order.
        """
        n = len(self.rig)
        if len(images) != n or len(timestamps_s) != n:
            raise ValueError(f"write_frame needs {n} images and {n} timestamps, got "
                             f"{len(images)} and {len(timestamps_s)}")
        if self._last_frame is not None and frame_index <= self._last_frame:
            raise ValueError(f"frame indices must increase: {frame_index} after {self._last_frame}")
        if self.n_frames % self.segment_frames == 0:
            self._close_segment()
            self._open_segment()
        for cam, w, img in zip(self.rig.cameras, self._writers, images):
            if img.shape != (cam.height, cam.width, 3) or img.dtype != np.uint8:
                raise ValueError(f"image for {cam.name} must be ({cam.height}, {cam.width}, 3) uint8, "
                                 f"got {img.shape} {img.dtype}")
            w.write(np.ascontiguousarray(img))
        self._table.write(f"{int(frame_index)}," + ",".join(
            "" if not math.isfinite(float(t)) else f"{float(t):.6f}" for t in timestamps_s) + "\n")
        self._table.flush()
        self.n_frames += 1
        self._last_frame = int(frame_index)

    def write_truth(self, truth: dict) -> None:
        """Store the studio's ground truth (``truth.npz``, compressed; see the docs for keys)."""
        with atomic_write(self.path / "truth.npz", "wb") as fh:
            np.savez_compressed(fh, **{k: np.asarray(v) for k, v in truth.items()})

    def close(self) -> None:
        self._close_segment()
        if not self._table.closed:
            self._table.close()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
