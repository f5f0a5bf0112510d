"""What a ``mocap-rt run`` starts: the node processes, their flags, loopback ports and priorities.

``plan_run(cfg)`` turns a ``RunConfig`` into a ``RunPlan`` (no process is started): the start
order (recorder, viewer, streamer, fusion, one worker per camera, sync last), a listen port
per node, the links (each node connects to every node before it and to the launcher's
monitor: a full mesh, each link opened from one side) and the SCHED_FIFO priorities.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

from nodes.procs import free_port
from nodes.run_config import NodeProc, RunConfig
from nodes.sources import parse_source
from nodes.transport import zenoh_argv

log = logging.getLogger(__name__)

DEFAULT_PREVIEW_EVERY = 6      # with a viewer: one JPEG per camera every 6 frames (5 per s at 30 fps)
DEFAULT_RT_PRIORITY = 10       # SCHED_FIFO priority of the workers and fusion (sync 12)
# fusion at the workers' priority: its handling of each arriving answer waits for the core a
# worker frees instead of preempting the frame's other perceptions (p99 ~1 ms lower on 2
# cores, docs/service.md "Latency"); streamer: ~0.3 ms a pose
RT_PRIORITY_OFFSET = {"camera": 0, "fusion": 0, "sync": 2, "streamer": 2}


@dataclass
class RunPlan:
    """The processes of one run and what they were planned from.

    base_fps : the source's frame rate; trigger_fps : the sync's rate (0 = free-running);
    rt_priority : the workers' SCHED_FIFO priority (0 = off); realtime : it is permitted here;
    n_replay_frames : frames of one pass of a replay (None otherwise); nodes : by name, in
    start order; monitor_port : the launcher's own listen port.
    """

    rig: object
    rig_name: str
    source_kind: str
    base_fps: float
    trigger_fps: float
    rt_priority: int
    realtime: bool
    n_replay_frames: int | None
    monitor_port: int
    nodes: dict[str, NodeProc]


def source_timing(kind: str, value: str, rig) -> tuple[float, int | None]:
    """(the trigger base rate, frames of one pass of a replay or None): a recording's fps and
    length (replay/fake; fake sources run until stopped), else the rig's fps (``rig_fps``)."""
    if kind in ("replay", "fake"):
        from mocap_rt.io.recording import Recording

        with Recording(value) as rec:
            return float(rec.fps), (int(rec.n_frames) if kind == "replay" else None)
    from nodes.node import rig_fps

    return rig_fps(rig), None


def realtime_priority(requested: int | None, trigger_fps: float) -> tuple[int, bool]:
    """The workers' SCHED_FIFO priority (0 = normal scheduling) and whether it is permitted.

    Auto (``requested`` None): real-time at a triggered rate, where the trigger bounds the
    nodes' duty cycle; never when free-running (``--speed max``), where real-time nodes would
    take the whole machine. Needs root, CAP_SYS_NICE or an RLIMIT_RTPRIO of at least the
    priority; without it the nodes run normally."""
    import resource

    want = requested
    if want is None:
        want = DEFAULT_RT_PRIORITY if trigger_fps > 0 else 0
    if want <= 0:
        return 0, False
    top = want + max(RT_PRIORITY_OFFSET.values())
    if os.geteuid() != 0 and resource.getrlimit(resource.RLIMIT_RTPRIO)[0] < top:
        log.info("real-time scheduling not permitted (needs root, CAP_SYS_NICE or RLIMIT_RTPRIO >= %d): "
                 "the nodes run at the normal priority", top)
        return want, False
    return want, True


def worker_sources(source: str, camera_names: list[str]) -> dict[str, str]:
    """Each camera's ``--source``: one v4l2 device per camera, a gst template filled in
    (``{camera}`` / ``{index}``), or the same recording for all."""
    kind, value = parse_source(source)
    if kind == "v4l2":
        devs = value.split(",")
        if len(devs) != len(camera_names):
            raise ValueError(f"--source v4l2: {len(devs)} device(s) for {len(camera_names)} rig cameras "
                             f"(give one per camera, in rig order, comma-separated)")
        return {n: f"v4l2:{d}" for n, d in zip(camera_names, devs)}
    if kind == "gst":
        return {n: "gst:" + value.replace("{camera}", n).replace("{index}", str(i))
                for i, n in enumerate(camera_names)}
    return {n: f"{kind}:{value}" for n in camera_names}


def node_commands(cfg: RunConfig, plan: RunPlan) -> list[tuple[str, str, list[str]]]:
    """(name, role, ``-m module`` and the node's own flags) in start order."""
    live = plan.source_kind != "replay"
    fps = str(plan.base_fps)
    preview = cfg.preview_every if cfg.preview_every is not None else (DEFAULT_PREVIEW_EVERY if cfg.rerun else 0)
    out: list[tuple[str, str, list[str]]] = []
    if cfg.record:
        out.append(("recorder", "recorder", ["-m", "nodes.recorder", "--out", str(cfg.record), "--fps", fps]
                    + (["--raw"] if live else [])))
    if cfg.rerun:
        out.append(("viewer", "viewer", ["-m", "nodes.viewer", "--rerun", cfg.rerun, "--preview-every", str(preview)]))
    if cfg.stream:
        out.append(("streamer", "streamer", ["-m", "nodes.streamer", "--stream", cfg.stream]
                    + (["--allow-remote-stream"] if cfg.allow_remote_stream else [])))
    out.append(("fusion", "fusion", ["-m", "nodes.fusion_node", "--deadline-frac", str(cfg.deadline_frac), "--fps", fps]
                + (["--bones", str(cfg.bones)] if cfg.bones else [])))
    for cam, src in worker_sources(cfg.source, list(plan.rig.names)).items():
        argv = ["-m", "nodes.camera_worker", "--camera", cam, "--source", src, "--fps", fps,
                "--preview-every", str(preview)]
        if live and cfg.record:
            argv.append("--publish-frames")
        if cfg.backgrounds_from:
            argv += ["--backgrounds-from", str(cfg.backgrounds_from)]
        out.append((f"worker-{cam}", "camera", argv))
    # sync connects to every other node and to the monitor: wait for all those links
    sync = ["-m", "nodes.sync", "--fps", str(plan.trigger_fps), "--expect-peers", str(len(out) + 1)]
    if plan.n_replay_frames and cfg.duration_s is None:
        sync += ["--frames", str(plan.n_replay_frames)]
    out.append(("sync", "sync", sync))
    return out


def plan_run(cfg: RunConfig) -> RunPlan:
    """The ``RunPlan`` of ``cfg`` (reads the rig and, for a replay, the recording's header)."""
    from mocap_rt.geometry.rig import read_rig
    from nodes.node import rig_name_for

    kind, value = parse_source(cfg.source)
    if not Path(cfg.rig_path).is_file():
        raise FileNotFoundError(f"--rig {cfg.rig_path}: no such file")
    rig = read_rig(cfg.rig_path)
    rec_fps, n_replay = source_timing(kind, value, rig)
    base_fps = cfg.fps or rec_fps
    trigger_fps = 0.0 if cfg.speed is None else base_fps * cfg.speed
    rt_priority, realtime = realtime_priority(cfg.rt_priority, trigger_fps)
    plan = RunPlan(rig, cfg.rig_name or rig_name_for(cfg.rig_path, rig), kind, base_fps, trigger_fps,
                   rt_priority, realtime, n_replay, free_port(), {})
    commands = node_commands(cfg, plan)
    ports = {name: free_port() for name, _, _ in commands}
    common = ["--rig", str(cfg.rig_path), "--rig-name", plan.rig_name]
    # each link is opened by one side only (the later node connects to the earlier ones and to
    # the launcher's monitor): two sessions racing to open the same link can drop messages
    # while one of them is torn down
    earlier: list[str] = []
    for name, role, argv in commands:
        others = [f"tcp/127.0.0.1:{ports[n]}" for n in earlier] + [f"tcp/127.0.0.1:{plan.monitor_port}"]
        earlier.append(name)
        z = zenoh_argv([f"tcp/127.0.0.1:{ports[name]}"], others)
        extra = list(cfg.extra_node_args.get(role, []))
        if rt_priority > 0 and role in RT_PRIORITY_OFFSET:
            extra = ["--rt-priority", str(rt_priority + RT_PRIORITY_OFFSET[role])] + extra
        plan.nodes[name] = NodeProc(name, role, argv + common + ["--node", name] + z + extra, ports[name])
    return plan
