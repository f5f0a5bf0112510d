"""``mocap-rt perceive REC_DIR --out CUES.npz``: run per-camera perception over a recording.

Every camera, every frame. By default the loop is closed as in ``mocap-rt process`` and
the live service: fusion (``BodyTracker``) triangulates each frame's cues and its 3D
prediction, projected into every camera with Z-buffer visibility (seed digest A.4),
guides the next frame's perception. ``--open-loop`` runs each camera on its own 2D tracks
(no fusion; also what a recording with fewer than two of the chosen cameras gets).

In the closed loop the torso cue written is the fused body's torso point (the pelvis-neck
midpoint) projected into each camera that found a torso (``fusion.offline.with_fused_torso``):
closer to the truth and never lost for long, where the measured one is the trunk's visible
centre; the measured one is kept as ``torso_measured_2d``.

The npz holds ``camera_names`` (C,), ``cue_names`` (6,), ``frames`` (F,), ``cues_2d``
(C, F, 6, 2) pixels (NaN = not found), ``torso_measured_2d`` (C, F, 2) the torso as each camera
measured it (in the open loop the same as ``cues_2d``'s), ``confidence`` (C, F, 6), ``cov`` (C, F, 6, 2, 2),
``legs_2d`` (C, F, 2, 2) pixels where the legs meet the left and right shoe blobs (the heel
ends, ``perception.leg_attach``; NaN = not measured), ``bbox`` (C, F, 4), ``ms_per_frame``
(C, F) perception milliseconds and ``closed_loop`` ().
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("perceive", help="2D cues (head, hands, feet, torso) of every camera of a recording",
                              description=__doc__)
    p.add_argument("recording", type=Path, help="recording directory (mocap_rt.io.recording format)")
    p.add_argument("--out", type=Path, required=True, help="output .npz")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="settings TOML: [perception] (PerceptionConfig) and [fusion] (FusionConfig, the "
                        "closed loop) tables (mocap_rt/pipeline_config.py)")
    p.add_argument("--skin-model", default="auto",
                   help="skin model: a TOML file, a shipped name (skin, studio_skin) or 'auto' "
                        "(studio_skin for studio recordings, else the config's / shipped skin)")
    p.add_argument("--cameras", nargs="*", help="only these cameras (default: all, rig order)")
    p.add_argument("--open-loop", action="store_true",
                   help="2D only: each camera follows its own 2D tracks (default: fusion's 3D predictions)")
    p.add_argument("--max-frames", type=int, default=0, help="stop after this many frames (0 = all)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def perceive_recording(rec, cameras: list[str], config, max_frames: int = 0, progress: bool = False,
                       closed_loop: bool = True, fusion_config=None) -> dict:
    """Run ``CameraPerceiver`` over cameras of an open ``Recording``; returns the npz arrays.

    closed_loop : fusion's predictions guide perception (needs >= 2 cameras; with fewer
        the run is open loop and ``closed_loop`` in the result says so).
    fusion_config : ``FusionConfig`` of the closed loop (default: the recording's fps).
    """
    from dataclasses import replace

    import numpy as np
    from tqdm import tqdm

    from mocap_rt.names import C_TORSO, CUE_NAMES, N_CUES
    from mocap_rt.perception.pipeline import CameraPerceiver

    n = rec.n_frames if max_frames <= 0 else min(rec.n_frames, max_frames)
    C = len(cameras)
    cues = np.full((C, n, N_CUES, 2), np.nan)
    conf = np.zeros((C, n, N_CUES))
    cov = np.full((C, n, N_CUES, 2, 2), np.nan)
    legs = np.full((C, n, 2, 2), np.nan)
    bbox = np.zeros((C, n, 4), np.int64)
    ms = np.full((C, n), np.nan)
    perceivers = {}
    for name in cameras:
        bgs = rec.backgrounds(name)
        if len(bgs) == 0:
            raise ValueError(f"{rec.path}: camera {name} has no background frames (backgrounds/{name}/*.png)")
        perceivers[name] = CameraPerceiver(rec.rig[name], bgs, config)
    iters = {name: rec.iter_frames(name) for name in cameras}
    frames = np.asarray(rec.frames)[:n]

    def frame_cues(i: int, predictions) -> tuple[int, dict]:
        out = {}
        for c, name in enumerate(cameras):
            _, img = next(iters[name])
            pred = None if predictions is None else predictions.get(name)
            cc = perceivers[name].process(img, int(frames[i]), pred)
            cues[c, i], conf[c, i], cov[c, i], bbox[c, i] = cc.xy, cc.confidence, cc.cov, cc.bbox
            if cc.leg_xy is not None:
                legs[c, i] = cc.leg_xy
            ms[c, i] = cc.timings_ms["total"]
            out[name] = cc
        return int(frames[i]), out

    closed_loop = closed_loop and C >= 2
    results = None
    if closed_loop:
        from mocap_rt.fusion.config import FusionConfig
        from mocap_rt.fusion.offline import run_tracker, with_fused_torso
        from mocap_rt.fusion.tracker import BodyTracker

        fc = replace(fusion_config or FusionConfig(), fps=float(rec.fps))
        results = run_tracker(BodyTracker(rec.rig, fc), frame_cues, n, progress)
    else:
        for i in tqdm(range(n), disable=not progress, unit="frame", desc="perceive"):
            frame_cues(i, None)
    measured = cues[:, :, C_TORSO].copy()
    if results is not None:
        cues = with_fused_torso(cues, [rec.rig[name] for name in cameras], np.array([r.joints for r in results]),
                                np.array([r.joint_valid for r in results]))
    return {"camera_names": np.array(cameras), "cue_names": np.array(CUE_NAMES), "frames": frames.copy(),
            "cues_2d": cues, "torso_measured_2d": measured, "confidence": conf, "cov": cov, "legs_2d": legs,
            "bbox": bbox, "ms_per_frame": ms, "closed_loop": np.array(closed_loop)}


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import numpy as np

    from mocap_rt.io.recording import Recording
    from mocap_rt.perception.pipeline import config_for_source
    from mocap_rt.pipeline_config import PipelineConfig, load_pipeline_config

    settings = load_pipeline_config(args.config) if args.config else PipelineConfig()
    config = settings.perception
    with Recording(args.recording) as rec:
        if args.skin_model == "auto":
            config = config_for_source(config, rec.source)
        else:
            config = replace(config, skin_model_path=args.skin_model)
        cameras = list(args.cameras) if args.cameras else list(rec.camera_names)
        unknown = [c for c in cameras if c not in rec.camera_names]
        if unknown:
            raise ValueError(f"{args.recording}: no camera {unknown} (has {rec.camera_names})")
        result = perceive_recording(rec, cameras, config, args.max_frames, progress=not args.no_progress,
                                    closed_loop=not args.open_loop, fusion_config=settings.fusion)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **result)
    found = np.isfinite(result["cues_2d"][..., 0]).mean(axis=(0, 1))
    ms = result["ms_per_frame"]
    loop = "closed loop (fusion's 3D predictions)" if result["closed_loop"] else "open loop (2D tracks)"
    print(f"{args.out}: {len(cameras)} cameras x {result['frames'].size} frames, {loop}; "
          f"median {np.nanmedian(ms):.2f} ms/frame; found " +
          ", ".join(f"{n} {v:.0%}" for n, v in zip(result["cue_names"], found)))
    return 0
