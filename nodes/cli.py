"""``mocap-rt run``: the real-time capture service, every node its own process.

Also ``mocap-rt node ROLE ...`` to start a single node by hand or from systemd
(``sync``, ``camera``, ``fusion``, ``recorder``, ``viewer``, ``stream``), with the node's own flags.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mocap_rt.fusion.gather import DEFAULT_DEADLINE_FRAC
from nodes.plan import DEFAULT_PREVIEW_EVERY

NODE_MODULES = {"sync": "nodes.sync", "camera": "nodes.camera_worker", "fusion": "nodes.fusion_node",
                "recorder": "nodes.recorder", "viewer": "nodes.viewer", "stream": "nodes.streamer"}


def _speed(text: str) -> float | None:
    if text == "max":
        return None
    v = float(text)
    if v <= 0:
        raise argparse.ArgumentTypeError("--speed must be > 0 or 'max'")
    return v


# flags of ``mocap-rt run`` whose ``RunConfig`` field has another name or sense
FLAG_FIELDS = {"rig": ("rig_path", lambda v: v), "duration": ("duration_s", lambda v: v),
               "no_restart": ("restart", lambda v: not v), "quiet": ("status_line", lambda v: not v)}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help="run the real-time capture service (sync, camera workers, fusion, recorder, viewer)",
        description="Start every node of the service as its own process on this host (Zenoh peers on "
                    "127.0.0.1), show a live status line, stop on Ctrl-C or after --duration.",
        argument_default=argparse.SUPPRESS)      # a flag not given leaves the RunConfig (or --config) value
    p.add_argument("--config", type=Path, default=None, metavar="RUN.toml",
                   help="the run's settings as TOML (the fields of nodes.run_config.RunConfig: rig_path, source, "
                        "speed, duration_s, record, ...); flags given as well win")
    p.add_argument("--rig", type=Path, help="rig TOML (default for replay/fake sources: REC_DIR/rig.toml)")
    p.add_argument("--source",
                   help="replay:REC_DIR | v4l2:/dev/video0,/dev/video2,... (one per camera) | fake:REC_DIR | "
                        "gst:'PIPELINE' ({camera}/{index} filled in per camera; see docs/sources.md); required, "
                        "here or in --config")
    p.add_argument("--backgrounds-from", type=Path, metavar="REC_DIR",
                   help="gst: sources: the empty-scene backgrounds (and source kind) of this recording "
                        "instead of capturing them at start")
    p.add_argument("--speed", type=_speed, help="replay speed factor or 'max' (default 1.0)")
    p.add_argument("--duration", type=float, help="seconds to run (default: one pass of a replay; live: until Ctrl-C)")
    p.add_argument("--rerun", help="viewer: save:FILE.rrd | serve[:PORT] | spawn")
    p.add_argument("--record", type=Path, help="record poses (BVH, NPZ) and live streams here")
    p.add_argument("--stats", type=Path, help="write run statistics JSON here")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --stats or --rerun save: file (otherwise the run refuses to start; "
                        "--record never overwrites: it writes poses_001.* beside an earlier recording)")
    p.add_argument("--stream", metavar="vmc[:HOST[:PORT]]",
                   help="send every pose as a VMC protocol bundle (OSC/UDP; default 127.0.0.1:39539) to "
                        "VSeeFace, EVMC4U, Warudo ...; see docs/streaming.md")
    p.add_argument("--allow-remote-stream", action="store_true",
                   help="let --stream send to a host other than this one (plain UDP, unauthenticated)")
    p.add_argument("--deadline-frac", type=float,
                   help=f"fusion waits for late cameras at most this fraction of a frame period "
                        f"(default {DEFAULT_DEADLINE_FRAC})")
    p.add_argument("--bones", type=Path, metavar="TOML",
                   help="the subject's bone lengths ([bones] table, e.g. bones.toml of mocap-rt process); "
                        "default: estimated from the first seconds of the capture")
    p.add_argument("--preview-every", type=int,
                   help=f"camera image to the viewer every N frames (default {DEFAULT_PREVIEW_EVERY} with --rerun)")
    p.add_argument("--no-restart", action="store_true", help="do not restart nodes that die")
    p.add_argument("--log-dir", type=Path, help="node logs (default: a temp dir)")
    p.add_argument("--quiet", action="store_true", help="no live status line")
    p.add_argument("--nice", type=int, help="niceness of sync, workers and fusion, e.g. -10 (needs root or CAP_SYS_NICE)")
    p.add_argument("--rt-priority", type=int,
                   help="SCHED_FIFO priority of the workers once warmed up (fusion the same, sync +2); 0 = off; "
                        "default: 10 at a triggered rate, off with --speed max (needs root or CAP_SYS_NICE)")
    p.set_defaults(func=run)

    n = subparsers.add_parser("node", help="run one service node (for systemd / multi-host deploys)",
                              description="mocap-rt node ROLE [node flags]; see deploy/README in docs/service.md")
    n.add_argument("role", choices=sorted(NODE_MODULES))
    n.add_argument("node_args", nargs=argparse.REMAINDER, help="the node's own flags (--help for them)")
    n.set_defaults(func=run_node)


def run_config(args: argparse.Namespace):
    """The ``RunConfig`` of ``mocap-rt run``: its defaults, then ``--config FILE``, then the flags
    given; ``rig_path`` resolved (``nodes.preflight.rig_path_for``)."""
    from dataclasses import fields, replace

    from mocap_rt.config import load_dataclass
    from nodes.preflight import rig_path_for
    from nodes.run_config import RunConfig

    cfg = load_dataclass(RunConfig, args.config) if args.config is not None else RunConfig()
    names = {f.name for f in fields(RunConfig)}
    given = {}
    for dest, value in vars(args).items():
        field_name, convert = FLAG_FIELDS.get(dest, (dest, lambda v: v))
        if field_name in names:
            given[field_name] = convert(value)
    cfg = replace(cfg, **given)
    if not cfg.source:
        raise ValueError("--source is required (or source = ... in --config)")
    return replace(cfg, rig_path=rig_path_for(cfg.source, cfg.rig_path))


def run(args: argparse.Namespace) -> int:
    from nodes.launcher import Launcher, _json_safe
    from nodes.preflight import check_run

    cfg = run_config(args)
    check_run(cfg)               # every input checked before a node starts: one line, no node traceback
    launcher = Launcher(cfg)
    notice = record_notice(cfg.record) if cfg.record is not None else None
    if notice:
        print(notice, file=sys.stderr)
    print(f"mocap-rt run: rig {launcher.rig_name}, {len(launcher.rig)} cameras, trigger "
          f"{launcher.trigger_fps:g} fps ({'free-run' if cfg.speed is None else f'x{cfg.speed:g}'}), "
          f"node logs in {launcher.log_dir}", file=sys.stderr)
    try:
        stats = launcher.run()
    except RuntimeError as exc:           # a node failed at start: the launcher names it and its log
        print(f"mocap-rt run: error: {exc}", file=sys.stderr)
        return 2
    summary = {k: stats[k] for k in ("frames_triggered", "poses_published", "frames_dropped", "latency_ms")}
    print(json.dumps(_json_safe(summary)))
    return 0


def record_notice(record: Path) -> str | None:
    """The line to print when ``--record DIR`` already holds a recording (the recorder then writes
    ``poses_001.*`` beside it, never over it), else None."""
    from nodes.recorder import output_paths

    npz, bvh, bones, _ = output_paths(Path(record))
    if npz.name == "poses.npz":
        return None
    return f"mocap-rt run: {record} already holds a recording; this one is written as {bvh.name}, {npz.name} " \
           f"and {bones.name} beside it"


def run_node(args: argparse.Namespace) -> int:
    import importlib

    mod = importlib.import_module(NODE_MODULES[args.role])
    return int(mod.main(args.node_args) or 0)
