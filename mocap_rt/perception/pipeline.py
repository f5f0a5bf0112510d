"""Per-camera 2D perception (seed digest A.1, A.2, A.4, B.8): frame -> ``CameraCues``.

Stages, each timed into ``CameraCues.timings_ms``:

* ``silhouette``: change detection against the background model inside a region of
  interest (the previous person box plus a margin; the whole image when there is none or
  the person reaches the ROI's edge), largest 8-connected component, holes filled, box.
* ``colour``: skin and shoe colour maps (A.1) inside the person box, on silhouette pixels.
* ``blobs``: head/hands on the skin map, feet on the shoe map (A.2, A.4).
* ``torso``: centre of the silhouette's distance-transform ridge.

Usage::

    perceiver = CameraPerceiver(camera, backgrounds)        # backgrounds (B, H, W, 3) BGR
    cues = perceiver.process(image_bgr, frame, prediction)  # prediction: CuePrediction | None
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from mocap_rt.config import load_dataclass
from mocap_rt.cues import SILHOUETTE_MAX_BYTES, CameraCues, CompactSilhouette, CuePrediction
from mocap_rt.geometry.camera import Camera
from mocap_rt.names import C_HEAD, C_TORSO, CUE_NAMES, N_CUES, SHOE_CUE_INDEX, SHOE_CUES, SKIN_CUE_INDEX, SKIN_CUES
from mocap_rt.perception.background import BackgroundModel, ChangeThresholds
from mocap_rt.perception.components import largest_component_box
from mocap_rt.perception.blobs import BlobFrame, BlobParams, BlobTracker
from mocap_rt.perception.colour_model import ColourModel, chroma_table, colour_model_from_spec
from mocap_rt.perception.roi import ChangeMask, roi_candidates
from mocap_rt.perception.leg_attach import MIN_BLOB_AREA_PX, leg_attachment
from mocap_rt.perception.scene import TORSO_HEAD_RADII, SceneState, check_head, torso_from_head
from mocap_rt.perception.silhouette import half_cells, silhouette_colour, top_point
from mocap_rt.perception.torso import DEFAULT_RIDGE_FRAC, HOLE_HEAD_AREAS, torso_point

log = logging.getLogger(__name__)

def _cue_rows(index: tuple[int, ...]) -> slice:
    """The cue rows of one tracker as a slice (a view, ~5x cheaper than an index array)."""
    if tuple(index) != tuple(range(index[0], index[-1] + 1)):
        raise ValueError(f"tracker cues {index} are not consecutive rows of CUE_NAMES")
    return slice(index[0], index[-1] + 1)


_SKIN_IDX = _cue_rows(SKIN_CUE_INDEX)
_SHOE_IDX = _cue_rows(SHOE_CUE_INDEX)
PART_REACH_MAX_FRAC = 0.1   # a part's reach (``CameraPerceiver._expected_parts``) is at most this x image width


@dataclass(frozen=True)
class PerceptionConfig:
    """Settings of one camera's perception; pixel values are at the camera's resolution.

    skin_model_path / shoe_model_path: TOML colour model files, or the name of a shipped
    model ("skin", "shoe", "studio_skin"); "" = the shipped "skin" / "shoe". Use
    "studio_skin" for studio recordings (its skin does not darken like real skin).
    """

    change: ChangeThresholds = ChangeThresholds()
    skin_blobs: BlobParams = BlobParams()  # by size: head and hands (docs/perception.md, Blobs)
    shoe_blobs: BlobParams = BlobParams(label_by_shape=True)  # touching shoes split along their seam
    skin_model_path: str = ""
    shoe_model_path: str = ""
    roi_margin_px: int = 16               # ROI = previous person box + this ...
    roi_margin_frac: float = 0.05         # ... + this fraction of the box's larger side
    roi_motion_px: int = 6                # first ROI: the box moved by its last motion + this (roi.py); 0 = off
    min_person_area_px: int = 200         # smaller largest component: no person
    part_min_px: int = 40                 # a separate changed component this large within reach of an expected
                                          # head, hand or foot is the person's too (a leg crossing a background
                                          # of its colour cuts the shoe off); 0 = off
    torso_ridge_frac: float = DEFAULT_RIDGE_FRAC
    torso_head_radii: float = TORSO_HEAD_RADII   # torso = head + this x head radius toward the ridge centroid
                                                 # (scene.py); 0 = the ridge centroid itself
    head_check: bool = True               # re-seat a head that left the trunk's top for a skin region there (scene.py)
    torso_head_shift_frac: float = 0.0    # torso point moved this fraction of the torso->head distance away
                                          # from the head; the ridge's bias depends on the clip (docs), so off
    torso_step_px: int = 0                # distance-transform subsampling; 0 = 2 if width > 400 else 1
    torso_hole_head_areas: float = HOLE_HEAD_AREAS  # holes this many head areas and larger are loops of the
                                                    # body, not trunk, for the torso ridge (torso.py); 0 = off
    background_update_rate: float = 0.0   # > 0: slow background update (per frame blend weight)
    close_px: int = 0                     # > 0: morphological closing (square, this size) of the change mask
    silhouette_bytes: int = SILHOUETTE_MAX_BYTES  # compact silhouette sent to fusion (packed bits); 0 = none


def visible_centre_offsets(offset_px: np.ndarray, area_px2: np.ndarray) -> np.ndarray:
    """The predicted offsets (K, 2) of the blobs' visible centres from their cue points
    (``CuePrediction.offset_px``) that a blob of ``area_px2`` (K,) can have: 0 where NaN or
    farther than the blob's radius (what is hidden of a part cannot move its centre that far;
    a stale or forged prediction moves no cue further)."""
    off = np.asarray(offset_px, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        near = (off * off).sum(axis=1) <= np.asarray(area_px2, np.float64) / np.pi     # NaN, inf: False
    return np.where(near[:, None], off, 0.0)


def load_perception_config(path: str | Path) -> PerceptionConfig:
    """Read a ``PerceptionConfig`` from TOML: a ``[perception]`` table, or its fields at the
    top level (sub-tables for the nested settings). Unknown keys are errors naming the file."""
    return load_dataclass(PerceptionConfig, path, "perception")


def config_for_source(config: PerceptionConfig, source: str) -> PerceptionConfig:
    """The config to use on a recording of the given ``source`` ("studio", "live", ...).

    Studio skin keeps one chromaticity under shading, while the real-skin (UCI) default
    model makes darker skin redder and accepts only ~60 % of studio skin pixels; so a
    studio recording gets the studio-fitted skin model unless one was chosen explicitly.
    """
    if source == "studio" and not config.skin_model_path:
        return replace(config, skin_model_path="studio_skin")
    return config


class CameraPerceiver:
    """Perception of one camera: keeps the background model and the 2D blob tracks.

    camera : the camera (its ``name`` and ``size`` are used).
    backgrounds : (B, H, W, 3) uint8 BGR frames of the empty scene.
    """

    def __init__(self, camera: Camera, backgrounds: np.ndarray,
                 config: PerceptionConfig = PerceptionConfig()) -> None:
        self.camera = camera
        self.config = config
        self.background = BackgroundModel.from_frames(np.asarray(backgrounds))
        self.background.derived(config.change)     # the change test's per-pixel tables now (~7 ms at
        w, h = self._wh = self.background.size     # 640x480), not in the first frame's latency
        self._close_kernel = (cv2.getStructuringElement(cv2.MORPH_RECT, (config.close_px, config.close_px))
                              if config.close_px > 0 else None)
        if tuple(int(v) for v in camera.size) != (w, h):
            raise ValueError(f"camera {camera.name}: size {tuple(camera.size)} but backgrounds are {w}x{h}")
        self.skin_model: ColourModel = colour_model_from_spec(config.skin_model_path, "skin")
        self.shoe_model: ColourModel = colour_model_from_spec(config.shoe_model_path, "shoe")
        self._chroma = chroma_table(self.skin_model.kernel_params(), self.shoe_model.kernel_params())
        self._emax = (self.skin_model.max_error, self.shoe_model.max_error)
        self.skin_tracker = BlobTracker(SKIN_CUES, config.skin_blobs)
        self.shoe_tracker = BlobTracker(SHOE_CUES, config.shoe_blobs)
        self._parts = np.empty((C_TORSO, 3))      # ``_expected_parts``' output
        self._reach_max = PART_REACH_MAX_FRAC * self._wh[0]
        self._torso_step = config.torso_step_px or (2 if w > 400 else 1)
        self._box: tuple[int, int, int, int] | None = None      # last person box, image px
        self._prev_box: tuple[int, int, int, int] | None = None  # ... and the one before
        self._change = ChangeMask((w, h))                        # this frame's change codes
        self._sil: np.ndarray | None = None                      # last silhouette in its box
        self._sil_box = (0, 0, 0, 0)
        self.scene = SceneState()                                # head size and place on the trunk (scene.py)

    # ------------------------------------------------------------------ public
    @property
    def last_contours(self) -> dict[str, np.ndarray]:
        """The last frame's deformed blob contours (image px) by cue name (overlays)."""
        out = {}
        for tracker, idx in ((self.skin_tracker, _SKIN_IDX), (self.shoe_tracker, _SHOE_IDX)):
            for k, c in zip(range(idx.start, idx.stop), tracker.last_contours()):
                if c is not None:
                    out[CUE_NAMES[k]] = c
        return out

    @property
    def last_silhouette(self) -> np.ndarray | None:
        """(H, W) bool silhouette of the last processed frame (None before the first)."""
        if self._sil is None:
            return None
        w, h = self.background.size
        full = np.zeros((h, w), bool)
        x, y, bw, bh = self._sil_box
        full[y:y + bh, x:x + bw] = self._sil > 0
        return full

    def process(self, image_bgr: np.ndarray, frame: int, prediction: CuePrediction | None = None) -> CameraCues:
        """Cues of one frame. image_bgr (H, W, 3) uint8 BGR; prediction for this frame or None."""
        t0 = time.perf_counter()
        img = np.asarray(image_bgr)
        w, h = self._wh
        if img.shape != (h, w, 3) or img.dtype != np.uint8:
            raise ValueError(f"camera {self.camera.name}: expected ({h}, {w}, 3) uint8 BGR, "
                             f"got {img.shape} {img.dtype}")
        member, change, box = self._silhouette(img, self._expected_parts(prediction))
        t1 = time.perf_counter()
        xy = np.full((N_CUES, 2), np.nan)
        cov = np.full((N_CUES, 2, 2), np.nan)
        area = np.zeros(N_CUES)
        conf = np.zeros(N_CUES)
        if box[2] == 0:
            self.skin_tracker.step(np.zeros((1, 1), np.uint8), (0, 0), (0, 0, 0, 0), None)
            self.shoe_tracker.step(np.zeros((1, 1), np.uint8), (0, 0), (0, 0, 0, 0), None)
            t = time.perf_counter()
            empty = CompactSilhouette(0, 0, 1, np.zeros((0, 0), bool)) if self.config.silhouette_bytes > 0 else None
            return CameraCues(self.camera.name, frame, xy, cov, area, conf, (0, 0, 0, 0),
                              {"silhouette": (t1 - t0) * 1e3, "total": (t - t0) * 1e3}, empty)
        bx, by, bw, bh = box
        sil, skin, shoe, n_sil = silhouette_colour(member, change, img, box, self._chroma, *self._emax)
        self._sil = sil
        t2 = time.perf_counter()
        top = top_point(sil)
        # with the body's prediction of what each part shows, the blobs' centres are corrected by it
        # instead of by the completion from central symmetry (docs/perception.md, "Where the
        # medians' error lies")
        offsets = None if prediction is None else prediction.offset_px
        offset_rows = None if offsets is None else np.isfinite(offsets[:, 0])
        for tracker, idx, cmap in ((self.skin_tracker, _SKIN_IDX, skin), (self.shoe_tracker, _SHOE_IDX, shoe)):
            out = BlobFrame(xy[idx], cov[idx], area[idx], conf[idx])         # views: the tracker writes the cues
            if prediction is not None:
                corrected = offset_rows is not None and bool(offset_rows[idx].any())
                tracker.step(cmap, (bx, by), (0, 0, bw, bh), top, prediction.xy[idx], prediction.visible[idx],
                             prediction.radius_px[idx], sil_roi=None if corrected else sil,
                             pred_shape=None if prediction.shape_px is None else prediction.shape_px[idx], out=out)
            else:
                tracker.step(cmap, (bx, by), (0, 0, bw, bh), top, sil_roi=sil, out=out)
        leg_xy = np.empty((2, 2))
        leg_attachment(sil, bx, by, xy[_SHOE_IDX], cov[_SHOE_IDX], area[_SHOE_IDX], MIN_BLOB_AREA_PX, leg_xy)
        if offsets is not None:
            xy[:C_TORSO] -= visible_centre_offsets(offsets[:C_TORSO], area[:C_TORSO])
        t3 = time.perf_counter()
        pred_r = float("nan") if prediction is None else float(prediction.radius_px[C_HEAD])
        head_r = self.scene.head_radius(pred_r)          # scaled to this frame's depth by the prediction
        n_radii = self.scene.measured
        hole_px = self.config.torso_hole_head_areas * np.pi * head_r ** 2       # NaN before a head is seen
        loops = (member, change, hole_px) if hole_px > 0 else None
        head = (xy[C_HEAD, 0] - bx, xy[C_HEAD, 1] - by, head_r)
        txy, tcov, thick = torso_point(sil, self.config.torso_ridge_frac, self._torso_step, loops, head)
        ridge = np.array((txy[0] + bx, txy[1] + by))
        if self.config.head_check:
            seat = check_head(self.scene, xy[C_HEAD], area[C_HEAD], conf[C_HEAD], ridge, tcov, skin, (bx, by),
                              pred_r)
            if seat is not None:
                xy[C_HEAD], area[C_HEAD], conf[C_HEAD] = seat[0], seat[1], 0.5
                self.skin_tracker.reseat(SKIN_CUES.index("head"), seat[0], 2.0 * np.sqrt(seat[1] / np.pi))
        if math.isfinite(txy[0]) and math.isfinite(txy[1]):
            xy[C_TORSO] = ridge
            if self.scene.measured != n_radii:
                head_r = self.scene.head_radius(pred_r)  # with this frame's head
            head_torso = (torso_from_head(xy[C_HEAD], head_r, ridge, self.config.torso_head_radii)
                          if self.config.torso_head_radii > 0 else None)
            if head_torso is not None:
                xy[C_TORSO] = head_torso
            elif self.config.torso_head_shift_frac and np.isfinite(xy[C_HEAD]).all():
                # bias correction (docs/perception.md, Torso), for a studio that measured it
                xy[C_TORSO] -= self.config.torso_head_shift_frac * (xy[C_HEAD] - xy[C_TORSO])
            cov[C_TORSO] = tcov
            area[C_TORSO] = float(n_sil)
            conf[C_TORSO] = 1.0
        t4 = time.perf_counter()
        if self.config.background_update_rate > 0:
            self.background.update(img, self.last_silhouette, self.config.background_update_rate)
        compact = None
        if self.config.silhouette_bytes > 0:
            step = CompactSilhouette.step_for(bw, bh, self.config.silhouette_bytes)
            compact = CompactSilhouette(bx, by, step, half_cells(sil, step))
        t5 = time.perf_counter()
        timings = {"silhouette": (t1 - t0) * 1e3, "colour": (t2 - t1) * 1e3, "blobs": (t3 - t2) * 1e3,
                   "torso": (t4 - t3) * 1e3, "total": (t5 - t0) * 1e3}
        return CameraCues(self.camera.name, frame, xy, cov, area, conf, box, timings, compact, leg_xy)

    # ------------------------------------------------------------------ stages
    def _expected_parts(self, prediction: CuePrediction | None) -> np.ndarray:
        """(5, 3) x, y, reach, image px: where the head, hands and feet are expected this frame
        and how far their pixels may lie from there (NaN: not expected): fusion's prediction,
        else the blobs' own 2D tracks (``BlobTracker.expected``); the reach is twice the blob's
        radius, at most ``PART_REACH_MAX_FRAC`` of the image's width (a forged radius claims no more)."""
        parts = self._parts
        if prediction is not None:
            parts[:, :2] = prediction.xy[:C_TORSO]
            parts[:, 2] = prediction.radius_px[:C_TORSO]
        else:
            self.skin_tracker.expected(parts[_SKIN_IDX])
            self.shoe_tracker.expected(parts[_SHOE_IDX])
        reach = parts[:, 2]
        reach *= 2.0
        np.minimum(reach, self._reach_max, out=reach)
        return parts

    def _silhouette(self, img: np.ndarray, parts: np.ndarray,
                    ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int]]:
        """Filled component (bh, bw) uint8 {0, 255} and change codes (``change_mask``) in the
        person box (x, y, w, h) image px; the boundary clean-up is ``silhouette_colour``'s.
        The regions searched are ``roi.roi_candidates``, smallest first. With the largest
        component, the components of ``part_min_px`` pixels within reach of the ``parts`` (K, 3)
        expected (``_expected_parts``)."""
        w, h = self._wh
        cfg = self.config
        self._change.start()
        for rx0, ry0, rx1, ry1 in roi_candidates(self._box, self._prev_box, (w, h), cfg.roi_margin_px,
                                                 cfg.roi_margin_frac, cfg.roi_motion_px):
            rw, rh = rx1 - rx0, ry1 - ry0
            mask = self._change.extend(img, self.background, cfg.change, (rx0, ry0, rx1, ry1))
            if self._close_kernel is not None:
                mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close_kernel)
            member, (cx, cy, cw, ch) = largest_component_box(mask, cfg.min_person_area_px, parts, (rx0, ry0),
                                                             cfg.part_min_px)
            touches = cw > 0 and ((cx == 0 and rx0 > 0) or (cy == 0 and ry0 > 0) or
                                  (cx + cw == rw and rx1 < w) or (cy + ch == rh and ry1 < h))
            if cw > 0 and not touches:
                break                   # else: lost or leaving the region, search the next
        self._prev_box = self._box
        if cw == 0:
            self._box = self._prev_box = None
            self._sil, self._sil_box = np.zeros((0, 0), np.uint8), (0, 0, 0, 0)
            return self._sil, self._sil, (0, 0, 0, 0)
        box = (rx0 + cx, ry0 + cy, cw, ch)
        self._box, self._sil_box = box, box
        change = np.ascontiguousarray(mask[cy:cy + ch, cx:cx + cw])   # the kernels vectorise on C layout
        if cfg.change.edge_strength <= 1.0:
            change = np.full_like(change, 255)      # no boundary clean-up
        return member, change, box
