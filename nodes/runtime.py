"""What a running node has: its session and ``NodeRuntime``, real-time priority, idle-time GC.

``NodeRuntime`` owns the stop event (SIGINT/SIGTERM set it), the decoder with its drop
counters, the rate meter and the once-a-second ``Status`` message; ``node_session`` opens it
(how a node process starts is ``nodes/node.py``).
"""

from __future__ import annotations

import gc
import logging
import os
import random
import signal
import statistics
import threading
import time
from collections import deque
from contextlib import contextmanager

from mocap_rt.warmup import SERVICE_PACKAGES, is_warm, load_cached_kernels
from nodes.messages import Decoder, Keys, Status
from nodes.transport import open_session

log = logging.getLogger(__name__)

STATUS_PERIOD_S = 1.0       # how often a node reports its status
RATE_WINDOW_S = 2.0         # fps / processing time are measured over this window


def enter_realtime(priority: int) -> bool:
    """Put every thread of this process (main, Zenoh's, callbacks) under SCHED_FIFO at
    ``priority``; threads started later inherit it. Called once the node is warmed up (JIT
    compilation at real-time priority would take the host's CPUs for seconds).

    A real-time node is never preempted by ordinary work on the host, and the workers of one
    frame run to completion instead of time-slicing the cores. Its duty cycle is bounded by
    the trigger rate; the kernel's real-time throttling (``sched_rt_runtime_us``, 95 %) is
    the safety net. Returns False (logged) when not permitted or ``priority`` <= 0.
    """
    if priority <= 0:
        return False
    param = os.sched_param(min(priority, os.sched_get_priority_max(os.SCHED_FIFO)))
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    done = 0
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, param)
            done += 1
        except OSError as exc:
            if done == 0:
                log.warning("real-time priority %d not set (%s): normal scheduling", priority, exc)
                return False
    log.info("SCHED_FIFO priority %d on %d thread(s)", param.sched_priority, done)
    return True


@contextmanager
def node_session(settings, rig_name: str, role: str, node: str):
    """A node's Zenoh session (``settings``: ``nodes.node.NodeSettings``) and its
    ``NodeRuntime`` (``rt.session``, ``rt.keys``; SIGINT and SIGTERM set ``rt.stop``)."""
    with open_session(settings) as session:
        rt = NodeRuntime(session, Keys(rig_name), node, role)
        rt.install_signal_handlers()
        if role in KERNEL_PACKAGES:
            rt.publish_status("starting", force=True)
            load_kernels(rt, KERNEL_PACKAGES[role])
        yield rt


# the nodes that run numba kernels on the frame path, and the packages whose kernels they call
# (a camera worker has no use for the ~30 IK and body-fit signatures: loading them cost each of
# the seven worker processes ~0.7 s of CPU at every cluster start; fusion's foot-axis cue calls
# a perception kernel, so fusion loads them all)
KERNEL_PACKAGES = {"camera": ("mocap_rt.perception", "mocap_rt.geometry"), "fusion": SERVICE_PACKAGES}


def load_kernels(rt: NodeRuntime, packages: tuple[str, ...]) -> None:
    """Load the cached numba kernels of ``packages`` now (``mocap_rt.warmup.load_cached_kernels``),
    before the node's warm-up frame and its *ready*: no frame waits for a kernel load."""
    if not is_warm():
        log.warning("%s: the numba kernel cache is cold (run `python -m mocap_rt.warmup`); "
                    "this node compiles what it needs during its warm-up", rt.node)
    n, secs = load_cached_kernels(packages)
    rt.extra["kernels_loaded"] = n
    log.info("%s: %d cached kernel signatures loaded in %.2f s", rt.node, n, secs)


DEFERRED_RT_PRIORITY = 1     # SCHED_FIFO priority of a real-time node's deferred work


class ThreadPriority:
    """Switch the calling thread between its real-time priority and the lowest one.

    A real-time worker does its deferred work (decoding the next replay image, preview JPEG,
    raw frames) at ``DEFERRED_RT_PRIORITY``: below every thread of the frame path (workers
    and fusion 10, sync 12), so it never delays another camera's frame, but still above
    ordinary work on the host, which starved it at normal priority (docs/service.md,
    "Latency"). Only this thread switches (a syscall, microseconds); Zenoh's threads keep
    their priority. Does nothing when the thread is not real-time.
    """

    def __init__(self) -> None:
        self._rt_param = None
        try:
            if os.sched_getscheduler(0) == os.SCHED_FIFO:
                self._rt_param = os.sched_getparam(0)
        except (AttributeError, OSError):
            pass
        self.realtime = self._rt_param is not None

    def normal(self) -> None:
        """Down to ``DEFERRED_RT_PRIORITY`` (the name is from when this was SCHED_OTHER)."""
        if self._rt_param is not None and self.realtime:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(DEFERRED_RT_PRIORITY))
                self.realtime = False
            except OSError as exc:
                log.debug("deferred priority not set: %s", exc)

    def realtime_again(self) -> None:
        if self._rt_param is not None and not self.realtime:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, self._rt_param)
                self.realtime = True
            except OSError as exc:
                log.debug("real-time scheduling not restored: %s", exc)


class RateMeter:
    """Frames per second and median work time over a sliding window (monotonic clock)."""

    def __init__(self, window_s: float = RATE_WINDOW_S) -> None:
        self.window_s = window_s
        self._events: deque[tuple[float, float]] = deque()
        self.frames = 0

    def add(self, work_ms: float, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        self._events.append((now, work_ms))
        self.frames += 1
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self._events and now - self._events[0][0] > self.window_s:
            self._events.popleft()

    def fps(self, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        self._trim(now)
        if len(self._events) < 2:
            return 0.0
        span = now - self._events[0][0]
        return (len(self._events) - 1) / span if span > 0 else 0.0

    def median_ms(self) -> float:
        return statistics.median(w for _, w in self._events) if self._events else 0.0


class NodeRuntime:
    """Stop event, decoder, rate meter and the periodic status message of one node."""

    def __init__(self, session, keys: Keys, node: str, role: str) -> None:
        self.session = session
        self.keys = keys
        self.node = node
        self.role = role
        self.stop = threading.Event()
        self.decoder = Decoder(node)
        self.meter = RateMeter()
        self.drops = 0
        self.source_drops = 0        # frames the source could not decode (a truncated video segment)
        self.extra: dict[str, float] = {}
        self.state = "starting"
        self._status_pub = session.declare_publisher(keys.status(node))
        self.extra["rt_priority"] = 0
        self._last_status = 0.0
        self._subs: list = []

    def subscribe(self, key: str, handler, direct: bool = False) -> None:
        """Declare a subscriber on ``key`` (``direct``: ``handler`` runs on Zenoh's receiving
        thread, ``nodes.transport.direct_callback``); ``unsubscribe`` ends them all."""
        from nodes.transport import direct_callback

        self._subs.append(self.session.declare_subscriber(key, direct_callback(handler) if direct else handler))

    def unsubscribe(self) -> None:
        """Undeclare every subscriber of ``subscribe``."""
        while self._subs:
            self._subs.pop().undeclare()

    def enter_realtime(self, priority: int) -> None:
        """``enter_realtime`` for this node; the status reports the priority it got."""
        if enter_realtime(priority):
            self.extra["rt_priority"] = os.sched_getparam(0).sched_priority

    def install_signal_handlers(self) -> None:
        """SIGINT/SIGTERM end the loop cleanly (main thread only)."""
        def _stop(signum, frame):  # noqa: ARG001
            self.stop.set()
        signal.signal(signal.SIGINT, _stop)
        signal.signal(signal.SIGTERM, _stop)

    def publish_status(self, state: str | None = None, force: bool = False) -> None:
        """Send a Status message if ``STATUS_PERIOD_S`` passed (or ``force``)."""
        now = time.monotonic()
        if state:
            self.state = state
        if not force and now - self._last_status < STATUS_PERIOD_S:
            return
        self._last_status = now
        t = os.times()
        msg = Status(self.keys.rig, self.node, self.role, os.getpid(), time.monotonic_ns(), self.state,
                     self.meter.fps(now), self.meter.median_ms(), self.meter.frames, self.drops,
                     self.decoder.total_drops + self.source_drops, t.user + t.system, dict(self.extra))
        try:
            self._status_pub.put(msg.to_msgpack())
        except Exception as exc:  # a status report must never stop the node
            log.warning("%s: status not sent: %s", self.node, exc)

class IdleGC:
    """Garbage collection only when the node is idle, never in the middle of a frame.

    ``start()`` (after warm-up): ``gc.freeze()`` moves everything alive so far (modules,
    JIT caches, the rig) out of the collector's view, and ``gc.disable()`` stops the automatic
    collections, whose pauses (a full one takes ms) land at random points of the critical
    path. ``idle()`` is called where the node has nothing to do (a frame published, the next
    trigger not yet due): it collects the young generations once enough objects were
    allocated, and everything every ``FULL_EVERY_S``. ``stop()`` restores automatic collection.
    """

    YOUNG_THRESHOLD = 700        # allocations (gc's own default gen-0 threshold)
    FULL_EVERY_S = 10.0

    def __init__(self) -> None:
        self.collections = 0
        self._last_full = time.monotonic()
        self._was_enabled = False

    def start(self) -> None:
        self._was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        # a random phase: nodes started together must not all collect in the same frame
        self._last_full = time.monotonic() - random.uniform(0.0, self.FULL_EVERY_S / 2)

    def idle(self) -> None:
        now = time.monotonic()
        if now - self._last_full >= self.FULL_EVERY_S:
            gc.collect()
            self._last_full = now
            self.collections += 1
        elif gc.get_count()[0] >= self.YOUNG_THRESHOLD:
            gc.collect(1)
            self.collections += 1

    def stop(self) -> None:
        gc.unfreeze()
        if self._was_enabled:
            gc.enable()
