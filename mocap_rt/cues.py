"""What the per-camera perception stage hands to fusion, and what fusion hands back.

Plain dataclasses of numpy arrays, in the cue order of ``mocap_rt.names.CUE_NAMES``.
``to_dict``/``from_dict`` give msgpack-friendly dicts (arrays stay numpy; the message
layer in ``nodes/messages.py`` encodes them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_rt.names import CUE_NAMES

N_CUES = len(CUE_NAMES)


def _arr(x, shape: tuple[int, ...], dtype, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=dtype)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


@dataclass(frozen=True, slots=True)
class CameraCues:
    """One camera's cues for one frame.

    xy : (6, 2) float64 pixels (OpenCV convention), NaN where the cue was not found.
    cov : (6, 2, 2) float64 pixel^2, the blob's covariance (NaN where not found).
    area : (6,) float64 pixels of the blob (0 where not found).
    confidence : (6,) float64 in [0, 1]; 0 where not found.
    bbox : (x, y, w, h) int pixels of the person; (0, 0, 0, 0) when there is none.
    timings_ms : per-stage processing time of this frame, milliseconds.
    """

    camera: str
    frame: int
    xy: np.ndarray
    cov: np.ndarray
    area: np.ndarray
    confidence: np.ndarray
    bbox: tuple[int, int, int, int] = (0, 0, 0, 0)
    timings_ms: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "xy", _arr(self.xy, (N_CUES, 2), np.float64, "xy"))
        object.__setattr__(self, "cov", _arr(self.cov, (N_CUES, 2, 2), np.float64, "cov"))
        object.__setattr__(self, "area", _arr(self.area, (N_CUES,), np.float64, "area"))
        object.__setattr__(self, "confidence", _arr(self.confidence, (N_CUES,), np.float64, "confidence"))
        object.__setattr__(self, "bbox", tuple(int(v) for v in self.bbox))

    @property
    def found(self) -> np.ndarray:
        """(6,) bool: the cue has a position."""
        return np.isfinite(self.xy).all(axis=1) & (self.confidence > 0)

    @classmethod
    def empty(cls, camera: str, frame: int) -> "CameraCues":
        return cls(camera, frame, np.full((N_CUES, 2), np.nan), np.full((N_CUES, 2, 2), np.nan),
                   np.zeros(N_CUES), np.zeros(N_CUES))

    def to_dict(self) -> dict:
        return {"camera": self.camera, "frame": int(self.frame), "xy": self.xy, "cov": self.cov,
                "area": self.area, "confidence": self.confidence, "bbox": list(self.bbox),
                "timings_ms": {str(k): float(v) for k, v in self.timings_ms.items()}}

    @classmethod
    def from_dict(cls, d: dict) -> "CameraCues":
        return cls(str(d["camera"]), int(d["frame"]), d["xy"], d["cov"], d["area"], d["confidence"],
                   tuple(d["bbox"]), dict(d.get("timings_ms", {})))


@dataclass(frozen=True, slots=True)
class CuePrediction:
    """Fusion's prediction of one camera's cues for a coming frame (seed digest A.4).

    xy : (6, 2) float64 predicted pixel positions (NaN where unknown or off-image).
    visible : (6,) bool, False where the Z-buffer test says the cue will be occluded
        by a nearer cue or is outside the image; an occluded blob keeps its initial
        ellipse (no boundary search).
    radius_px : (6,) float64 predicted blob radius in pixels (NaN where unknown).
    """

    camera: str
    frame: int
    xy: np.ndarray
    visible: np.ndarray
    radius_px: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "xy", _arr(self.xy, (N_CUES, 2), np.float64, "xy"))
        object.__setattr__(self, "visible", _arr(self.visible, (N_CUES,), bool, "visible"))
        object.__setattr__(self, "radius_px", _arr(self.radius_px, (N_CUES,), np.float64, "radius_px"))

    def to_dict(self) -> dict:
        return {"camera": self.camera, "frame": int(self.frame), "xy": self.xy,
                "visible": self.visible, "radius_px": self.radius_px}

    @classmethod
    def from_dict(cls, d: dict) -> "CuePrediction":
        return cls(str(d["camera"]), int(d["frame"]), d["xy"], d["visible"], d["radius_px"])
