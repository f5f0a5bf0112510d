"""The launcher's view of a running service: triggers, poses, node status, statistics.

``ServiceMonitor`` subscribes to ``trigger``, ``pose`` and ``status/*`` and keeps what the
status line and the ``--stats`` JSON need. Callbacks only append under a lock.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from nodes.frame_window import RECORD_AHEAD, RECORD_BEHIND, FrameWindow
from nodes.messages import Decoder, Keys, Pose, Status, Trigger

ALIVE_S = 2.0              # a node whose status is older than this is not alive
POSE_HISTORY = 100_000     # poses kept for the fault tests and statistics


@dataclass(frozen=True, slots=True)
class PoseEvent:
    """A pose as the monitor saw it (monotonic ns stamps of this host)."""

    frame: int
    t_trigger_ns: int
    t_pub_ns: int
    t_recv_ns: int
    cameras_used: tuple[str, ...]
    cameras_missing: tuple[str, ...]
    timings_ms: dict = field(default_factory=dict)   # the pose's stage timings

    @property
    def latency_ms(self) -> float:
        return (self.t_pub_ns - self.t_trigger_ns) / 1e6


def percentiles(values, qs=(50, 95, 99)) -> dict[str, float]:
    """``{"p50": .., "p95": .., "p99": .., "max": .., "mean": ..}`` (NaN when empty)."""
    a = np.asarray(list(values), np.float64)
    if a.size == 0:
        return {**{f"p{q}": float("nan") for q in qs}, "max": float("nan"), "mean": float("nan")}
    out = {f"p{q}": float(np.percentile(a, q)) for q in qs}
    out.update(max=float(a.max()), mean=float(a.mean()))
    return out


class ServiceMonitor:
    """Subscribes to a rig's trigger, pose and status keys."""

    def __init__(self, session, keys: Keys) -> None:
        self.keys = keys
        self.decoder = Decoder("monitor")
        # poses of triggered frames, even late ones
        self.window = FrameWindow(keys.rig, "monitor", RECORD_BEHIND, RECORD_AHEAD)
        self._lock = threading.Lock()
        self.triggers: dict[int, int] = {}          # frame -> trigger mono ns
        self.poses: deque[PoseEvent] = deque(maxlen=POSE_HISTORY)
        self.pose_frames: set[int] = set()
        self.status: dict[str, tuple[int, Status]] = {}   # node -> (recv ns, last status)
        self.status_log: deque[tuple[int, Status]] = deque(maxlen=POSE_HISTORY)
        self._subs = [session.declare_subscriber(keys.trigger, self._on_trigger),
                      session.declare_subscriber(keys.pose, self._on_pose),
                      session.declare_subscriber(keys.status(), self._on_status)]

    def _on_trigger(self, sample) -> None:
        self._ingest(self.decoder.decode(sample.payload, Trigger), time.monotonic_ns())

    def _on_pose(self, sample) -> None:
        self._ingest(self.decoder.decode(sample.payload, Pose), time.monotonic_ns())

    def _ingest(self, msg, now: int) -> None:
        """A trigger, or a pose of a triggered frame (``FrameWindow``; forged ones are dropped)."""
        for m, t_recv in self.window.accept(msg, (msg, now)) if msg is not None else ():
            with self._lock:
                if isinstance(m, Trigger):
                    self.triggers[m.frame] = m.t_mono_ns
                    continue
                self.poses.append(PoseEvent(m.frame, m.t_trigger_mono_ns, m.t_pub_mono_ns, t_recv,
                                            m.cameras_used, m.cameras_missing, dict(m.timings_ms)))
                self.pose_frames.add(m.frame)

    def _on_status(self, sample) -> None:
        now = time.monotonic_ns()
        m = self.decoder.decode(sample.payload, Status)
        if m is not None:
            with self._lock:
                self.status[m.node] = (now, m)
                self.status_log.append((now, m))

    # ------------------------------------------------------------ queries
    def node_state(self, node: str) -> str | None:
        with self._lock:
            s = self.status.get(node)
        return None if s is None else s[1].state

    def alive_nodes(self, role: str | None = None, now_ns: int | None = None) -> list[str]:
        now_ns = time.monotonic_ns() if now_ns is None else now_ns
        with self._lock:
            return sorted(n for n, (t, s) in self.status.items()
                          if now_ns - t <= ALIVE_S * 1e9 and s.state in ("ready", "running")
                          and (role is None or s.role == role))

    def poses_since(self, t_ns: int) -> list[PoseEvent]:
        with self._lock:
            return [p for p in self.poses if p.t_recv_ns >= t_ns]

    def snapshot(self) -> tuple[list[int], list[PoseEvent]]:
        """(the triggers' monotonic ns, the poses seen), copied under the lock: the callbacks
        append from the transport's threads while a report reads them."""
        with self._lock:
            return list(self.triggers.values()), list(self.poses)

    def first_trigger_ns(self) -> int | None:
        """Monotonic ns of the first trigger seen (None before it)."""
        with self._lock:
            return min(self.triggers.values(), default=None)

    def counts(self) -> tuple[int, int, int]:
        """(frames triggered, poses published, triggered frames without a pose)."""
        with self._lock:
            trig = set(self.triggers)
            return len(trig), len(self.pose_frames), len(trig - self.pose_frames)

    def recent_fps(self, window_s: float = 2.0) -> float:
        now = time.monotonic_ns()
        with self._lock:
            ts = [p.t_recv_ns for p in self.poses if now - p.t_recv_ns <= window_s * 1e9]
        return (len(ts) - 1) / ((ts[-1] - ts[0]) / 1e9) if len(ts) > 1 and ts[-1] > ts[0] else 0.0

    def latencies_ms(self, last: int | None = None) -> list[float]:
        with self._lock:
            ps = list(self.poses)[-last:] if last else list(self.poses)
        return [p.latency_ms for p in ps]

    def stage_percentiles(self) -> dict[str, dict[str, float]]:
        """Per pose-timing key (``w_pub``, ``f_last_cue``, ``step_ms`` ...): p50/p95/p99/max/mean
        over the poses seen, ms; plus ``recv`` (pose published -> received here)."""
        with self._lock:
            ps = list(self.poses)
        keys = sorted({k for p in ps for k in p.timings_ms})
        out = {k: percentiles(p.timings_ms[k] for p in ps if k in p.timings_ms) for k in keys}
        out["recv"] = percentiles((p.t_recv_ns - p.t_pub_ns) / 1e6 for p in ps)
        return out

    def node_table(self) -> dict[str, dict]:
        with self._lock:
            items = list(self.status.items())
        return {n: {"role": s.role, "pid": s.pid, "state": s.state, "fps": round(s.fps, 2),
                    "processing_ms": round(s.processing_ms, 3), "frames": s.frames, "drops": s.drops,
                    "decode_drops": s.decode_drops, "cpu_s_reported": round(s.cpu_s, 3),
                    **{f"x_{k}": v for k, v in s.extra.items()}}
                for n, (_, s) in sorted(items)}

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # session may already be closed
                pass
