"""Parametric, illumination-robust colour model (seed digest A.1, eq. 1-2).

Each colour channel is a quadratic through the origin in the grey level ``i``::

    R = R2*i^2 + R1*i,   G = G2*i^2 + G1*i,   B = B2*i^2 + B1*i        (eq. 1)

with ``i = (r + g + b) / 3`` in 0..255 grey levels. A pixel (r, g, b) is compared with
the model colour at the same ``i`` in normalised chromaticity::

    error = (r/s - R/S)^2 + (g/s - G/S)^2,   s = r+g+b,  S = R+G+B      (eq. 2)

The likelihood used by the blob boundary search (A.2, eq. 4) is
``p = exp(-error / (2 sigma2))`` for pixels whose grey level lies inside the trained
range, else 0. ``sigma2`` is the per-component chromaticity variance of the training
pixels, so ``error / sigma2`` is chi-square with two degrees of freedom.

One model of this form is used for skin (head, hands), another for shoes (feet).
Models are stored as small TOML files (``mocap_rt/data/skin.toml`` / ``shoe.toml``).

Images are OpenCV BGR; the coefficients are in the paper's R, G, B order.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from mocap_rt.config import FileFormatError, dumps_toml, loads_toml, read_toml

log = logging.getLogger(__name__)

# Package data: the shipped default models (mocap_rt/data/*.toml).
_DATA_DIR = Path(__file__).resolve().parents[1] / "data"

# Fraction of training pixels accepted by the default threshold (the rest are outliers).
DEFAULT_ACCEPT_QUANTILE = 0.97
# Grey-level range kept: training quantiles (very dark / saturated pixels have no chroma).
GREY_RANGE_QUANTILES = (0.005, 0.995)
# Grey levels are widened by this margin beyond the training quantiles (grey levels 0..255).
GREY_MARGIN = 10.0


class ColourModelError(FileFormatError):
    """A colour-model file or training set that cannot be used; names the file/field."""


@dataclass(frozen=True)
class ColourModel:
    """Quadratic-in-grey colour model.

    coeffs : (3, 2) float64, rows R, G, B; columns (c2, c1) of ``c = c2 i^2 + c1 i``,
        colours and grey levels in 0..255.
    sigma2 : chromaticity variance per component (dimensionless, r/(r+g+b) units squared).
    max_error : eq. 2 error above which a pixel is not of this colour.
    grey_min, grey_max : grey-level range (0..255) in which the model is valid.
    """

    name: str
    coeffs: np.ndarray
    sigma2: float
    max_error: float
    grey_min: float = 0.0
    grey_max: float = 255.0

    def __post_init__(self) -> None:
        c = np.asarray(self.coeffs, dtype=np.float64)
        if c.shape != (3, 2) or not np.isfinite(c).all():
            raise ColourModelError(f"colour model {self.name!r}: coeffs must be finite (3, 2), got {c.shape}")
        if not (self.sigma2 > 0 and self.max_error > 0):
            raise ColourModelError(f"colour model {self.name!r}: sigma2 and max_error must be > 0")
        object.__setattr__(self, "coeffs", c)

    def model_rgb(self, grey: np.ndarray) -> np.ndarray:
        """Model colour at grey levels ``grey`` (N,) -> (N, 3) float64 R, G, B (eq. 1)."""
        g = np.asarray(grey, dtype=np.float64)[..., None]
        return self.coeffs[:, 0] * g * g + self.coeffs[:, 1] * g

    def error_rgb(self, rgb: np.ndarray) -> np.ndarray:
        """Eq. 2 chromaticity error of pixels ``rgb`` (N, 3) in R, G, B order -> (N,) float64."""
        px = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
        s = px.sum(axis=1)
        model = self.model_rgb(s / 3.0)
        S = model.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            e = (px[:, 0] / s - model[:, 0] / S) ** 2 + (px[:, 1] / s - model[:, 1] / S) ** 2
        return np.where(s > 0, e, np.inf)

    def likelihood_rgb(self, rgb: np.ndarray) -> np.ndarray:
        """p(colour) of pixels ``rgb`` (N, 3) R, G, B -> (N,) in [0, 1]; 0 outside the grey range."""
        px = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
        grey = px.sum(axis=1) / 3.0
        p = np.exp(-self.error_rgb(px) / (2.0 * self.sigma2))
        return np.where((grey >= self.grey_min) & (grey <= self.grey_max), p, 0.0)

    @property
    def min_likelihood(self) -> float:
        """Likelihood at ``max_error``: pixels below it are not of this colour."""
        return math.exp(-self.max_error / (2.0 * self.sigma2))

    def kernel_params(self) -> np.ndarray:
        """(10,) float64 packed parameters for the numba kernels."""
        return np.array([*self.coeffs.ravel(), 1.0 / (2.0 * self.sigma2), self.grey_min,
                         self.grey_max, self.max_error], dtype=np.float64)

    # ------------------------------------------------------------------ I/O
    def to_toml(self) -> str:
        c = self.coeffs
        return dumps_toml({"colour_model": {
            "name": self.name,
            "R": [float(c[0, 0]), float(c[0, 1])],
            "G": [float(c[1, 0]), float(c[1, 1])],
            "B": [float(c[2, 0]), float(c[2, 1])],
            "sigma2": float(self.sigma2),
            "max_error": float(self.max_error),
            "grey_min": float(self.grey_min),
            "grey_max": float(self.grey_max),
        }})


_TOML_KEYS = {"name", "R", "G", "B", "sigma2", "max_error", "grey_min", "grey_max"}


def save_colour_model(model: ColourModel, path: str | Path) -> None:
    Path(path).write_text("# parametric colour model, seed digest A.1 eq. 1-2: c = c2*i^2 + c1*i\n"
                          + model.to_toml())


def loads_colour_model(text: str, where: str = "<string>") -> ColourModel:
    return _colour_model_from_doc(loads_toml(text, where, ColourModelError), where)


def _colour_model_from_doc(doc: dict, where: str) -> ColourModel:
    table = doc.get("colour_model")
    if not isinstance(table, dict):
        raise ColourModelError(f"{where}: missing [colour_model] table")
    unknown = set(table) - _TOML_KEYS
    if unknown:
        raise ColourModelError(f"{where}: unknown keys in [colour_model]: {sorted(unknown)}")
    try:
        coeffs = np.array([table["R"], table["G"], table["B"]], dtype=np.float64)
        return ColourModel(str(table.get("name", Path(where).stem)), coeffs, float(table["sigma2"]),
                           float(table["max_error"]), float(table.get("grey_min", 0.0)),
                           float(table.get("grey_max", 255.0)))
    except KeyError as exc:
        raise ColourModelError(f"{where}: [colour_model] lacks field {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise ColourModelError(f"{where}: bad [colour_model] value: {exc}") from None


def load_colour_model(path: str | Path) -> ColourModel:
    return _colour_model_from_doc(read_toml(path, "colour model file", ColourModelError), str(path))


SHIPPED_MODELS = ("skin", "shoe", "studio_skin")


def default_colour_model(kind: str) -> ColourModel:
    """A shipped model from ``mocap_rt/data``: "skin" (real UCI skin pixels), "shoe" (the
    studio's shoes) or "studio_skin" (the studio's rendered skin, see docs/perception.md)."""
    if kind not in SHIPPED_MODELS:
        raise ValueError(f"unknown shipped colour model {kind!r} (one of {SHIPPED_MODELS})")
    path = _DATA_DIR / f"{kind}.toml"
    return loads_colour_model(path.read_text(), str(path))


def colour_model_from_spec(spec: str, default: str) -> ColourModel:
    """``spec`` = "" (the shipped ``default``), a shipped model name, or a TOML file path."""
    if not spec:
        return default_colour_model(default)
    if spec in SHIPPED_MODELS:
        return default_colour_model(spec)
    return load_colour_model(spec)


# ---------------------------------------------------------------------- fitting
def fit_colour_model(rgb: np.ndarray, name: str = "skin",
                     accept_quantile: float = DEFAULT_ACCEPT_QUANTILE) -> ColourModel:
    """Fit eq. 1 by linear least squares (per channel, no intercept) to labelled pixels.

    rgb : (N, 3) pixels of the colour, R, G, B order, 0..255. Pixels with grey level 0 are
        ignored. The threshold ``max_error`` accepts ``accept_quantile`` of them.
    """
    px = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
    px = px[px.sum(axis=1) > 0]
    if len(px) < 10:
        raise ColourModelError(f"colour model {name!r}: need >= 10 labelled pixels, got {len(px)}")
    grey = px.mean(axis=1)
    design = np.stack([grey * grey, grey], axis=1)                # (N, 2)
    coeffs, *_ = np.linalg.lstsq(design, px, rcond=None)          # (2, 3)
    lo, hi = np.quantile(grey, GREY_RANGE_QUANTILES)
    model = ColourModel(name, coeffs.T, 1.0, 1.0, max(0.0, lo - GREY_MARGIN), min(255.0, hi + GREY_MARGIN))
    err = model.error_rgb(px)
    err = err[np.isfinite(err)]
    sigma2 = max(float(np.mean(err)) / 2.0, 1e-8)                # E[error] = 2 sigma^2
    max_error = max(float(np.quantile(err, accept_quantile)), 1e-8)
    log.info("fitted colour model %r from %d pixels: sigma=%.4f max_error=%.2e", name, len(px),
             math.sqrt(sigma2), max_error)
    return ColourModel(name, coeffs.T, sigma2, max_error, model.grey_min, model.grey_max)


def read_uci_skin_table(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read the UCI Skin Segmentation table (``B G R label``, 1 = skin, 2 = non-skin).

    Returns (rgb (N, 3) uint8 in R, G, B order, is_skin (N,) bool).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"UCI skin table not found: {path}")
    try:
        table = np.loadtxt(path, dtype=np.int64, ndmin=2)
    except ValueError as exc:
        raise ColourModelError(f"{path}: not a 'B G R label' table: {exc}") from None
    if table.shape[1] != 4 or not np.isin(table[:, 3], (1, 2)).all():
        raise ColourModelError(f"{path}: expected 4 columns B G R label with label 1 or 2")
    return table[:, 2::-1].astype(np.uint8), table[:, 3] == 1


def pixels_from_masks(images_bgr: list[np.ndarray], masks: list[np.ndarray]) -> np.ndarray:
    """Labelled pixels (N, 3) R, G, B from images (H, W, 3) BGR and masks (H, W) (nonzero = colour)."""
    out = []
    for k, (img, mask) in enumerate(zip(images_bgr, masks, strict=True)):
        if img.shape[:2] != mask.shape[:2]:
            raise ColourModelError(f"image {k}: size {img.shape[:2]} differs from its mask {mask.shape[:2]}")
        m = mask if mask.ndim == 2 else mask[..., 0]
        out.append(img[m > 0][:, ::-1])
    return np.concatenate(out) if out else np.zeros((0, 3), np.uint8)


# ---------------------------------------------------------------------- per-pixel kernel
@numba.njit(cache=True, nogil=True)
def _likelihood_kernel(img, mask, params, binary, out):  # pragma: no cover - numba
    """img (H,W,3) uint8 BGR, mask (H,W) uint8 (0 = skip), params (10,), out (H,W) float32.

    binary: write 1 for accepted pixels (error <= max_error) instead of the likelihood.
    """
    r2, r1, g2, g1, b2, b1, inv2s, gmin, gmax, emax = (params[0], params[1], params[2], params[3],
                                                       params[4], params[5], params[6], params[7],
                                                       params[8], params[9])
    h, w = mask.shape
    for y in range(h):
        for x in range(w):
            if mask[y, x] == 0:
                out[y, x] = 0.0
                continue
            b = np.float32(img[y, x, 0])
            g = np.float32(img[y, x, 1])
            r = np.float32(img[y, x, 2])
            s = r + g + b
            i = s * np.float32(1.0 / 3.0)
            if s <= 0.0 or i < gmin or i > gmax:
                out[y, x] = 0.0
                continue
            mr = (r2 * i + r1) * i
            mg = (g2 * i + g1) * i
            mb = (b2 * i + b1) * i
            ms = mr + mg + mb
            dr = r / s - mr / ms
            dg = g / s - mg / ms
            e = dr * dr + dg * dg
            if e > emax:
                out[y, x] = 0.0
            elif binary:
                out[y, x] = 1.0
            else:
                out[y, x] = np.exp(-e * inv2s)


@numba.njit(cache=True, nogil=True, inline="always")
def _model_chroma(s, p):  # pragma: no cover - numba
    """Model chromaticity (R/S, G/S) float64 at the pixel sum ``s`` = r+g+b (float32), eq. 1-2,
    and whether its grey level s/3 lies in the model's range; p = ``kernel_params``."""
    i = s * np.float32(1.0 / 3.0)
    if i < p[7] or i > p[8]:
        return 0.0, 0.0, False
    mr = (p[0] * i + p[1]) * i
    mg = (p[2] * i + p[3]) * i
    mb = (p[4] * i + p[5]) * i
    ms = mr + mg + mb
    return mr / ms, mg / ms, True


@numba.njit(cache=True, nogil=True, inline="always")
def colour_bits(b, g, r, pa, pb):  # pragma: no cover - numba
    """Eq. 1-2 test of one BGR pixel (uint8 b, g, r) by two models (``kernel_params``):
    bit 0 set when model ``pa`` accepts it, bit 1 when ``pb`` does."""
    b = np.float32(b)
    g = np.float32(g)
    r = np.float32(r)
    s = r + g + b
    if s <= 0.0:
        return 0
    rn = r / s
    gn = g / s
    bits = 0
    for m in range(2):
        mr, mg, ok = _model_chroma(s, pa if m == 0 else pb)
        if ok:
            dr = rn - mr
            dg = gn - mg
            if dr * dr + dg * dg <= (pa[9] if m == 0 else pb[9]):
                bits |= 1 << m
    return bits


@numba.njit(cache=True, nogil=True)
def chroma_table(pa, pb):  # pragma: no cover - numba
    """(766, 5) float64 lookup of two models by pixel sum s = r+g+b (0..765): model a's
    (R/S, G/S), model b's, and bits (1: a's grey range holds s/3, 2: b's). Rows equal
    ``_model_chroma`` exactly, so a test through the table equals ``colour_bits``."""
    t = np.zeros((766, 5))
    for s in range(1, 766):
        ra, ga, oka = _model_chroma(np.float32(s), pa)
        rb, gb, okb = _model_chroma(np.float32(s), pb)
        t[s, 0] = ra
        t[s, 1] = ga
        t[s, 2] = rb
        t[s, 3] = gb
        t[s, 4] = oka + 2 * okb
    return t


@numba.njit(cache=True, nogil=True)
def _two_maps_kernel(img, mask, pa, pb, out_a, out_b):  # pragma: no cover - numba
    """Binary maps of two models in one pass (the pipeline's skin + shoe maps)."""
    h, w = mask.shape
    for y in range(h):
        for x in range(w):
            out_a[y, x] = 0.0
            out_b[y, x] = 0.0
            if mask[y, x] == 0:
                continue
            bits = colour_bits(img[y, x, 0], img[y, x, 1], img[y, x, 2], pa, pb)
            if bits & 1:
                out_a[y, x] = 1.0
            if bits & 2:
                out_b[y, x] = 1.0


def colour_maps_binary(image_bgr: np.ndarray, model_a: ColourModel, model_b: ColourModel,
                       mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Binary maps (H, W) float32 of two models on ``mask`` pixels, one pass over the image.

    Equal to ``likelihood_map(image, model, mask, binary=True)`` for each model.
    """
    img = np.asarray(image_bgr)
    m = np.asarray(mask)
    m = m.view(np.uint8) if m.dtype == bool else m.astype(np.uint8, copy=False)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or m.shape != img.shape[:2]:
        raise ValueError(f"image (H, W, 3) uint8 and mask (H, W) required, got {img.shape} {img.dtype}, {m.shape}")
    out_a = np.empty(m.shape, np.float32)
    out_b = np.empty(m.shape, np.float32)
    _two_maps_kernel(img, m, model_a.kernel_params(), model_b.kernel_params(), out_a, out_b)
    return out_a, out_b


def likelihood_map(image_bgr: np.ndarray, model: ColourModel, mask: np.ndarray | None = None,
                   out: np.ndarray | None = None, binary: bool = False) -> np.ndarray:
    """Per-pixel p(colour) (H, W) float32 of ``image_bgr`` (H, W, 3) uint8 BGR.

    Pixels where ``mask`` (H, W) uint8/bool is 0, outside the grey range or with error above
    ``model.max_error`` get 0. ``binary``: accepted pixels get 1 instead of p (the colour
    map the blob tracker uses). ``out`` (H, W) float32 may be given to avoid an allocation.
    """
    img = np.asarray(image_bgr)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8 BGR, got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    m = np.ones((h, w), np.uint8) if mask is None else np.asarray(mask).view(np.uint8) if \
        np.asarray(mask).dtype == bool else np.asarray(mask, dtype=np.uint8)
    if m.shape != (h, w):
        raise ValueError(f"mask must be {(h, w)}, got {m.shape}")
    if out is None:
        out = np.empty((h, w), np.float32)
    _likelihood_kernel(img, m, model.kernel_params(), bool(binary), out)
    return out
