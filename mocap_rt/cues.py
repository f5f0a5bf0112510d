"""What the per-camera perception stage hands to fusion, and what fusion hands back.

Plain dataclasses of numpy arrays, in the cue order of ``mocap_rt.names.CUE_NAMES``.
``to_dict``/``from_dict`` are the one field layout of cues and predictions (arrays stay
numpy): the service's messages (``nodes/messages.py``) carry exactly these fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_rt.names import N_CUES

# Budget of a compact silhouette's packed bits, bytes: with the rest of the cues the
# message stays under 4 KB per camera and frame.
SILHOUETTE_MAX_BYTES = 3072
# Finest cell size of a compact silhouette, pixels (the mask is rarely worth more).
SILHOUETTE_MIN_STEP = 2


def _arr(x, shape: tuple[int, ...], dtype, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=dtype)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


@dataclass(frozen=True, slots=True)
class CompactSilhouette:
    """The person's silhouette in one camera, downsampled inside its box (for fusion).

    x0, y0 : image pixel of the first cell's top-left corner; step : cell size, pixels
    (cell (i, j) covers pixels x0 + step*j .. x0 + step*(j+1) - 1, likewise rows);
    mask : (h, w) bool, a cell is set when at least half of its pixels are the person's.
    Everything outside the cells is background.
    """

    x0: int
    y0: int
    step: int
    mask: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.mask, dtype=bool)
        if m.ndim != 2:
            raise ValueError(f"silhouette mask must be 2-D, got shape {m.shape}")
        if int(self.step) < 1:
            raise ValueError(f"silhouette step must be >= 1, got {self.step}")
        object.__setattr__(self, "mask", m)
        for k in ("x0", "y0", "step"):
            object.__setattr__(self, k, int(getattr(self, k)))

    @property
    def nbytes(self) -> int:
        """Bytes of the packed mask (what travels)."""
        h, w = self.mask.shape
        return h * ((w + 7) // 8)

    @staticmethod
    def step_for(bw: int, bh: int, max_bytes: int = SILHOUETTE_MAX_BYTES) -> int:
        """The smallest cell size >= SILHOUETTE_MIN_STEP whose packed mask of a (bh, bw) box
        fits ``max_bytes``."""
        step = SILHOUETTE_MIN_STEP
        while (-(-bh // step)) * ((-(-bw // step) + 7) // 8) > max_bytes:
            step += 1
        return step

    @classmethod
    def from_box_mask(cls, sil: np.ndarray, box: tuple[int, int, int, int],
                      max_bytes: int = SILHOUETTE_MAX_BYTES) -> "CompactSilhouette":
        """Downsample a silhouette given inside its box (bh, bw) (nonzero = person; box
        (x, y, w, h) image pixels) with the smallest step >= SILHOUETTE_MIN_STEP whose packed
        mask fits ``max_bytes``."""
        import cv2

        sil = np.asarray(sil)
        x, y, bw, bh = (int(v) for v in box)
        if sil.shape != (bh, bw):
            raise ValueError(f"silhouette {sil.shape} does not match box {box}")
        step = cls.step_for(bw, bh, max_bytes)
        h, w = -(-bh // step), -(-bw // step)
        if h == 0 or w == 0:
            return cls(x, y, step, np.zeros((0, 0), bool))
        pad = np.zeros((h * step, w * step), np.float32)
        pad[:bh, :bw] = sil > 0
        small = cv2.resize(pad, (w, h), interpolation=cv2.INTER_AREA)
        return cls(x, y, step, small >= 0.5)

    @classmethod
    def box_around(cls, uv: np.ndarray) -> "CompactSilhouette":
        """A filled box around the finite pixels ``uv`` (N, 2) (warm-ups, synthetic cues)."""
        uv = np.asarray(uv, np.float64)
        uv = uv[np.isfinite(uv).all(axis=1)]
        x0, y0 = np.floor(uv.min(axis=0)).astype(int)
        x1, y1 = np.ceil(uv.max(axis=0)).astype(int)
        return cls.from_box_mask(np.ones((y1 - y0 + 1, x1 - x0 + 1), np.uint8), (x0, y0, x1 - x0 + 1, y1 - y0 + 1))

    def full_mask(self, width: int, height: int) -> np.ndarray:
        """(height, width) bool at image resolution (each cell repeated step x step)."""
        out = np.zeros((height, width), bool)
        big = np.repeat(np.repeat(self.mask, self.step, axis=0), self.step, axis=1)
        x1, y1 = min(width, self.x0 + big.shape[1]), min(height, self.y0 + big.shape[0])
        if x1 > self.x0 and y1 > self.y0:
            out[self.y0:y1, self.x0:x1] = big[:y1 - self.y0, :x1 - self.x0]
        return out

    def packed(self) -> np.ndarray:
        """(h, ceil(w / 8)) uint8, ``np.packbits`` along rows."""
        return np.packbits(self.mask, axis=1)

    @classmethod
    def from_packed(cls, x0: int, y0: int, step: int, width: int, bits: np.ndarray) -> "CompactSilhouette":
        """Inverse of ``packed``: ``width`` cells per row; ValueError when the sizes disagree."""
        bits = np.asarray(bits, dtype=np.uint8)
        if bits.ndim != 2 or width < 0 or bits.shape[1] != (width + 7) // 8:
            raise ValueError(f"silhouette bits {bits.shape} do not hold rows of {width} cells")
        return cls(x0, y0, step, np.unpackbits(bits, axis=1, count=width).astype(bool))

    def to_dict(self) -> dict:
        return {"x0": self.x0, "y0": self.y0, "step": self.step, "w": int(self.mask.shape[1]),
                "bits": self.packed()}

    @classmethod
    def from_dict(cls, d: dict) -> "CompactSilhouette":
        return cls.from_packed(int(d["x0"]), int(d["y0"]), int(d["step"]), int(d["w"]), d["bits"])


@dataclass(frozen=True, slots=True)
class CameraCues:
    """One camera's cues for one frame.

    xy : (6, 2) float64 pixels (OpenCV convention), NaN where the cue was not found.
    cov : (6, 2, 2) float64 pixel^2, the blob's covariance (NaN where not found).
    area : (6,) float64 pixels of the blob (0 where not found).
    confidence : (6,) float64 in [0, 1]; 0 where not found.
    bbox : (x, y, w, h) int pixels of the person; (0, 0, 0, 0) when there is none.
    timings_ms : per-stage processing time of this frame, milliseconds.
    silhouette : the person's compact silhouette (None: not sent).
    leg_xy : (2, 2) float64 pixels where the legs meet the left and right shoe blobs
        (``perception.leg_attach``), NaN where not measured; None: not sent.
    """

    camera: str
    frame: int
    xy: np.ndarray
    cov: np.ndarray
    area: np.ndarray
    confidence: np.ndarray
    bbox: tuple[int, int, int, int] = (0, 0, 0, 0)
    timings_ms: dict = field(default_factory=dict)
    silhouette: CompactSilhouette | None = None
    leg_xy: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "xy", _arr(self.xy, (N_CUES, 2), np.float64, "xy"))
        if self.leg_xy is not None:
            object.__setattr__(self, "leg_xy", _arr(self.leg_xy, (2, 2), np.float64, "leg_xy"))
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
        """The fields; the silhouette (key ``sil``) and the legs' attachments (``leg``) only
        when there are."""
        return {"camera": self.camera, "frame": int(self.frame), "xy": self.xy, "cov": self.cov,
                "area": self.area, "confidence": self.confidence, "bbox": [int(v) for v in self.bbox],
                "timings_ms": {str(k): float(v) for k, v in self.timings_ms.items()},
                **({} if self.silhouette is None else {"sil": self.silhouette.to_dict()}),
                **({} if self.leg_xy is None else {"leg": self.leg_xy})}

    @classmethod
    def from_dict(cls, d: dict) -> "CameraCues":
        sil = d.get("sil")
        return cls(str(d["camera"]), int(d["frame"]), d["xy"], d["cov"], d["area"], d["confidence"],
                   tuple(d["bbox"]), dict(d.get("timings_ms", {})),
                   None if sil is None else CompactSilhouette.from_dict(sil), d.get("leg"))


@dataclass(frozen=True, slots=True)
class CuePrediction:
    """Fusion's prediction of one camera's cues for a coming frame (seed digest A.4).

    xy : (6, 2) float64 predicted pixel positions (NaN where unknown or off-image).
    visible : (6,) bool, False where the Z-buffer test says the cue will be occluded
        by a nearer cue or is outside the image; an occluded blob keeps its initial
        ellipse (no boundary search).
    radius_px : (6,) float64 predicted blob radius in pixels (NaN where unknown).
    offset_px : (6, 2) float64 or None: the offset of the centre of what the camera will see of
        each blob's body part from the cue's point (``body.visible``: collar, sleeve and trouser
        leg cover one end); the camera reports the centre it measures less this (NaN: none).
    shape_px : (6, 2, 2) float64 or None: the covariance of what the camera will see of each
        blob's body part, px^2 (``body.visible``; the shoes: two that touch are split along the
        seam these shapes predict); NaN: none.
    """

    camera: str
    frame: int
    xy: np.ndarray
    visible: np.ndarray
    radius_px: np.ndarray
    offset_px: np.ndarray | None = None
    shape_px: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "xy", _arr(self.xy, (N_CUES, 2), np.float64, "xy"))
        object.__setattr__(self, "visible", _arr(self.visible, (N_CUES,), bool, "visible"))
        object.__setattr__(self, "radius_px", _arr(self.radius_px, (N_CUES,), np.float64, "radius_px"))
        if self.offset_px is not None:
            object.__setattr__(self, "offset_px", _arr(self.offset_px, (N_CUES, 2), np.float64, "offset_px"))
        if self.shape_px is not None:
            object.__setattr__(self, "shape_px", _arr(self.shape_px, (N_CUES, 2, 2), np.float64, "shape_px"))

    def to_dict(self) -> dict:
        return {"camera": self.camera, "frame": int(self.frame), "xy": self.xy,
                "visible": self.visible, "radius_px": self.radius_px,
                **({} if self.offset_px is None else {"offset_px": self.offset_px}),
                **({} if self.shape_px is None else {"shape_px": self.shape_px})}

    @classmethod
    def from_dict(cls, d: dict) -> "CuePrediction":
        return cls(str(d["camera"]), int(d["frame"]), d["xy"], d["visible"], d["radius_px"], d.get("offset_px"),
                   d.get("shape_px"))
