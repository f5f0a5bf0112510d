"""What a ``Launcher`` run reports: the live status line and the statistics (``--stats``)."""

from __future__ import annotations

import math
import time
from collections import Counter

from nodes.frame_window import window_drops
from nodes.monitor import percentiles


def _json_safe(x):
    """NaN/inf -> None so the stats file is strict JSON."""
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def status_line(launcher) -> str:
    """The live status line of a running ``Launcher``."""
    m = launcher.monitor
    trig, poses, missing = m.counts()
    lat = percentiles(m.latencies_ms(last=300))
    cams = m.alive_nodes("camera")
    n_cams = sum(1 for n in launcher.nodes.values() if n.role == "camera")
    table = m.node_table()
    drops = sum(v["drops"] for v in table.values())
    decode = sum(v["decode_drops"] for v in table.values()) + m.decoder.total_drops
    t = 0.0 if launcher.t_sync_start is None else time.monotonic() - launcher.t_sync_start
    return (f"t={t:6.1f}s  pose fps {m.recent_fps():5.1f}  triggered {trig}  poses {poses}  "
            f"no-pose {missing}  latency p50 {lat['p50']:.1f} p99 {lat['p99']:.1f} ms  "
            f"node drops {drops}  decode drops {decode}  cameras alive {len(cams)}/{n_cams}")


SLOWEST_SHARE = 0.01        # the share of the poses ``slowest_poses`` lists (at least SLOWEST_MIN)
SLOWEST_MIN = 5


def slowest_poses(events) -> list[dict]:
    """The slowest ``SLOWEST_SHARE`` of the poses (trigger -> published), slowest first: frame,
    latency and stage timings (ms), so that a p99 can be traced to the frames that make it."""
    n = max(SLOWEST_MIN, math.ceil(SLOWEST_SHARE * len(events)))
    worst = sorted(events, key=lambda p: p.latency_ms, reverse=True)[:n]
    return [{"frame": p.frame, "latency_ms": round(p.latency_ms, 3),
             **{k: round(v, 3) for k, v in p.timings_ms.items()}} for p in worst]


def run_stats(launcher) -> dict:
    """The statistics of a ``Launcher``'s run (what ``--stats`` writes; docs/service.md)."""
    m = launcher.monitor
    trig, poses, no_pose = m.counts() if m else (0, 0, 0)
    table = m.node_table() if m else {}
    lat = percentiles(m.latencies_ms()) if m else percentiles([])
    t, events = m.snapshot() if m else ([], [])   # (not m.triggers / m.poses: the callbacks append to them)
    run_s = 0.0
    if len(t) > 1:                                # first to last trigger seen, plus a period
        t.sort()
        run_s = (t[-1] - t[0]) / 1e9 + (t[-1] - t[0]) / 1e9 / (len(t) - 1)
    missing_any = sum(1 for p in events if p.cameras_missing)
    missing_by_camera = Counter(c for p in events for c in p.cameras_missing)
    nodes = {}
    for name, n in launcher.nodes.items():
        st = table.get(name, {})
        nodes[name] = {"role": n.role, "cpu_s": round(n.cpu_s, 3),
                       "cpu_s_running": round(n.cpu_s - launcher.cpu_at_start.get(name, 0.0), 3),
                       "restarts": n.restarts,
                       "drops": st.get("drops", 0), "decode_drops": st.get("decode_drops", 0),
                       "fps": st.get("fps", 0.0), "processing_ms": st.get("processing_ms", 0.0),
                       "rt_priority": st.get("x_rt_priority", 0)}
    return {
        "rig": launcher.rig_name, "source": launcher.cfg.source, "trigger_fps": launcher.trigger_fps,
        "speed": "max" if launcher.cfg.speed is None else launcher.cfg.speed, "run_s": round(run_s, 3),
        "frames_triggered": trig, "poses_published": poses, "frames_dropped": no_pose,
        "node_drops": sum(v["drops"] for v in nodes.values()),
        "decode_drops": sum(v["decode_drops"] for v in nodes.values()) + (m.decoder.total_drops if m else 0),
        "frame_window_drops": window_drops(table, *([m.window] if m else [])),
        "poses_with_missing_cameras": missing_any,
        "poses_missing_camera": {c: missing_by_camera[c] for c in launcher.rig.names},
        "latency_ms": {k: round(v, 3) for k, v in lat.items()},
        "slowest_poses": slowest_poses(events),
        "stages_ms": ({k: {q: round(v, 3) for q, v in d.items()} for k, d in m.stage_percentiles().items()}
                      if m else {}),
        "cameras": list(launcher.rig.names),
        "cpu_s": {name: v["cpu_s"] for name, v in nodes.items()},
        "cpu_s_running": {name: v["cpu_s_running"] for name, v in nodes.items()},
        "nodes": nodes, "log_dir": str(launcher.log_dir),
        **({"stream": {k[2:]: v for k, v in table.get("streamer", {}).items() if k.startswith("x_")}}
           if "streamer" in launcher.nodes else {}),
    }
