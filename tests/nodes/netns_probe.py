"""Run inside a network namespace: wait until the named nodes report ready, then listen for
poses during a window and print a JSON summary.

    python netns_probe.py RIG_NAME WINDOW_S --wait-nodes fusion,worker-cam_1 --listen ... --connect ...
"""

import argparse
import json
import sys
import threading
import time

import numpy as np

from nodes.messages import Decoder, Keys, Pose, Status
from nodes.transport import add_zenoh_args, open_session


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("rig_name")
    p.add_argument("window_s", type=float)
    p.add_argument("--wait-nodes", default="", help="comma-separated node names")
    p.add_argument("--timeout", type=float, default=120.0)
    add_zenoh_args(p)
    args = p.parse_args()
    keys, dec, lock = Keys(args.rig_name), Decoder("probe"), threading.Lock()
    poses: list[Pose] = []
    ready: set[str] = set()
    waiting = {n for n in args.wait_nodes.split(",") if n}
    t_ready = [None]

    def on_pose(sample):
        m = dec.decode(sample.payload, Pose)
        if m is not None and t_ready[0] is not None:
            with lock:
                poses.append(m)

    def on_status(sample):
        m = dec.decode(sample.payload, Status)
        if m is not None and m.state in ("ready", "running"):
            ready.add(m.node)
            if t_ready[0] is None and waiting <= ready:
                t_ready[0] = time.monotonic()

    t0 = time.monotonic()
    with open_session(args) as session:
        subs = [session.declare_subscriber(keys.pose, on_pose),
                session.declare_subscriber(keys.status(), on_status)]
        while t_ready[0] is None and time.monotonic() - t0 < args.timeout:
            time.sleep(0.05)
        if t_ready[0] is not None:
            time.sleep(args.window_s)
        for s in subs:
            s.undeclare()
    with lock:
        out = {"ready_after_s": None if t_ready[0] is None else round(t_ready[0] - t0, 2),
               "ready_nodes": sorted(ready), "poses": len(poses), "frames": [p.frame for p in poses],
               "cameras_used": sorted({c for p in poses for c in p.cameras_used}),
               "all_cameras_frames": sum(1 for p in poses if len(p.cameras_used) == 2),
               "finite_joints": sum(1 for p in poses if np.isfinite(p.joints).all()),
               "decode_drops": dec.total_drops}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
