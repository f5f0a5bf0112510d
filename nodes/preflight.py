"""``mocap-rt run``'s checks before any node is started.

A node that fails at start-up used to be the first to notice a bad input (a rig that does not
match the recording, a wrong image size, NaN fps, a bad ``--rerun`` spec ...), and the user got
its traceback through the launcher. ``check_run`` reads and checks everything the nodes will
read, so a bad input is one ``ValueError``/``OSError`` naming the file, field or flag, which
the CLI prints as one line (``mocap-rt run: error: ...``, exit code 2).
"""

from __future__ import annotations

import math
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


def check_options(cfg) -> None:
    """The options (``RunConfig``) the nodes would otherwise reject at start-up."""
    from nodes.rerun_sink import check_rerun

    outputs = {"--stats": cfg.stats} if cfg.stats is not None else {}
    if cfg.rerun is not None:
        mode, args = check_rerun(cfg.rerun)
        if mode == "save":
            outputs["--rerun save:"] = Path(args[0])
    check_outputs(cfg, outputs)
    if not (math.isfinite(cfg.deadline_frac) and 0.0 < cfg.deadline_frac <= 1.0):
        raise ValueError(f"--deadline-frac must be in (0, 1], got {cfg.deadline_frac}")
    if cfg.duration_s is not None and not (math.isfinite(cfg.duration_s) and cfg.duration_s > 0):
        raise ValueError(f"--duration must be a number > 0, got {cfg.duration_s}")
    if cfg.preview_every is not None and cfg.preview_every < 0:
        raise ValueError(f"--preview-every must be >= 0, got {cfg.preview_every}")
    if cfg.rt_priority is not None and not 0 <= cfg.rt_priority <= MAX_RT_PRIORITY:
        raise ValueError(f"--rt-priority must be in 0..{MAX_RT_PRIORITY}, got {cfg.rt_priority}")
    if not -20 <= cfg.nice <= 19:
        raise ValueError(f"--nice must be in -20..19, got {cfg.nice}")
    if cfg.record is not None and Path(cfg.record).exists() and not Path(cfg.record).is_dir():
        raise ValueError(f"--record {cfg.record}: exists and is not a directory")
    if cfg.bones is not None:
        from mocap_rt.body.skeleton import read_bone_lengths

        read_bone_lengths(cfg.bones)
    if cfg.backgrounds_from is not None and not (Path(cfg.backgrounds_from) / "recording.toml").is_file():
        raise FileNotFoundError(f"--backgrounds-from {cfg.backgrounds_from}: not a recording directory")
    if cfg.stream is not None:
        from mocap_rt.io.vmc import parse_vmc_target

        parse_vmc_target(cfg.stream, cfg.allow_remote_stream)


def check_outputs(cfg, outputs: dict[str, Path]) -> None:
    """The run's output files (flag -> path): never an input, never each other, never an existing
    file unless ``--overwrite`` (an earlier run's statistics or viewer recording is a result too)."""
    from mocap_rt.io.files import OutputError, claim_outputs, refuse_input_as_output, same_file

    inputs = [p for p in (cfg.rig_path, cfg.bones) if p is not None]
    for flag, path in outputs.items():
        refuse_input_as_output(path, inputs, flag)
        if path.is_dir():
            raise OutputError(f"{flag} {path}: is a directory (give a file name)")
        claim_outputs([path], cfg.overwrite, flag)
    if len(outputs) == 2 and same_file(*outputs.values()):
        raise OutputError(f"--stats and --rerun save: name one file ({cfg.stats}); give two")


def rig_path_for(source: str, rig: Path | None) -> Path:
    """``--rig``, else a recording's ``rig.toml`` (replay/fake sources); ValueError for others."""
    from nodes.sources import parse_source

    kind, value = parse_source(source)
    if rig is not None:
        return Path(rig)
    if kind not in ("replay", "fake"):
        raise ValueError(f"--rig is required for {kind} sources")
    return Path(value) / "rig.toml"


def check_run(cfg) -> None:
    """All checks of ``mocap-rt run`` (module doc) on its ``RunConfig``."""
    from mocap_rt.geometry.rig import read_rig
    from nodes.sources import parse_source

    kind, value = parse_source(cfg.source)
    check_options(cfg)
    rig_path = cfg.rig_path
    if not Path(rig_path).is_file():
        raise FileNotFoundError(f"rig file {rig_path} not found")
    rig = read_rig(rig_path)
    if kind in ("replay", "fake"):
        from mocap_rt.io.recording import Recording

        if not (Path(value) / "recording.toml").is_file():
            raise FileNotFoundError(f"--source {cfg.source}: {value} is not a recording directory "
                                    f"(no recording.toml)")
        with Recording(value) as rec:          # recording.toml, frames.csv, video sizes: checked on open
            if rec.n_frames < 1:
                raise ValueError(f"--source {cfg.source}: the recording has no frames")
            check_rig_against_recording(rig, Path(rig_path), rec)
    else:
        from nodes.plan import worker_sources

        worker_sources(cfg.source, list(rig.names))     # v4l2: one device per rig camera
