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

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Protocol

import numpy as np

from nodes.node import DEFAULT_FPS

log = logging.getLogger(__name__)

LIVE_BACKGROUND_FRAMES = 10     # empty-scene frames a live source captures at start
GRAB_TIMEOUT_S = 1.0            # no new frame from a live device for this long -> error
DEVICE_OPEN_RETRIES = 3


@dataclass(frozen=True, slots=True)
class Grab:
    """One image handed to perception.

    image : (H, W, 3) uint8 BGR.  t_mono_ns / t_wall_ns : when it was captured (replay: read).
    seq : the device's frame counter (replay: the recording frame index).
    """

    image: np.ndarray
    t_mono_ns: int
    t_wall_ns: int
    seq: int


def parse_source(spec: str) -> tuple[str, str]:
    """``"replay:DIR"`` -> ``("replay", "DIR")``; raise ValueError for unknown kinds."""
    kind, sep, value = str(spec).partition(":")
    if not sep or kind not in ("replay", "v4l2", "fake", "gst") or not value:
        raise ValueError(f"--source {spec!r}: expected replay:REC_DIR, v4l2:/dev/videoN, fake:REC_DIR "
                         f"or gst:PIPELINE")
    return kind, value


class Device(Protocol):
    """A frame device: ``read()`` blocks until the next frame, like ``cv2.VideoCapture``."""

    def read(self) -> tuple[bool, np.ndarray | None]: ...
    def release(self) -> None: ...


class Grabber:
    """Background thread draining a device, keeping only the newest frame and its stamps.

    ``latest(after_seq, timeout_s)`` returns the newest ``Grab`` with ``seq > after_seq``
    (waiting for one if needed). ``overwritten`` counts frames replaced before anyone took
    them (the normal cost of always serving the newest frame).
    """

    def __init__(self, device: Device, name: str = "grabber") -> None:
        self._device = device
        self._cond = threading.Condition()
        self._latest: Grab | None = None
        self._taken_seq = -1
        self.overwritten = 0
        self.failures = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        seq = 0
        while not self._stop.is_set():
            ok, image = self._device.read()
            t_mono, t_wall = time.monotonic_ns(), time.time_ns()
            if ok and hasattr(self._device, "capture_stamps"):   # a device that knows (GStreamer PTS)
                t_mono, t_wall = self._device.capture_stamps()
            if not ok or image is None:
                self.failures += 1
                if self._stop.wait(0.01):
                    break
                continue
            with self._cond:
                if self._latest is not None and self._latest.seq > self._taken_seq:
                    self.overwritten += 1
                self._latest = Grab(image, t_mono, t_wall, seq)
                self._cond.notify_all()
            seq += 1

    def latest(self, after_seq: int = -1, timeout_s: float = GRAB_TIMEOUT_S) -> Grab:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._latest is None or self._latest.seq <= after_seq:
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set():
                    raise TimeoutError(f"no new frame within {timeout_s} s")
                self._cond.wait(left)
            self._taken_seq = self._latest.seq
            return self._latest

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._device.release()


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


class LiveSource:
    """A live device behind a ``Grabber``: each trigger takes the newest frame."""

    live = True

    def __init__(self, device: Device, camera: str, n_backgrounds: int = LIVE_BACKGROUND_FRAMES,
                 backgrounds_fn: Callable[[], np.ndarray] | None = None, origin: str = "live") -> None:
        self.camera = camera
        self.origin = origin
        self._backgrounds_fn = backgrounds_fn
        self.grabber = Grabber(device, name=f"grab-{camera}")
        self._n_backgrounds = n_backgrounds
        self._last_seq = -1

    def prefetch(self, frame_id: int) -> None:  # noqa: ARG002 - the grabber thread does this
        pass

    def grab(self, frame_id: int) -> Grab:  # noqa: ARG002 - live: the newest frame, whatever the id
        g = self.grabber.latest(after_seq=-1)
        self._last_seq = g.seq
        return g

    def backgrounds(self) -> np.ndarray:
        """The next ``n_backgrounds`` distinct frames (the scene must be empty at start)."""
        if self._backgrounds_fn is not None:
            return np.asarray(self._backgrounds_fn())
        frames, seq = [], -1
        for _ in range(self._n_backgrounds):
            g = self.grabber.latest(after_seq=seq)
            frames.append(g.image)
            seq = g.seq
        return np.stack(frames)

    def close(self) -> None:
        self.grabber.close()


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
