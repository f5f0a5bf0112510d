"""``mocap-rt run``'s checks before any node is started.

A node that fails at start-up used to be the first to notice a bad input (a rig that does not
match the recording, a wrong image size, NaN fps, a bad ``--rerun`` spec ...), and the user got
its traceback through the launcher. ``check_run`` reads and checks everything the nodes will
read, so a bad input is one ``ValueError``/``OSError`` naming the file, field or flag, which
the CLI prints as one line (``mocap-rt run: error: ...``, exit code 2).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

MAX_RT_PRIORITY = 97            # the launcher adds up to 2 for fusion and sync (SCHED_FIFO max 99)


def check_rig_against_recording(rig, rig_path: Path, rec) -> None:
    """Every rig camera is a camera of the recording, with the recording's image size."""
    rec_cams = list(rec.camera_names)
    missing = [c for c in rig.names if c not in rec_cams]
    if missing:
        raise ValueError(f"--rig {rig_path}: camera(s) {missing} are not in the recording {rec.path} "
                         f"(it has {rec_cams})")
    for cam in rig.cameras:
        want = tuple(rec.rig[cam.name].size)
        if tuple(cam.size) != want:
            raise ValueError(f"--rig {rig_path}: camera {cam.name!r} has size {cam.size[0]}x{cam.size[1]}, the "
                             f"recording's images are {want[0]}x{want[1]}")


def check_options(args) -> None:
    """The flags the nodes would otherwise reject at start-up."""
    from nodes.viewer import parse_rerun

    if args.rerun is not None:
        mode, _ = parse_rerun(args.rerun)
        if mode == "spawn" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise ValueError("--rerun spawn needs a display (DISPLAY/WAYLAND_DISPLAY unset); "
                             "use --rerun save:FILE.rrd or serve")
    if not (math.isfinite(args.deadline_frac) and 0.0 < args.deadline_frac <= 1.0):
        raise ValueError(f"--deadline-frac must be in (0, 1], got {args.deadline_frac}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be a number > 0, got {args.duration}")
    if args.preview_every is not None and args.preview_every < 0:
        raise ValueError(f"--preview-every must be >= 0, got {args.preview_every}")
    if args.rt_priority is not None and not 0 <= args.rt_priority <= MAX_RT_PRIORITY:
        raise ValueError(f"--rt-priority must be in 0..{MAX_RT_PRIORITY}, got {args.rt_priority}")
    if not -20 <= args.nice <= 19:
        raise ValueError(f"--nice must be in -20..19, got {args.nice}")
    if args.record is not None and Path(args.record).exists() and not Path(args.record).is_dir():
        raise ValueError(f"--record {args.record}: exists and is not a directory")
    if args.bones is not None:
        from mocap_rt.body.skeleton import read_bone_lengths

        read_bone_lengths(args.bones)
    bg = getattr(args, "backgrounds_from", None)
    if bg is not None and not (Path(bg) / "recording.toml").is_file():
        raise FileNotFoundError(f"--backgrounds-from {bg}: not a recording directory")
    if getattr(args, "stream", None) is not None:
        from mocap_rt.io.vmc import parse_vmc_target

        parse_vmc_target(args.stream, args.allow_remote_stream)


def check_run(args) -> Path:
    """All checks of ``mocap-rt run`` (module doc); returns the rig path to use."""
    from mocap_rt.geometry.rig import read_rig
    from nodes.sources import parse_source

    kind, value = parse_source(args.source)
    check_options(args)
    rig_path = args.rig
    if rig_path is None:
        if kind not in ("replay", "fake"):
            raise ValueError(f"--rig is required for {kind} sources")
        rig_path = Path(value) / "rig.toml"
    if not Path(rig_path).is_file():
        raise FileNotFoundError(f"rig file {rig_path} not found")
    rig = read_rig(rig_path)
    if kind in ("replay", "fake"):
        from mocap_rt.io.recording import Recording

        if not (Path(value) / "recording.toml").is_file():
            raise FileNotFoundError(f"--source {args.source}: {value} is not a recording directory "
                                    f"(no recording.toml)")
        with Recording(value) as rec:          # recording.toml, frames.csv, video sizes: checked on open
            if rec.n_frames < 1:
                raise ValueError(f"--source {args.source}: the recording has no frames")
            check_rig_against_recording(rig, Path(rig_path), rec)
    elif kind == "v4l2" and len(value.split(",")) != len(rig):
        raise ValueError(f"--source v4l2: {len(value.split(','))} device(s) for {len(rig)} rig cameras "
                         f"(give one per camera, in rig order, comma-separated)")
    return Path(rig_path)
