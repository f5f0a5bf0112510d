"""The VMC stream of the capture service: bundles delivered and the latency the stream adds.

A six-camera 640x480 studio replay at 30 fps with ``--stream vmc:127.0.0.1:PORT``; this
process holds a plain UDP socket on that port and a Zenoh subscriber to the poses (connected
to fusion like any node). Per pose: delivered if a bundle with its pelvis as root arrived;
**added latency** = bundle received on UDP - pose received by the Zenoh subscriber (both in
this process, one clock), i.e. what going through the streamer costs over subscribing to
the pose directly. Also the streamer's own figure (pose received -> bundle sent) and the
conversion + encoding alone, with the cvtColor yardstick.

    python -m bench stream                          # 60 s at 30 fps (targets: >= 98 %, p99 <= 1 ms)
    python -m bench.bench_stream --duration 20
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

from bench.bench_service import REPO, ensure_recording
from bench.yardstick import header, timing_lock, yardstick_ms

TARGET_DELIVERED = 0.98
TARGET_ADDED_P99_MS = 1.0


def _pelvis_key(p) -> tuple:
    """Unity (x, z, y) of the world pelvis as the bundle carries it (float32), as a dict key."""
    return tuple(np.float32([p[0], p[2], p[1]]).tolist())


def _root_key(data: bytes) -> tuple | None:
    """The root position of a VMC bundle: the first message is /VMC/Ext/Root/Pos "root" x y z ..."""
    i = data.find(b"root\0")
    if i < 0:
        return None
    i += 8                                           # "root" + NUL, padded to 8 bytes
    return tuple(np.frombuffer(data[i:i + 12], ">f4").astype(np.float32).tolist())


def conversion_ms(repeats: int = 2000) -> tuple[float, float]:
    """Median / p99 ms of one pose -> humanoid -> bundle (the streamer's per-pose work)."""
    from mocap_rt.body.bvh_export import bvh_frame
    from mocap_rt.body.humanoid import HumanoidRig, humanoid_pose_from_bvh_row
    from mocap_rt.body.skeleton import body_model
    from mocap_rt.io.vmc import vmc_bundle

    model = body_model(None, "paper")
    rig = HumanoidRig.of(model)
    rng = np.random.default_rng(0)
    rows = [bvh_frame(model, rng.normal(size=3), rng.uniform(-1, 1, (20, 3))) for _ in range(50)]
    t = []
    for i in range(repeats):
        t0 = time.perf_counter()
        vmc_bundle(humanoid_pose_from_bvh_row(rig, model, rows[i % 50]), 1.0)
        t.append(time.perf_counter() - t0)
    return float(np.median(t) * 1e3), float(np.percentile(t, 99) * 1e3)


def run(rec: Path, duration_s: float, log_dir: Path) -> dict:
    import zenoh

    from nodes.launcher import Launcher, RunConfig
    from nodes.messages import Pose
    from nodes.runtime import enter_realtime
    from nodes.transport import make_config

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.1)
    udp: list[tuple[int, bytes]] = []
    poses: dict[tuple, deque] = {}        # pelvis -> probe receipt times (a replay loop repeats poses)
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            udp.append((time.monotonic_ns(), data))

    def on_pose(sample) -> None:
        t = time.monotonic_ns()
        p = Pose.from_msgpack(bytes(sample.payload))
        poses.setdefault(_pelvis_key(p.joints[0]), deque()).append(t)

    L = Launcher(RunConfig(rig_path=rec / "rig.toml", source=f"replay:{rec}", duration_s=duration_s,
                           stream=f"vmc:127.0.0.1:{sock.getsockname()[1]}", status_line=False, log_dir=log_dir))
    th = threading.Thread(target=receive, daemon=True)
    th.start()
    probe = sub = None
    try:
        L.start()
        eps = [f"tcp/127.0.0.1:{n.port}" for n in L.nodes.values()]
        probe = zenoh.open(make_config(["tcp/127.0.0.1:0"], eps))
        sub = probe.declare_subscriber(L.keys.pose, on_pose)
        # both receivers of this process at the streamer's SCHED_FIFO priority (when permitted),
        # so that the difference is the streamer's, not this process's wait for a CPU
        enter_realtime(L.rt_priority + 1 if L.rt_priority else 0)
        L.supervise_for(duration_s)
    finally:
        L.stop()
        stop.set()
        th.join()
        sock.close()
        if sub is not None:
            sub.undeclare()
        if probe is not None:
            probe.close()
    stats = L.stats()
    n_probe = sum(len(q) for q in poses.values())
    added = []
    for t, d in udp:                  # both arrive in order: match each bundle to the oldest such pose
        q = poses.get(_root_key(d))
        if q:
            added.append((t - q.popleft()) / 1e6)
    n_poses = stats["poses_published"]
    return {"poses_published": n_poses, "poses_seen_by_probe": n_probe, "bundles": len(udp),
            "bundles_matched": len(added), "delivered": len(udp) / max(1, n_poses),
            "added_ms": {q: float(np.percentile(added, v)) for q, v in (("p50", 50), ("p95", 95), ("p99", 99),
                                                                        ("max", 100))} if added else {},
            "streamer": stats.get("stream", {}), "latency_ms": stats["latency_ms"]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=60.0, help="seconds at 30 fps")
    p.add_argument("--rec", type=Path, default=REPO / "out" / "bench" / "studio_walk_640")
    p.add_argument("--out", type=Path, default=REPO / "out" / "bench" / "stream.json")
    p.add_argument("--no-lock", action="store_true", help="do not take the shared timing lock")
    args = p.parse_args(argv or [])
    rec = ensure_recording(args.rec)
    with timing_lock(not args.no_lock):
        yard = yardstick_ms()
        conv = conversion_ms()
        print(f"stream bench: {rec}, {args.duration:g} s at 30 fps, loadavg {os.getloadavg()[0]:.1f}")
        print(header(yard))
        r = run(rec, args.duration, args.out.parent / "stream_logs")
    r["yardstick_ms"], r["conversion_ms"] = yard, {"p50": conv[0], "p99": conv[1]}
    a, s = r["added_ms"], r["streamer"]
    print(f"| poses published | probe saw | bundles | matched | delivered | target |\n|---|---|---|---|---|---|\n"
          f"| {r['poses_published']} | {r['poses_seen_by_probe']} | {r['bundles']} | {r['bundles_matched']} | "
          f"{100 * r['delivered']:.2f} % | >= {100 * TARGET_DELIVERED:.0f} % |")
    print("| added latency (UDP bundle - Zenoh pose, same process) | p50 | p95 | p99 | max | x yardstick (p50) |\n"
          "|---|---|---|---|---|---|")
    if a:
        print(f"| ms | {a['p50']:.3f} | {a['p95']:.3f} | {a['p99']:.3f} | {a['max']:.3f} | {a['p50'] / yard:.1f} |")
    print(f"streamer's own pose received -> bundle sent: p50 {s.get('added_ms_p50', float('nan')):.3f} ms, "
          f"p99 {s.get('added_ms_p99', float('nan')):.3f} ms (the whole run); conversion + encoding alone "
          f"p50 {conv[0]:.3f} ms ({conv[0] / yard:.2f} x yardstick), p99 {conv[1]:.3f} ms; target added p99 <= "
          f"{TARGET_ADDED_P99_MS} ms")
    print(f"service latency (trigger -> pose) p50 {r['latency_ms']['p50']:.1f} ms, p99 {r['latency_ms']['p99']:.1f} ms")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(r, indent=2))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
