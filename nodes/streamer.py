"""Streamer node: every pose as a VMC protocol bundle (OSC over UDP) for VSeeFace, EVMC4U, Warudo ...

Subscribes to ``pose``; per pose it turns the BVH row into the Unity humanoid's bone-local
rotations (``mocap_rt.body.humanoid``), encodes one OSC bundle (``mocap_rt.io.vmc``) and sends
it to ``HOST:PORT`` (default 127.0.0.1:39539; another host needs ``--allow-remote-stream``).
The work runs on Zenoh's receiving thread (a direct callback): nothing else waits on it, and
no hand-over to another thread adds to the latency. A pose that cannot be converted (bad
values) or sent is dropped, counted and logged; the node goes on.

Status ``extra``: ``sent`` bundles, ``send_errors``, ``added_ms_p50`` / ``added_ms_p99``
(pose received -> bundle sent, last ``WINDOW`` poses), ``pub_to_send_ms_p99`` (fusion published ->
sent, same host).

    python -m nodes.streamer --rig RIG.toml --stream vmc:127.0.0.1:39539 [--allow-remote-stream]
"""

from __future__ import annotations

import logging
import socket
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np

from mocap_rt.body.humanoid import HumanoidRig, humanoid_pose_from_bvh_row
from mocap_rt.body.skeleton import BoneLengths, body_model
from mocap_rt.io.vmc import VmcEncoder, parse_vmc_target
from nodes.frame_window import FrameWindow
from nodes.messages import Pose, Trigger
from nodes.node import NodeSettings, parse_settings, run_node, settings_parser
from nodes.runtime import STATUS_PERIOD_S, IdleGC, NodeRuntime

log = logging.getLogger(__name__)

WINDOW = 3600         # poses over which the status percentiles are taken (2 min at 30 fps)
STATS_PERIOD_S = STATUS_PERIOD_S / 2


class LatencyWindow:
    """The last ``WINDOW`` (added, publication -> sent) latencies, ms, in a preallocated array.
    Percentiles are taken on the callback thread right after a bundle has left, at most every
    ``STATS_PERIOD_S`` (the status loop used to copy and sort 3600-entry deques five times a
    second, holding the GIL for a millisecond or more that a pose arriving then waited for)."""

    def __init__(self, n: int = WINDOW) -> None:
        self._a = np.zeros((n, 2))
        self._n = 0
        self._lock = threading.Lock()

    def add(self, added_ms: float, pub_ms: float) -> None:
        with self._lock:
            self._a[self._n % len(self._a)] = added_ms, pub_ms
            self._n += 1

    def percentiles(self) -> dict[str, float]:
        with self._lock:
            a = self._a[:min(self._n, len(self._a))].copy()
        if not len(a):
            return {}
        p50, p99 = np.percentile(a[:, 0], (50, 99))
        return {"added_ms_p50": float(p50), "added_ms_p99": float(p99),
                "pub_to_send_ms_p99": float(np.percentile(a[:, 1], 99))}


@dataclass(frozen=True)
class StreamerSettings(NodeSettings):
    """stream : vmc[:HOST[:PORT]] (default 127.0.0.1:39539); allow_remote_stream : let HOST be
    another machine (the stream is plain UDP)."""

    node: str = "streamer"
    stream: str = "vmc"
    allow_remote_stream: bool = False


class VmcSender:
    """Pose -> VMC bundle -> UDP datagram, with the skeleton of the poses' bone lengths."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.t0 = time.monotonic()
        self._bones: bytes | None = None
        self._model = self._rig = self._encoder = None
        self.sent = 0
        self.send_errors = 0

    def bundle(self, pose: Pose) -> bytearray:
        """The bundle of ``pose`` (a buffer reused by the next call); ValueError for a pose that
        cannot be converted."""
        key = np.asarray(pose.bones, np.float64).tobytes()
        if key != self._bones:                    # once per session: the subject's lengths
            self._model = body_model(BoneLengths.from_array(pose.bones), "paper")
            self._rig = HumanoidRig.of(self._model)
            self._encoder = VmcEncoder(self._rig.local_positions)
            self._bones = key
        row = np.asarray(pose.bvh_frame, np.float64)
        if not np.isfinite(row).all():
            raise ValueError(f"pose {pose.frame}: BVH row has non-finite values")
        hp = humanoid_pose_from_bvh_row(self._rig, self._model, row)
        return self._encoder.encode_pose(hp, time.monotonic() - self.t0)

    def send(self, payload: bytes | bytearray) -> bool:
        try:
            self.sock.sendto(payload, self.target)
        except OSError as exc:                    # no route, buffer full ...: drop, count, go on
            self.send_errors += 1
            log.warning("streamer: bundle not sent to %s:%d: %s", *self.target, exc)
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        self.sock.close()


def run_streamer(session, keys, sender: VmcSender, rt: NodeRuntime) -> None:
    """Stream until ``rt.stop``."""
    lat = LatencyWindow()
    stats_t = [0.0]                    # when the percentiles were last taken
    idle_gc = IdleGC()                 # collections after a bundle is sent, never before

    window = FrameWindow(keys.rig, rt.node)     # only poses of triggered frames near the newest

    def on_pose(sample) -> None:
        t_recv = time.perf_counter()
        msg = rt.decoder.decode(sample.payload, Pose)
        for m in window.accept(msg) if msg is not None else ():
            send(m, t_recv)

    def on_trigger(sample) -> None:
        msg = rt.decoder.decode(sample.payload, Trigger)
        for m in window.accept(msg)[1:] if msg is not None else ():     # poses that waited for it
            send(m, time.perf_counter())

    def send(msg: Pose, t_recv: float) -> None:
        try:
            ok = sender.send(sender.bundle(msg))
        except ValueError as exc:
            rt.drops += 1
            log.warning("streamer: %s", exc)
            return
        if not ok:
            rt.drops += 1
            return
        ms = (time.perf_counter() - t_recv) * 1e3
        lat.add(ms, (time.monotonic_ns() - msg.t_pub_mono_ns) / 1e6)
        rt.meter.add(ms)
        idle_gc.idle()                 # the bundle has left: now the housekeeping
        now = time.monotonic()
        if now - stats_t[0] >= STATS_PERIOD_S:
            stats_t[0] = now
            rt.extra.update(lat.percentiles())

    idle_gc.start()
    rt.subscribe(keys.pose, on_pose, direct=True)
    rt.subscribe(keys.trigger, on_trigger, direct=True)
    rt.publish_status("running", force=True)
    try:
        while not rt.stop.wait(STATUS_PERIOD_S / 2):
            rt.extra.update(sent=sender.sent, send_errors=sender.send_errors, **window.counters())
            rt.publish_status()
    finally:
        rt.unsubscribe()
        idle_gc.stop()
        log.info("streamer: %d bundles sent to %s:%d, %d send errors, %d poses dropped",
                 sender.sent, *sender.target, sender.send_errors, rt.drops)


def _flags(p) -> None:
    p.add_argument("--stream", help="vmc[:HOST[:PORT]] (default vmc:127.0.0.1:39539)")
    p.add_argument("--allow-remote-stream", action="store_true",
                   help="allow a HOST that is not this machine (the stream is plain UDP)")


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    return settings_parser(StreamerSettings, __doc__.splitlines()[0], _flags)


def main(argv: list[str] | None = None) -> int:
    s = parse_settings(build_parser(), StreamerSettings, argv)

    def prepare(rig, stack) -> VmcSender:
        target = parse_vmc_target(s.stream, s.allow_remote_stream)
        sender = VmcSender(target)
        stack.callback(sender.close)
        # the first bundle's conversion (imports, scipy) is made now, not on the first pose
        from mocap_rt.body.bvh_export import bvh_skeleton_of

        n_ch = bvh_skeleton_of(BoneLengths()).n_channels
        sender.bundle(Pose("warm-up", 0, 0, 0, np.zeros((6, 3)), np.zeros(6, bool), np.zeros((20, 3)),
                           np.zeros(n_ch), (), (), BoneLengths().as_array()))
        log.info("streamer: VMC bundles to %s:%d", *target)
        return sender

    # the launcher's SCHED_FIFO puts the streamer above fusion's predictions
    return run_node("streamer", s, lambda rt, rig, sender: run_streamer(rt.session, rt.keys, sender, rt),
                    prepare=prepare)


if __name__ == "__main__":
    sys.exit(main())
