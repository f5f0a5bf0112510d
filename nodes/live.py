"""Live frame devices behind a grabber thread: the ``Grab`` a camera worker perceives, the
``Grabber`` that keeps only a device's newest frame, and ``LiveSource`` (a source on top of it)
shared by the V4L2, fake and GStreamer sources (``nodes/sources.py``, ``nodes/gst_source.py``)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

LIVE_BACKGROUND_FRAMES = 10     # empty-scene frames a live source captures at start
GRAB_TIMEOUT_S = 1.0            # no new frame from a live device for this long -> error

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
