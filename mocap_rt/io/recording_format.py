"""The recorded multi-view stream format (version 1): its names, layout and error.

Owns what the reader (``mocap_rt.io.recording``) and the writer
(``mocap_rt.io.recording_writer``) share: the format's name and version, the codecs and
their file extensions, the video segment file names and ``RecordingError``. One directory
per recording (full description in ``docs/recording-format.md``)::

    recording.toml          [recording] format, version, fps, cameras, codec, segment_frames
    rig.toml                the calibrated rig (``mocap_rt.geometry.rig`` TOML)
    frames.csv              frame,<cam_1>,<cam_2>,...  capture timestamps in seconds
    video/<cam>/seg_000000.avi ...  each holds ``segment_frames`` consecutive rows
    backgrounds/<cam>/000.png ...   empty-scene frames (lossless)
    truth.npz               studio recordings only (see docs)

Row ``k`` of ``frames.csv`` is frame ``k`` of the stream (``k // segment_frames`` is
its segment). A video segment is written as ``seg_NNNNNN.part.avi`` and renamed to
``seg_NNNNNN.avi`` once closed, and each table row is flushed as it is written, so
after a SIGKILL the recording opens with every frame of its closed segments: at most
one segment (~1 s) is lost.
"""

from __future__ import annotations

from mocap_rt.config import FileFormatError

FORMAT_NAME = "mocap_rt.recording"
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)
DEFAULT_CODEC = "MJPG"  # intra-only: exact seeks, a cut file loses only its own frames
DEFAULT_JPEG_QUALITY = 95
DEFAULT_SEGMENT_S = 1.0
# FOURCC of cv2.VideoWriter -> file extension of its segments
CODEC_EXT = {"MJPG": ".avi", "XVID": ".avi", "FFV1": ".avi", "mp4v": ".mp4"}


class RecordingError(FileFormatError):
    """A recording that cannot be read; the message names the file and field."""


def segment_name(index: int, ext: str, part: bool = False) -> str:
    """File name of video segment ``index`` (``.part`` while it is being written)."""
    return f"seg_{index:06d}{'.part' if part else ''}{ext}"
