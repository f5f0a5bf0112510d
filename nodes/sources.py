"""Image sources of a camera worker: recorded streams, V4L2 devices and a fake live device.

Source specs (``--source``):

* ``replay:REC_DIR`` — a recorded multi-view stream (``mocap_rt.io.recording``); the image
  of trigger ``k`` is recording frame ``k mod n_frames`` (the replay loops).
* ``v4l2:/dev/videoN`` (or ``v4l2:N``) — a live camera through OpenCV's V4L2 backend; a
  grabber thread keeps only the newest frame and its timestamp.
* ``fake:REC_DIR`` — a *simulated live camera*: the recording's images produced in real
  time at its fps by a device object, read through the very same ``Grabber`` as V4L2.
* ``gst:PIPELINE`` — a GStreamer pipeline (IEEE1394, GenICam, RTSP, V4L2, files), see
  ``nodes/gst_source.py``; ``{camera}`` in it is the camera's name.

A source has ``camera`` (name), ``live`` (bool), ``grab(frame_id) -> Grab``,
``prefetch(frame_id)`` (replay: decode the next image between triggers; live: nothing),
``backgrounds() -> (B, H, W, 3) uint8`` and ``close()``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from nodes.live import Grab, LiveSource
from nodes.node import DEFAULT_FPS

DEVICE_OPEN_RETRIES = 3


def parse_source(spec: str) -> tuple[str, str]:
    """``"replay:DIR"`` -> ``("replay", "DIR")``; raise ValueError for unknown kinds."""
    kind, sep, value = str(spec).partition(":")
    if not sep or kind not in ("replay", "v4l2", "fake", "gst") or not value:
        raise ValueError(f"--source {spec!r}: expected replay:REC_DIR, v4l2:/dev/videoN, fake:REC_DIR "
                         f"or gst:PIPELINE")
    return kind, value


class FakeDevice:
    """A real-time frame device for tests and dry runs: ``frame_fn(i)`` served at ``fps``.

    ``read()`` sleeps until frame ``i`` is due on an absolute schedule, like a camera
    delivering frames on its own clock.
    """

    def __init__(self, frame_fn: Callable[[int], np.ndarray], fps: float) -> None:
        self._frame_fn = frame_fn
        self._period_ns = round(1e9 / fps)
        self._t0 = time.monotonic_ns()
        self._i = 0
        self._released = False

    def read(self) -> tuple[bool, np.ndarray | None]:
        if self._released:
            return False, None
        due = self._t0 + self._i * self._period_ns
        wait = (due - time.monotonic_ns()) / 1e9
        if wait > 0:
            time.sleep(wait)
        img = self._frame_fn(self._i)
        self._i += 1
        return True, img

    def release(self) -> None:
        self._released = True


class ReplaySource:
    """Frames of one camera of a recording, chosen by trigger id (``k mod n_frames``)."""

    live = False

    def __init__(self, rec_dir: Path, camera: str) -> None:
        from mocap_rt.io.recording import Recording

        self.recording = Recording(rec_dir)
        if camera not in list(self.recording.camera_names):
            raise ValueError(f"camera {camera!r} is not in recording {rec_dir} "
                             f"(has {list(self.recording.camera_names)})")
        self.camera = camera
        self.n_frames = int(self.recording.n_frames)
        self.origin = self.recording.source  # what made the frames: "studio", "live", ...
        if self.n_frames <= 0:
            raise ValueError(f"recording {rec_dir} has no frames")
        self._next: tuple[int, np.ndarray] | None = None

    def grab(self, frame_id: int) -> Grab:
        idx = frame_id % self.n_frames
        t_mono, t_wall = time.monotonic_ns(), time.time_ns()
        if self._next is not None and self._next[0] == idx:
            image = self._next[1]
        else:
            image = self.recording.read_frame(self.camera, idx)
        self._next = None
        return Grab(image, t_mono, t_wall, idx)

    def prefetch(self, frame_id: int) -> None:
        """Decode the image of ``frame_id`` now (between triggers), like a camera whose next
        frame is already in memory when the trigger comes: decoding leaves the critical path."""
        idx = frame_id % self.n_frames
        self._next = (idx, self.recording.read_frame(self.camera, idx))

    def backgrounds(self) -> np.ndarray:
        return np.asarray(self.recording.backgrounds(self.camera))

    def close(self) -> None:
        close = getattr(self.recording, "close", None)
        if close:
            close()


class V4L2Device:
    """``cv2.VideoCapture`` on the V4L2 backend with the size and rate asked for."""

    def __init__(self, path: str, size: tuple[int, int], fps: float) -> None:
        import cv2

        dev = int(path) if path.isdigit() else path
        cap = None
        for _ in range(DEVICE_OPEN_RETRIES):
            cap = cv2.VideoCapture(dev, cv2.CAP_V4L2)
            if cap.isOpened():
                break
            time.sleep(0.2)
        if cap is None or not cap.isOpened():
            raise FileNotFoundError(f"cannot open V4L2 device {path}")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[0])
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[1])
        cap.set(cv2.CAP_PROP_FPS, fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        self._cap = cap

    def read(self) -> tuple[bool, np.ndarray | None]:
        return self._cap.read()

    def release(self) -> None:
        self._cap.release()


def open_source(spec: str, camera, fps: float = DEFAULT_FPS, backgrounds_from: str | None = None):
    """Build the source for ``--source spec`` and a rig ``Camera`` (``backgrounds_from``: a
    recording whose stored backgrounds a ``gst:`` source uses instead of capturing them)."""
    kind, value = parse_source(spec)
    if kind == "gst":
        from nodes.gst_source import open_gst_source

        if "{index}" in value:
            raise ValueError(f"--source {spec!r}: {{index}} is filled in by mocap-rt run; give the pipeline "
                             f"of this camera")
        return open_gst_source(value, camera, 0, backgrounds_from)
    if kind == "replay":
        return ReplaySource(Path(value), camera.name)
    if kind == "v4l2":
        return LiveSource(V4L2Device(value, tuple(camera.size), fps), camera.name)
    # fake: a recording played as a live camera in real time
    rep = ReplaySource(Path(value), camera.name)
    dev = FakeDevice(lambda i: rep.recording.read_frame(camera.name, i % rep.n_frames),
                     float(rep.recording.fps))
    return LiveSource(dev, camera.name, backgrounds_fn=lambda: rep.recording.backgrounds(camera.name),
                      origin=rep.origin)
