"""``mocap-rt process REC_DIR --out OUT_DIR``: perception + fusion + IK over a recording."""

from __future__ import annotations

import argparse
from pathlib import Path

# the choices of --views / --ik (mocap_rt.fusion.config.VIEW_MODES / IK_MODES; not imported
# here so that ``mocap-rt --help`` stays quick; tests/fusion checks they agree)
VIEW_MODES = ("all", "pair")
IK_MODES = ("analytic", "ccd")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "process", help="run perception, fusion and IK over a recording; write poses.bvh, .npz, .c3d and .trc",
        description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("rec_dir", metavar="REC_DIR", help="recording directory (docs/recording-format.md)")
    p.add_argument("--out", required=True, metavar="OUT_DIR", help="output directory")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="settings TOML: [perception] (PerceptionConfig) and [fusion] (FusionConfig) tables "
                        "(mocap_rt/pipeline_config.py); the flags below override it")
    # SUPPRESS: absent from args unless given (the config's value stands), no "(default: None)"
    p.add_argument("--views", choices=VIEW_MODES, default=argparse.SUPPRESS,
                   help="triangulate from all cameras that see a cue, or the frontal pair (A.6) "
                        "(default: the config's, 'all')")
    p.add_argument("--ik", choices=IK_MODES, default=argparse.SUPPRESS,
                   help="analytic two-link IK, or analytic + improved-CCD refinement (default: the config's, 'analytic')")
    p.add_argument("--bones", metavar="TOML", help="subject bone lengths ([bones] table); "
                   "default: estimated from the first seconds of cues")
    p.add_argument("--smooth-hz", type=float, default=argparse.SUPPRESS, metavar="HZ",
                   help="low-pass the clip's poses both ways at this cutoff once all are solved (no lag; "
                        "mocap_rt/fusion/smooth.py); 0: off, the poses as the live service publishes them "
                        "(default: the config's, 4)")
    p.add_argument("--max-frames", type=int, help="process only the first N frames")
    p.add_argument("--truth-2d", action="store_true",
                   help="feed the truth's 2D cues instead of perception (studio recordings)")
    p.add_argument("--noise-px", type=float, default=1.0, help="pixel noise added with --truth-2d")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the poses.* and bones.toml of an earlier run in OUT_DIR")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from mocap_rt.body.skeleton import read_bone_lengths
    from mocap_rt.fusion.offline import process_recording
    from mocap_rt.fusion.config import FusionConfig
    from mocap_rt.io.files import claim_outputs, refuse_input_as_output
    from mocap_rt.pipeline_config import load_pipeline_config

    rec = Path(args.rec_dir)
    if not rec.is_dir():
        raise FileNotFoundError(f"recording directory not found: {rec}")
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames must be >= 1, got {args.max_frames}")
    outputs = [Path(args.out) / name for name in ("poses.bvh", "poses.npz", "bones.toml", "poses.c3d", "poses.trc")]
    for o in outputs:
        refuse_input_as_output(o, [args.bones, args.config, *(rec / n for n in ("truth.npz", "rig.toml"))])
    settings = load_pipeline_config(args.config) if args.config else None
    claim_outputs(outputs, args.overwrite)
    cfg = settings.fusion if settings else FusionConfig()
    flags = {"views": getattr(args, "views", None), "ik": getattr(args, "ik", None),
             "offline_smooth_hz": getattr(args, "smooth_hz", None),
             "bone_lengths": read_bone_lengths(args.bones) if args.bones else None}
    cfg = replace(cfg, **{k: v for k, v in flags.items() if v is not None})
    out = process_recording(rec, args.out, cfg, settings.perception if settings else None,
                            max_frames=args.max_frames, truth_2d=args.truth_2d,
                            noise_px=args.noise_px, progress=not args.no_progress)
    print(f"wrote {Path(args.out) / 'poses.bvh'}, poses.npz, poses.c3d, poses.trc and bones.toml ({len(out.frames)} frames)")
    print("timings (ms): " + ", ".join(f"{k} {v:.2f}" for k, v in out.timings_ms.items()))
    if out.accuracy is not None:
        print(out.accuracy.summary())
    return 0
