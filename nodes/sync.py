"""Sync node: the rig's frame trigger (seed digest A.6, the PC that sends the sync signal).

Drift-free: frame ``k`` is due at ``t0 + k * period`` on the monotonic clock (an absolute
schedule, never ``sleep(period)`` after the work). When the process falls more than one
period behind (e.g. it was descheduled), the frames whose slot passed are skipped and
counted as drops, so frame ids stay tied to time. ``--fps 0`` (``--speed max`` in the
launcher) free-runs instead: the next trigger goes out as soon as the pose of the previous
frame arrived (or after ``MAX_FREE_RUN_WAIT_S``).

    python -m nodes.sync --rig RIG.toml --fps 30 [--frames N] [--listen ...] [--connect ...]
    python -m nodes.sync --config sync.toml        # the same as SyncSettings in TOML
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from dataclasses import dataclass

from nodes.messages import Keys, Pose, Trigger
from nodes.node import NodeSettings, parse_settings, rig_fps, run_node, settings_parser
from nodes.runtime import IdleGC, NodeRuntime

log = logging.getLogger(__name__)

QUICK_EXIT = True               # it holds no file: the fork server ends it without the interpreter's teardown
SPIN_S = 0.0005               # final busy-wait before a trigger, for sub-ms punctuality
PEER_WAIT_S = 10.0            # --expect-peers: wait at most this long for the links
DECLARE_SETTLE_S = 0.2        # after the links are up, let subscriber declarations arrive
MAX_FREE_RUN_WAIT_S = 0.25    # free-running: re-trigger if no pose came back by then


@dataclass(frozen=True)
class SyncSettings(NodeSettings):
    """fps : trigger rate, 0 = free-run (None: the rig's); frames : stop after this many
    frame slots, triggered or skipped (None: never; the ids are start_frame .. start_frame +
    frames - 1 whatever the load); start_frame : the first frame id; start_delay : seconds before the
    first trigger; expect_peers : wait until this many peers are connected first."""

    node: str = "sync"
    fps: float | None = None
    frames: int | None = None
    start_frame: int = 0
    start_delay: float = 0.0
    expect_peers: int = 0


class Schedule:
    """Absolute frame schedule: ``due(k) = t0_ns + k * period_ns`` (integer ns, no drift)."""

    def __init__(self, t0_ns: int, period_ns: int) -> None:
        if period_ns <= 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        self.t0_ns = t0_ns
        self.period_ns = period_ns

    def due(self, k: int) -> int:
        return self.t0_ns + k * self.period_ns

    def slot(self, now_ns: int) -> int:
        """The latest frame index whose due time is <= now_ns."""
        return max(0, (now_ns - self.t0_ns) // self.period_ns)


def sleep_until(t_ns: int, stop: threading.Event) -> None:
    """Sleep until monotonic ``t_ns`` (coarse wait on ``stop``, then a short spin)."""
    while True:
        left = (t_ns - time.monotonic_ns()) / 1e9
        if left <= 0 or stop.is_set():
            return
        if left > SPIN_S:
            stop.wait(left - SPIN_S)
        # else spin


def wait_for_peers(session, n: int, rt: NodeRuntime) -> int:
    """Wait until ``n`` peers are connected (or ``PEER_WAIT_S``): a trigger sent before the
    links are up would be lost. Returns the number of peers seen."""
    t_end = time.monotonic() + PEER_WAIT_S
    seen = 0
    while not rt.stop.is_set() and time.monotonic() < t_end:
        seen = len(list(session.info.peers_zid()))
        if seen >= n:
            rt.stop.wait(DECLARE_SETTLE_S)
            return seen
        rt.stop.wait(0.02)
    log.warning("sync: only %d of %d peers connected after %.0f s; triggering anyway", seen, n, PEER_WAIT_S)
    return seen


def run_sync(session, keys: Keys, fps: float, n_frames: int | None, start_frame: int,
             rt: NodeRuntime) -> int:
    """Publish triggers for the frame slots ``0 .. n_frames - 1`` (a slot skipped because the
    process was late counts as one of them) or until ``rt.stop`` is set; returns frames sent."""
    pub = session.declare_publisher(keys.trigger, express=True)
    sent = 0
    gcs = IdleGC()
    gcs.start()
    if fps > 0:
        sched = Schedule(time.monotonic_ns(), round(1e9 / fps))
        k = 0
        rt.publish_status("running", force=True)
        while not rt.stop.is_set() and (n_frames is None or k < n_frames):
            due = sched.due(k)
            sleep_until(due, rt.stop)
            if rt.stop.is_set():
                break
            now = time.monotonic_ns()
            msg = Trigger(keys.rig, start_frame + k, now, time.time_ns(), sched.period_ns)
            pub.put(msg.to_msgpack())
            sent += 1
            rt.meter.add((now - due) / 1e6)
            rt.extra["late_ms_last"] = (now - due) / 1e6
            nxt = k + 1
            slot = sched.slot(time.monotonic_ns())
            if n_frames is not None:
                slot = min(slot, n_frames)
            if slot > nxt:             # fell behind by more than a period: skip those slots
                rt.drops += slot - nxt
                log.warning("sync: %d trigger slot(s) skipped (process was late)", slot - nxt)
                nxt = slot
            k = nxt
            rt.publish_status()
            gcs.idle()
    else:
        got = threading.Event()
        last_frame = [-1]

        def on_pose(sample) -> None:
            msg = rt.decoder.decode(sample.payload, Pose)
            if msg is not None and msg.frame >= last_frame[0]:
                got.set()

        with session.declare_subscriber(keys.pose, on_pose):
            rt.publish_status("running", force=True)
            k = 0
            while not rt.stop.is_set() and (n_frames is None or sent < n_frames):
                got.clear()
                now = time.monotonic_ns()
                last_frame[0] = start_frame + k
                pub.put(Trigger(keys.rig, start_frame + k, now, time.time_ns(), 0).to_msgpack())
                sent += 1
                if not got.wait(MAX_FREE_RUN_WAIT_S):
                    rt.drops += 1
                rt.meter.add((time.monotonic_ns() - now) / 1e6)
                k += 1
                rt.publish_status()
    gcs.stop()
    rt.extra["frames_triggered"] = sent
    rt.publish_status("stopping", force=True)
    pub.undeclare()
    return sent


def _flags(p) -> None:
    p.add_argument("--fps", type=float, help="trigger rate; 0 = free-run (default: rig metadata fps or 30)")
    p.add_argument("--frames", type=int, help="stop after this many frame slots (triggered or skipped)")
    p.add_argument("--start-frame", type=int)
    p.add_argument("--start-delay", type=float, help="seconds to wait before the first trigger")
    p.add_argument("--expect-peers", type=int,
                   help="before the first trigger, wait until this many peers are connected")


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    return settings_parser(SyncSettings, __doc__.splitlines()[0], _flags)


def main(argv: list[str] | None = None) -> int:
    s = parse_settings(build_parser(), SyncSettings, argv)

    def serve(rt: NodeRuntime, rig, _) -> None:
        if s.expect_peers > 0:
            wait_for_peers(rt.session, s.expect_peers, rt)
        if s.start_delay > 0:
            rt.stop.wait(s.start_delay)
        fps = s.fps if s.fps is not None else rig_fps(rig)
        sent = run_sync(rt.session, rt.keys, fps, s.frames, s.start_frame, rt)
        log.info("sync: %d triggers sent, %d slots skipped", sent, rt.drops)

    return run_node("sync", s, serve)


if __name__ == "__main__":
    sys.exit(main())
