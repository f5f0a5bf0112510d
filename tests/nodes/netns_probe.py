"""Run inside a network namespace: listen for poses for a while, print a JSON summary.

    python netns_probe.py RIG_NAME SECONDS --listen ... --connect ...
"""

import argparse
import json
import sys
import threading
import time

import numpy as np

from nodes.messages import Decoder, Keys, Pose
from nodes.transport import add_zenoh_args, open_session


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("rig_name")
    p.add_argument("seconds", type=float)
    add_zenoh_args(p)
    args = p.parse_args()
    keys, dec, lock = Keys(args.rig_name), Decoder("probe"), threading.Lock()
    poses: list[Pose] = []

    def on_pose(sample):
        m = dec.decode(sample.payload, Pose)
        if m is not None:
            with lock:
                poses.append(m)

    with open_session(args) as session:
        with session.declare_subscriber(keys.pose, on_pose):
            time.sleep(args.seconds)
    with lock:
        out = {"poses": len(poses), "frames": [p.frame for p in poses],
               "cameras_used": sorted({c for p in poses for c in p.cameras_used}),
               "all_cameras_frames": sum(1 for p in poses if len(p.cameras_used) == 2),
               "finite_joints": sum(1 for p in poses if np.isfinite(p.joints).all()),
               "decode_drops": dec.total_drops}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
