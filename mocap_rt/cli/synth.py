"""``mocap-rt synth``: render a studio recording with ground truth from a BVH clip."""

from __future__ import annotations

import argparse


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT, e.g. 640x480, got {text!r}") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"size {text!r} is too small")
    return w, h


def _bgr(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(0 <= v <= 255 for v in vals):
        raise argparse.ArgumentTypeError(f"colour must be B,G,R in 0..255, got {text!r}")
    return vals  # type: ignore[return-value]


def _light(text: str):
    """AZ,EL,INTENSITY[,noshadow] -> (azimuth_deg, elevation_deg, intensity, casts_shadow)."""
    parts = text.split(",")
    try:
        az, el, inten = (float(v) for v in parts[:3])
    except ValueError:
        raise argparse.ArgumentTypeError(f"light must be AZ_DEG,EL_DEG,INTENSITY[,noshadow], got {text!r}") from None
    if len(parts) > 4 or (len(parts) == 4 and parts[3] != "noshadow") or not 3 <= el <= 90 or inten < 0:
        raise argparse.ArgumentTypeError(f"light {text!r}: elevation 3..90 deg, intensity >= 0, "
                                         "optional 4th field 'noshadow'")
    return az, el, inten, len(parts) == 3


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "synth", help="render a multi-camera studio recording with ground truth from a BVH clip",
        description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--motion", required=True,
                   help="BVH clip (CMU, Bandai-Namco or MakeHuman skeleton), or procedural:NAME[:SEED] "
                        "(generated motion, e.g. procedural:jumping_jacks:3; docs/studio.md lists the names)")
    p.add_argument("--variant", default=None,
                   help="reversed (played backwards), mirrored (left/right mirror image), turn:DEG_PER_S "
                        "(turning by a heading ramp); join several with '+'")
    p.add_argument("--out", required=True, help="new recording directory")
    p.add_argument("--rig", choices=("ring", "desktop"), default="ring",
                   help="camera ring around the subject, or the 2-camera desktop rig (upper body)")
    p.add_argument("--cameras", type=int, default=6, help="cameras on the ring")
    p.add_argument("--size", type=_size, default=(640, 480), help="image size WIDTHxHEIGHT")
    p.add_argument("--radius", type=float, default=3.0, help="ring radius, metres")
    p.add_argument("--height", type=float, default=1.6, help="camera height, metres")
    p.add_argument("--hfov", type=float, default=60.0, help="horizontal field of view, degrees")
    p.add_argument("--fps", type=float, default=30.0, help="output frame rate (the clip is resampled)")
    p.add_argument("--seconds", type=float, default=None, help="duration (default: the whole clip)")
    p.add_argument("--start", type=float, default=0.0, help="start time in the clip, seconds")
    p.add_argument("--seed", type=int, default=0, help="seed of noise, flicker and camera gains")
    p.add_argument("--placement", choices=("centre", "first", "none"), default="centre",
                   help="horizontal placement: centre the pelvis path, put the first frame at the origin, or keep")
    p.add_argument("--config", metavar="FILE",
                   help="settings TOML: a [render] table (RenderConfig: noise_sigma_levels, flicker_amplitude, "
                        "flicker_hz, gain_jitter, white_balance_jitter, shadows, albedo_bgr) and a [scene] table "
                        "(StudioScene: floor, backdrop, lights, ambient); the flags below override it")
    # SUPPRESS: absent from args unless given (the config's value stands), no "(default: None)"
    p.add_argument("--noise", type=float, default=argparse.SUPPRESS, help="sensor noise sigma, grey levels (RenderConfig's 2.0)")
    p.add_argument("--flicker", type=float, default=argparse.SUPPRESS, help="global illumination flicker amplitude, 0.05 = 5%% (RenderConfig's 0)")
    p.add_argument("--gain-jitter", type=float, default=argparse.SUPPRESS, help="per-camera gain spread, fraction (RenderConfig's 0.05)")
    p.add_argument("--wb-jitter", type=float, default=argparse.SUPPRESS, help="per-camera white-balance spread, fraction (RenderConfig's 0.03)")
    p.add_argument("--no-shadows", action="store_true", help="do not cast the body's shadow on the floor")
    p.add_argument("--ambient", type=float, default=None, help="ambient light level (default: the scene's)")
    p.add_argument("--light", type=_light, action="append", default=None, metavar="AZ,EL,I[,noshadow]",
                   help="directional light (azimuth from +X towards +Y and elevation in degrees, intensity); "
                        "repeat for several; replaces the default key + fill lights")
    p.add_argument("--shoe-bgr", type=_bgr, default=None, help="shoe colour B,G,R 0..255")
    p.add_argument("--codec", choices=("MJPG", "XVID", "mp4v", "FFV1"), default="MJPG", help="video codec")
    p.add_argument("--jpeg-quality", type=int, default=95, help="MJPG quality (video compression)")
    p.add_argument("--truth-masks", action=argparse.BooleanOptionalAction, default=True,
                   help="store bit-packed person silhouettes in truth.npz")
    p.add_argument("--threads", type=int, default=2, help="render threads")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses
    from pathlib import Path

    from tqdm import tqdm

    from mocap_rt.config import load_dataclass
    from mocap_rt.studio.synth import StudioConfig, make_rig, synthesize

    from mocap_rt.studio.variants import load_motion

    motion, motion_name = load_motion(args.motion, args.variant)
    if (Path(args.out) / "recording.toml").exists():
        raise ValueError(f"--out: {args.out} already holds a recording; choose a new directory")
    if args.fps <= 0 or args.cameras < 1:
        raise ValueError("--fps must be > 0 and --cameras >= 1")
    rig = make_rig(args.rig, args.cameras, args.size, args.radius, args.height, args.hfov)
    settings = load_dataclass(StudioConfig, args.config) if args.config else StudioConfig()
    config = settings.render
    given = vars(args)
    flags = {"noise_sigma_levels": given.get("noise"), "flicker_amplitude": given.get("flicker"),
             "gain_jitter": given.get("gain_jitter"), "white_balance_jitter": given.get("wb_jitter"), "shadows": False if args.no_shadows else None,
             "albedo_bgr": None if args.shoe_bgr is None else
             {**config.albedo_bgr, "shoe": tuple(v / 255.0 for v in args.shoe_bgr)}}
    config = dataclasses.replace(config, **{k: v for k, v in flags.items() if v is not None})
    scene = settings.scene
    if args.ambient is not None:
        scene = dataclasses.replace(scene, ambient=args.ambient)
    if args.light:
        import math

        from mocap_rt.studio.scene import Light

        lights = []
        for az, el, inten, shadow in args.light:
            a, e = math.radians(az), math.radians(el)
            lights.append(Light((math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)), inten, shadow))
        scene = dataclasses.replace(scene, lights=tuple(lights))
    bar = None if args.no_progress else tqdm(unit="frame", desc="synth")

    def progress(done: int) -> None:
        if bar is not None:
            bar.update(done - bar.n)

    try:
        stats = synthesize(motion, args.out, rig=rig, fps=args.fps, seconds=args.seconds, start_s=args.start,
                           seed=args.seed, placement=args.placement, scene=scene, config=config,
                           truth_masks=args.truth_masks, codec=args.codec, jpeg_quality=args.jpeg_quality,
                           threads=args.threads, progress=progress, motion_name=motion_name)
    finally:
        if bar is not None:
            bar.close()
    print(f"wrote {stats.out}: {stats.n_frames} frames x {len(rig)} cameras = {stats.n_images} images "
          f"in {stats.total_s:.1f} s (render {stats.render_s:.1f} s, encode {stats.encode_s:.1f} s)")
    return 0
