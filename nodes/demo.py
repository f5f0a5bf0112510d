"""``make demo``: the full process cluster on a six-camera studio replay, viewed in Rerun.

On the first run a studio recording is rendered from a real CMU walk (6 cameras, 640x480,
30 fps, 2.9 s) into ``OUT/studio_<clip>`` and kept; then ``mocap-rt run`` replays it
``--loops`` times (4: ~12 s of motion; the figure is back at the start of its walk at each
loop) through sync, six camera workers, fusion, recorder and viewer (``--rerun
save:OUT/demo.rrd``, ``--record OUT/poses``, ``--stats OUT/stats.json``), and prints what
was measured and how to open the recording and the live web viewer.

    python -m nodes.demo --out out/demo --data ../shared/data
"""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
from pathlib import Path

DEFAULT_CLIP = "bvh/cmu/cmu_02_01_walk.bvh"      # CMU subject 2, trial 1: walk (2.9 s)
DEFAULT_SIZE = (640, 480)
DEFAULT_LOOPS = 4


def ensure_recording(out: Path, data: Path, clip: str, seconds: float | None) -> Path:
    """The studio recording of ``clip`` under ``out`` (rendered once, reused afterwards)."""
    from mocap_rt.studio.synth import make_rig, synthesize

    motion = data / clip
    if not motion.is_file():
        raise FileNotFoundError(f"motion clip {motion} not found (is --data the shared data folder?)")
    rec = out / f"studio_{motion.stem}" if seconds is None else out / f"studio_{motion.stem}_{seconds:g}s"
    if (rec / "recording.toml").is_file():
        return rec
    if rec.exists():             # an interrupted earlier render: start again
        shutil.rmtree(rec)
    print(f"demo: rendering the studio recording {rec} from {motion} (first run only) ...", flush=True)
    stats = synthesize(motion, rec, rig=make_rig(n_cameras=6, size=DEFAULT_SIZE), seconds=seconds)
    print(f"demo: {stats.n_frames} frames x 6 cameras in {stats.total_s:.1f} s", flush=True)
    return rec


def _rel(p: Path) -> str:
    """``p`` relative to the working directory when below it (shorter commands to copy)."""
    try:
        return str(Path(os.path.relpath(p)) if not os.path.relpath(p).startswith("..") else p)
    except ValueError:
        return str(p)


def _most_missing(counts: dict[str, int], n: int = 3) -> str:
    """``"; late or missing: cam_3 12, cam_5 4"``: the cameras most often absent from a pose."""
    worst = sorted(((k, c) for c, k in counts.items() if k), reverse=True)[:n]
    return "; late or missing: " + ", ".join(f"{c} {k}" for k, c in worst) if worst else ""


def summary(stats: dict, rec: Path, out: Path, rrd: Path, poses: Path, stats_path: Path) -> list[str]:
    """The lines printed at the end: what was measured, where it is, how to look at it."""
    lat = stats["latency_ms"]
    trig, n_poses = stats["frames_triggered"], stats["poses_published"]
    all_cams = n_poses - stats["poses_with_missing_cameras"]
    pct = (lambda a, b: 100.0 * a / b if b else 0.0)
    rerun = _rel(Path(sys.executable).with_name("rerun"))
    mocap = _rel(Path(sys.executable).with_name("mocap-rt"))
    viewer = stats["nodes"].get("viewer", {})
    return [
        f"demo: {trig} frames triggered in {stats['run_s']:.1f} s ({stats['trigger_fps']:.0f} fps), "
        f"{n_poses} poses ({pct(n_poses, trig):.1f} %), {stats['frames_dropped']} frames without a pose, "
        f"{all_cams} poses from all {len(stats['cameras'])} cameras ({pct(all_cams, n_poses):.1f} %)"
        + _most_missing(stats.get("poses_missing_camera", {})),
        f"demo: latency trigger -> pose p50 {lat['p50']:.1f} ms, p95 {lat['p95']:.1f} ms, "
        f"p99 {lat['p99']:.1f} ms, max {lat['max']:.1f} ms; node drops {stats['node_drops']} "
        f"(viewer {viewer.get('drops', 0)}), restarts {sum(n['restarts'] for n in stats['nodes'].values())}",
        f"demo: poses {_rel(poses)}/poses.bvh (Blender), {_rel(poses)}/poses.npz; statistics {_rel(stats_path)}; "
        f"node logs {_rel(out / 'logs')}",
        f"demo: open the recording:   {rerun} {_rel(rrd)}",
        f"demo: live web viewer:      {mocap} run --source replay:{_rel(rec)} --rerun serve --duration 60",
        "demo:                        then open http://127.0.0.1:9090 (the exact URL is in the viewer's "
        "log line 'viewer: open ...'; 127.0.0.1 only: use an SSH tunnel from another machine)",
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/demo"))
    p.add_argument("--data", type=Path, default=Path("../shared/data"))
    p.add_argument("--clip", default=DEFAULT_CLIP, help="BVH clip under --data")
    p.add_argument("--seconds", type=float, default=None, help="render only this much of the clip")
    p.add_argument("--loops", type=int, default=DEFAULT_LOOPS, help="passes of the replay (it loops)")
    p.add_argument("--duration", type=float, default=None, help="run time in s (overrides --loops)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from mocap_rt.io.recording import Recording
    from nodes.launcher import Launcher, RunConfig

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    rec = ensure_recording(out, args.data, args.clip, args.seconds)
    rrd, stats_path, poses = out / "demo.rrd", out / "stats.json", out / "poses"
    if poses.exists():           # a previous demo's poses: keep them, under a new name
        poses.rename(out / f"poses.previous.{int(poses.stat().st_mtime)}")
    rrd.unlink(missing_ok=True)
    replay = Recording(rec)
    duration = args.duration if args.duration is not None else args.loops * replay.n_frames / replay.fps
    cfg = RunConfig(rig_path=rec / "rig.toml", source=f"replay:{rec}", duration_s=duration,
                    rerun=f"save:{rrd}", record=poses, stats=stats_path, log_dir=out / "logs")
    launcher = Launcher(cfg)
    print(f"demo: replaying {rec} ({replay.n_frames / replay.fps:.1f} s, {duration:.1f} s of motion) through "
          f"{len(launcher.nodes)} processes (sync, {len(launcher.rig)} camera workers, fusion, recorder, "
          f"viewer) ...", flush=True)
    stats = launcher.run()
    print()
    for line in summary(stats, rec, out, rrd, poses, stats_path):
        print(line)
    return 0 if stats["poses_published"] > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
