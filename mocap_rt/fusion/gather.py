"""Gathering one frame's cues from the cameras (the first stage of fusion's per-frame path).

``FrameGatherer`` collects, per triggered frame, the cues each camera sends and decides
when the frame is ready for fusion: every *live* camera answered, or the deadline
``deadline_frac * period`` passed, counted from the trigger; for a frame served late (its
first answer more than half that wait after the trigger, as when the cameras catch up
after a stall), counted from its first answer, so that it still waits for all of them.
A camera is live when its cues arrived within ``liveness_s``. Pure bookkeeping on
monotonic ns stamps (no transport), so the fusion node (``nodes/fusion_node.py``) stays a
thin loop and this is unit-tested alone. Triggers need ``frame``, ``t_mono_ns`` and
``period_ns``; cue messages ``camera``, ``frame``, ``t_trigger_mono_ns`` and ``cues`` (the
node's ``Trigger`` and ``Cues``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

DEFAULT_DEADLINE_FRAC = 0.8     # of the frame period, after the trigger
FREE_RUN_DEADLINE_S = 0.1       # deadline when the sync free-runs (period 0)
LIVENESS_S = 0.25               # a camera silent this long is not waited for
FIRST_FRAME_GRACE_S = 0.5       # the very first frame waits this long for every camera: the
                                # tracker initialises from it (fewer views can start it badly)
MAX_PENDING_FRAMES = 64         # frames gathered at once (older ones are dropped)


@dataclass
class PendingFrame:
    """Cues gathered so far for one frame."""

    frame: int
    t_trigger_mono_ns: int
    deadline_ns: int
    cues: dict = field(default_factory=dict)       # camera -> CameraCues
    t_first_ns: int = 0
    t_last_ns: int = 0                             # when the last answer arrived


class FrameGatherer:
    """Collects cues per frame and decides when a frame is ready (all live, or deadline).

    Pure bookkeeping on monotonic ns stamps, so it is tested without Zenoh.
    """

    def __init__(self, cameras: list[str], deadline_frac: float = DEFAULT_DEADLINE_FRAC,
                 liveness_s: float = LIVENESS_S) -> None:
        self.cameras = list(cameras)
        self.deadline_frac = deadline_frac
        self.liveness_ns = int(liveness_s * 1e9)
        self.period_ns = 0
        self.pending: dict[int, PendingFrame] = {}
        self.last_seen: dict[str, int] = {}
        self.last_done = -1
        self.late_cues = 0
        self.frames_dropped = 0
        self._triggered = False

    def _wait_ns(self) -> int:
        if self.period_ns > 0:
            return int(self.deadline_frac * self.period_ns)
        return int(FREE_RUN_DEADLINE_S * 1e9)

    def _deadline(self, t_trigger_ns: int) -> int:
        wait_ns = self._wait_ns()
        if self.last_done < 0:            # nothing fused yet: the first frame
            wait_ns = max(wait_ns, int(FIRST_FRAME_GRACE_S * 1e9))
        return t_trigger_ns + wait_ns

    def _get(self, frame: int, t_trigger_ns: int) -> PendingFrame | None:
        if frame <= self.last_done:
            return None
        pf = self.pending.get(frame)
        if pf is None:
            pf = PendingFrame(frame, t_trigger_ns, self._deadline(t_trigger_ns))
            self.pending[frame] = pf
            if len(self.pending) > MAX_PENDING_FRAMES:
                oldest = min(self.pending)
                del self.pending[oldest]
                self.frames_dropped += 1
        return pf

    def on_trigger(self, trig, now_ns: int | None = None) -> None:
        self.period_ns = trig.period_ns
        if not self._triggered:
            # the first frames wait for every rig camera (see assume_all_live)
            self.assume_all_live(time.monotonic_ns() if now_ns is None else now_ns)
            self._triggered = True
        self._get(trig.frame, trig.t_mono_ns)

    def on_cues(self, msg, now_ns: int) -> None:
        if msg.camera not in self.cameras:
            return
        self.last_seen[msg.camera] = now_ns
        pf = self._get(msg.frame, msg.t_trigger_mono_ns)
        if pf is None:
            self.late_cues += 1
            return
        pf.cues[msg.camera] = msg.cues
        if not pf.t_first_ns:
            pf.t_first_ns = now_ns
            wait_ns = self._wait_ns()
            if now_ns - pf.t_trigger_mono_ns > wait_ns // 2:
                # served late (the cameras catching up after a stall): the others' answers
                # come in the same burst, within the usual wait of this first one
                pf.deadline_ns = max(pf.deadline_ns, now_ns + wait_ns)
        pf.t_last_ns = max(pf.t_last_ns, now_ns)

    def assume_all_live(self, now_ns: int) -> None:
        """Every rig camera not heard of yet counts as live from ``now_ns`` (done at the first
        trigger): the first frames wait for all of them (up to the deadline) instead of
        completing with whichever camera answered first."""
        for c in self.cameras:
            self.last_seen.setdefault(c, now_ns)

    def live(self, now_ns: int) -> set[str]:
        return {c for c, t in self.last_seen.items() if now_ns - t <= self.liveness_ns}

    def ready(self, now_ns: int) -> list[PendingFrame]:
        """Frames to fuse now, oldest first.

        A frame is ready when every live camera answered, or at its deadline if it has at
        least one answer (a frame with none cannot make a pose, so it keeps waiting for a
        late answer). Once a frame is ready, every older pending frame goes too: fused with
        what it has, or dropped (counted) when it has nothing.
        """
        live = self.live(now_ns)
        ready = [f for f, pf in self.pending.items()
                 if pf.cues and (live <= set(pf.cues) or now_ns >= pf.deadline_ns)]
        if not ready:
            return []
        newest = max(ready)
        older = sorted(f for f in self.pending if f <= newest)
        out = [self.pending[f] for f in older if self.pending[f].cues]
        self.frames_dropped += len(older) - len(out)
        for f in older:
            del self.pending[f]
        self.last_done = max(self.last_done, newest)
        return out

    def next_deadline_ns(self) -> int | None:
        """The earliest deadline of a frame that has answers (others wait for answers)."""
        return min((pf.deadline_ns for pf in self.pending.values() if pf.cues), default=None)
