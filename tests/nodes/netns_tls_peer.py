"""Run inside a network namespace: one Zenoh peer opened with a deploy config, as a node opens it.

It subscribes to ``mocap/**``, waits up to ``--connect-wait`` seconds for a peer, then puts
``NAME`` on each ``--put`` key every 0.1 s for ``--seconds`` seconds, and prints a JSON line:
the peers it had, and every (key, payload) it received.

    python netns_tls_peer.py NAME --zenoh-config FILE.json5 --put mocap/r/cues/cam_1 ... --seconds 3
"""

import argparse
import json
import sys
import threading
import time

from nodes.transport import add_zenoh_args, open_session


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("name")
    p.add_argument("--put", action="append", default=[])
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--connect-wait", type=float, default=30.0)
    add_zenoh_args(p)
    args = p.parse_args()
    got: set[tuple[str, str]] = set()
    lock = threading.Lock()

    def on_sample(sample) -> None:
        with lock:
            got.add((str(sample.key_expr), sample.payload.to_bytes().decode(errors="replace")))

    with open_session(args) as session:
        sub = session.declare_subscriber("mocap/**", on_sample)
        t_end = time.monotonic() + args.connect_wait
        while not list(session.info.peers_zid()) and time.monotonic() < t_end:
            time.sleep(0.05)
        peers = len(list(session.info.peers_zid()))
        time.sleep(0.5)                       # the peers' subscriber declarations arrive
        t_end = time.monotonic() + args.seconds
        while time.monotonic() < t_end:
            for key in args.put:
                session.put(key, args.name.encode())
            time.sleep(0.1)
        time.sleep(0.5)
        sub.undeclare()
    with lock:
        print(json.dumps({"name": args.name, "peers": peers, "received": sorted(got)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
