"""``mocap-rt perceive REC_DIR --out CUES.npz``: run per-camera perception over a recording.

Every camera, every frame; predictions come from each camera's own 2D tracks (the 3D
predictor is not used here). The npz holds ``camera_names`` (C,), ``cue_names`` (6,),
``frames`` (F,), ``cues_2d`` (C, F, 6, 2) pixels (NaN = not found), ``confidence``
(C, F, 6), ``cov`` (C, F, 6, 2, 2), ``bbox`` (C, F, 4) and ``ms_per_frame`` (C, F).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("perceive", help="2D cues (head, hands, feet, torso) of every camera of a recording",
                              description=__doc__)
    p.add_argument("recording", type=Path, help="recording directory (mocap_rt.io.recording format)")
    p.add_argument("--out", type=Path, required=True, help="output .npz")
    p.add_argument("--config", type=Path, help="perception config TOML (PerceptionConfig fields)")
    p.add_argument("--skin-model", default="auto",
                   help="skin model: a TOML file, a shipped name (skin, studio_skin) or 'auto' "
                        "(studio_skin for studio recordings, else the config's / shipped skin)")
    p.add_argument("--cameras", nargs="*", help="only these cameras (default: all, rig order)")
    p.add_argument("--max-frames", type=int, default=0, help="stop after this many frames (0 = all)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def perceive_recording(rec, cameras: list[str], config, max_frames: int = 0, progress: bool = False) -> dict:
    """Run ``CameraPerceiver`` over cameras of an open ``Recording``; returns the npz arrays."""
    import numpy as np
    from tqdm import tqdm

    from mocap_rt.names import CUE_NAMES
    from mocap_rt.perception.pipeline import CameraPerceiver

    n = rec.n_frames if max_frames <= 0 else min(rec.n_frames, max_frames)
    C = len(cameras)
    cues = np.full((C, n, 6, 2), np.nan)
    conf = np.zeros((C, n, 6))
    cov = np.full((C, n, 6, 2, 2), np.nan)
    bbox = np.zeros((C, n, 4), np.int64)
    ms = np.full((C, n), np.nan)
    bar = tqdm(total=C * n, unit="img", disable=not progress)
    for c, name in enumerate(cameras):
        bgs = rec.backgrounds(name)
        if len(bgs) == 0:
            raise ValueError(f"{rec.path}: camera {name} has no background frames (backgrounds/{name}/*.png)")
        perceiver = CameraPerceiver(rec.rig[name], bgs, config)
        for f, img in rec.iter_frames(name):
            if f >= n:
                break
            out = perceiver.process(img, int(rec.frames[f]))
            cues[c, f], conf[c, f], cov[c, f] = out.xy, out.confidence, out.cov
            bbox[c, f] = out.bbox
            ms[c, f] = out.timings_ms["total"]
            bar.update(1)
    bar.close()
    return {"camera_names": np.array(cameras), "cue_names": np.array(CUE_NAMES), "frames": rec.frames[:n].copy(),
            "cues_2d": cues, "confidence": conf, "cov": cov, "bbox": bbox, "ms_per_frame": ms}


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    import numpy as np

    from mocap_rt.io.recording import Recording
    from mocap_rt.perception.pipeline import PerceptionConfig, config_for_source, load_perception_config

    config = load_perception_config(args.config) if args.config else PerceptionConfig()
    with Recording(args.recording) as rec:
        if args.skin_model == "auto":
            config = config_for_source(config, rec.source)
        else:
            config = replace(config, skin_model_path=args.skin_model)
        cameras = list(args.cameras) if args.cameras else list(rec.camera_names)
        unknown = [c for c in cameras if c not in rec.camera_names]
        if unknown:
            raise ValueError(f"{args.recording}: no camera {unknown} (has {rec.camera_names})")
        result = perceive_recording(rec, cameras, config, args.max_frames, progress=not args.no_progress)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **result)
    found = np.isfinite(result["cues_2d"][..., 0]).mean(axis=(0, 1))
    ms = result["ms_per_frame"]
    print(f"{args.out}: {len(cameras)} cameras x {result['frames'].size} frames; "
          f"median {np.nanmedian(ms):.2f} ms/frame; found " +
          ", ".join(f"{n} {v:.0%}" for n, v in zip(result["cue_names"], found)))
    return 0
