"""The machine yardstick every bench prints: one ``cv2.cvtColor`` BGR -> HSV pass over a
640x480 frame, median milliseconds, measured in the bench's own process. Figures divided by
it carry between machines (absolute times do not)."""

from __future__ import annotations

import fcntl
import os
import time
from contextlib import contextmanager

import numpy as np

TIMING_LOCK = "/tmp/mocap-timing.lock"


def yardstick_ms(repeats: int = 200) -> float:
    """Median ms of one ``cv2.cvtColor(BGR2HSV)`` over a 640x480 8-bit frame."""
    import cv2

    img = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    for _ in range(10):
        cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        t.append(time.perf_counter() - t0)
    return float(np.median(t) * 1e3)


def header(ms: float) -> str:
    return f"yardstick: one cv2.cvtColor BGR->HSV pass over 640x480 = {ms:.3f} ms (median); ratios are x yardstick"


@contextmanager
def timing_lock(enabled: bool = True, path: str = TIMING_LOCK):
    """Hold the timing lock, so that timed benches on a shared machine run one at a time."""
    if not enabled:
        yield
        return
    fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
