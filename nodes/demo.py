"""``make demo``: the full process cluster on a six-camera studio replay, viewed in Rerun.

On the first run a studio recording is rendered from a real CMU clip (6 cameras,
640x480, 30 fps) into ``OUT/studio_<clip>``; then ``mocap-rt run`` replays it through sync,
six camera workers, fusion, recorder and viewer (``--rerun save:OUT/demo.rrd``,
``--record OUT/poses``, ``--stats OUT/stats.json``) and prints how to open the result.

    python -m nodes.demo --out out/demo --data ../shared/data
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
from pathlib import Path

DEFAULT_CLIP = "bvh/cmu/cmu_02_01_walk.bvh"      # CMU subject 2, trial 1: walk (2.9 s)
DEFAULT_SIZE = (640, 480)


def ensure_recording(out: Path, data: Path, clip: str, seconds: float | None) -> Path:
    """The studio recording of ``clip`` under ``out`` (rendered once, reused afterwards)."""
    from mocap_rt.studio.synth import make_rig, synthesize

    motion = data / clip
    if not motion.is_file():
        raise FileNotFoundError(f"motion clip {motion} not found (is --data the shared data folder?)")
    rec = out / f"studio_{motion.stem}"
    if (rec / "recording.toml").is_file():
        return rec
    if rec.exists():             # an interrupted earlier render: start again
        shutil.rmtree(rec)
    print(f"demo: rendering the studio recording {rec} from {motion} (first run only) ...", flush=True)
    stats = synthesize(motion, rec, rig=make_rig(n_cameras=6, size=DEFAULT_SIZE), seconds=seconds)
    print(f"demo: {stats.n_frames} frames x 6 cameras in {stats.total_s:.1f} s", flush=True)
    return rec


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/demo"))
    p.add_argument("--data", type=Path, default=Path("../shared/data"))
    p.add_argument("--clip", default=DEFAULT_CLIP, help="BVH clip under --data")
    p.add_argument("--seconds", type=float, default=None, help="render only this much of the clip")
    p.add_argument("--duration", type=float, default=None, help="run time (default: one pass of the replay)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    from nodes.launcher import Launcher, RunConfig

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    rec = ensure_recording(out, args.data, args.clip, args.seconds)
    rrd, stats_path, poses = out / "demo.rrd", out / "stats.json", out / "poses"
    if poses.exists():           # a previous demo's poses: keep them, under a new name
        poses.rename(out / f"poses.previous.{int(poses.stat().st_mtime)}")
    rrd.unlink(missing_ok=True)
    cfg = RunConfig(rig_path=rec / "rig.toml", source=f"replay:{rec}", duration_s=args.duration,
                    rerun=f"save:{rrd}", record=poses, stats=stats_path, log_dir=out / "logs")
    launcher = Launcher(cfg)
    print(f"demo: replaying {rec} through {len(launcher.nodes)} processes "
          f"(sync, {len(launcher.rig)} camera workers, fusion, recorder, viewer) ...", flush=True)
    stats = launcher.run()
    lat = stats["latency_ms"]
    print()
    print(f"frames triggered {stats['frames_triggered']}, poses {stats['poses_published']}, "
          f"dropped {stats['frames_dropped']}; latency trigger->pose p50 {lat['p50']:.1f} ms, "
          f"p95 {lat['p95']:.1f} ms, p99 {lat['p99']:.1f} ms")
    print("CPU seconds per node: " + json.dumps(stats["cpu_s"]))
    print(f"poses: {poses}/poses.bvh, {poses}/poses.npz; statistics: {stats_path}; node logs: {out / 'logs'}")
    print(f"open the figure with:  .venv/bin/rerun {rrd}")
    return 0 if stats["poses_published"] > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
