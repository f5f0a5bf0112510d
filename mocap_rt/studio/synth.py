"""Synthesise a studio recording with ground truth from a BVH clip.

``synthesize`` reads the clip, maps it onto the body points (world frame, Z up,
metres), resamples it to the output rate, renders every camera of the rig, and writes a
recording directory in the stream format (``mocap_rt.io.recording``) with
``truth.npz`` (keys in ``docs/recording-format.md``). Deterministic for a given seed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap_rt.geometry.rig import Rig, desktop_rig, ring_rig
from mocap_rt.io.bvh import BvhClip, read_bvh
from mocap_rt.io.recording_format import DEFAULT_CODEC, DEFAULT_JPEG_QUALITY
from mocap_rt.io.recording_writer import RecordingWriter
from mocap_rt.names import CUE_JOINT_INDEX, CUE_NAMES, JOINT_NAMES
from mocap_rt.studio.body_map import POINT_NAMES, body_motion, bone_names
from mocap_rt.studio.body_shape import body_primitives
from mocap_rt.studio.render import RenderConfig, StudioRenderer
from mocap_rt.studio.scene import StudioScene

log = logging.getLogger(__name__)

# Empty-studio frames written per camera (each with its own sensor noise).
DEFAULT_N_BACKGROUNDS = 5


@dataclass(frozen=True)
class StudioConfig:
    """The studio's settings file (``mocap-rt synth --config``): a ``[render]`` table
    (``RenderConfig``: sensor and camera effects) and a ``[scene]`` table (``StudioScene``:
    studio geometry, colours, lights as ``lights = [{ direction = [x, y, z], intensity = 0.6 }]``)."""

    render: RenderConfig = field(default_factory=RenderConfig)
    scene: StudioScene = field(default_factory=StudioScene)


@dataclass(frozen=True)
class SynthStats:
    """What ``synthesize`` did: frame count, images, wall time split (seconds)."""

    out: Path
    n_frames: int
    n_images: int
    render_s: float
    encode_s: float
    total_s: float


def make_rig(layout: str = "ring", n_cameras: int = 6, size: tuple[int, int] = (640, 480),
             radius_m: float = 3.0, height_m: float = 1.6, hfov_deg: float = 60.0) -> Rig:
    """The studio's rigs: "ring" (``ring_rig``) or "desktop" (2 cameras, upper body)."""
    if layout == "ring":
        return ring_rig(n_cameras, radius_m=radius_m, height_m=height_m, size=size, hfov_deg=hfov_deg)
    if layout == "desktop":
        return desktop_rig(size=size)
    raise ValueError(f"rig layout must be 'ring' or 'desktop', got {layout!r}")


def synthesize(motion: str | Path | BvhClip, out: str | Path, *, rig: Rig | None = None, fps: float = 30.0,
               seconds: float | None = None, start_s: float = 0.0, seed: int = 0,
               placement: str = "centre", scene: StudioScene | None = None,
               config: RenderConfig | None = None, truth_masks: bool = True,
               codec: str = DEFAULT_CODEC, jpeg_quality: int = DEFAULT_JPEG_QUALITY,
               n_backgrounds: int = DEFAULT_N_BACKGROUNDS, threads: int = 2,
               progress: Callable[[int], None] | None = None, motion_name: str | None = None) -> SynthStats:
    """Render ``motion`` (a BVH file or clip) into a new recording directory ``out``.

    rig : default ``make_rig()`` (6-camera ring, 640x480). fps : output rate, Hz.
    seconds : duration from ``start_s`` (default: to the clip's end; longer requests are
    cut to the clip with a warning). placement : see ``body_motion``. truth_masks : store
    the person's silhouettes (bit-packed) in truth.npz. progress : called with the number
    of frames done after each frame. motion_name : recorded in truth.npz (default: the file
    name; for a clip object ``"clip"``), e.g. from ``mocap_rt.studio.variants.load_motion``.
    """
    t_start = time.perf_counter()
    rig = make_rig() if rig is None else rig
    clip = motion if isinstance(motion, BvhClip) else read_bvh(motion)
    if motion_name is None:
        motion_name = "clip" if isinstance(motion, BvhClip) else Path(motion).name
    duration = (clip.n_frames - 1) * clip.frame_time_s
    available = int(np.floor((duration - start_s) * fps + 1e-9)) + 1
    if available < 1:
        raise ValueError(f"{motion}: start {start_s} s is past the clip's end ({duration:.2f} s)")
    n_frames = available if seconds is None else int(round(seconds * fps))
    if n_frames > available:
        log.warning("%s lasts %.2f s; rendering %d frames instead of %d", motion, duration,
                    available, n_frames)
        n_frames = available
    if n_frames < 1:
        raise ValueError(f"seconds must give at least one frame, got {seconds}")
    body = body_motion(clip, fps=fps, n_frames=n_frames, start_s=start_s, placement=placement)
    renderer = StudioRenderer(rig, scene=scene, config=config, seed=seed, fps=fps)
    C = len(rig)
    cue_vis = np.zeros((C, n_frames, len(CUE_NAMES)))
    masks = ([np.zeros((n_frames, cam.height, (cam.width + 7) // 8), np.uint8) for cam in rig.cameras]
             if truth_masks else None)
    render_s = encode_s = 0.0
    with RecordingWriter(out, rig, fps, codec=codec, jpeg_quality=jpeg_quality, source="studio") as writer, \
            ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        for ci, cam in enumerate(rig.cameras):
            bgs = [renderer.render(ci, None, -1 - k).image for k in range(n_backgrounds)]
            writer.write_backgrounds(cam.name, np.stack(bgs))
        for f in range(n_frames):
            t0 = time.perf_counter()
            prims = body_primitives(body.points[f])
            results = list(pool.map(lambda ci: renderer.render(ci, prims, f), range(C)))
            t1 = time.perf_counter()
            writer.write_frame(f, [r.image for r in results], [f / fps] * C)
            t2 = time.perf_counter()
            render_s += t1 - t0
            encode_s += t2 - t1
            for ci, r in enumerate(results):
                cue_vis[ci, f] = r.cue_visibility
                if masks is not None:
                    masks[ci][f] = np.packbits(r.mask, axis=1)
            if progress is not None:
                progress(f + 1)
        writer.write_truth(_truth(rig, body, cue_vis, masks, clip_name=motion_name, seed=seed))
    total = time.perf_counter() - t_start
    return SynthStats(Path(out), n_frames, n_frames * C, render_s, encode_s, total)


def _truth(rig: Rig, body, cue_vis: np.ndarray, masks, clip_name: str, seed: int) -> dict:
    joints = body.joints                                           # (F, 20, 3)
    cues = joints[:, list(CUE_JOINT_INDEX)]                       # (F, 6, 3)
    F = joints.shape[0]
    cues_2d = np.full((len(rig), F, len(CUE_NAMES), 2), np.nan)
    for ci, cam in enumerate(rig.cameras):
        uv, _ = cam.project(cues.reshape(-1, 3))
        cues_2d[ci] = uv.reshape(F, len(CUE_NAMES), 2)
    truth = {
        "joint_names": np.array(JOINT_NAMES),
        "joints": joints,
        "cue_names": np.array(CUE_NAMES),
        "cues": cues,
        "camera_names": np.array(rig.names),
        "cues_2d": cues_2d,
        "cue_visibility": cue_vis,
        "frames": np.arange(F, dtype=np.int64),
        "times_s": body.times_s,
        "bone_names": np.array(bone_names()),
        "bone_lengths": body.bone_lengths(),
        "point_names": np.array(POINT_NAMES),
        "points": body.points,
        "skeleton_family": np.array(body.family),
        "motion_file": np.array(clip_name),
        "seed": np.array(seed),
    }
    if masks is not None:
        truth["masks"] = np.stack(masks)                           # (C, F, H, ceil(W/8))
    return truth


def unpack_masks(truth: dict, width: int) -> np.ndarray:
    """(C, F, H, W) bool silhouettes from ``truth["masks"]``."""
    return np.unpackbits(truth["masks"], axis=-1, count=width).astype(bool)
