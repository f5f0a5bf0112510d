"""Frame-window rules on the bus: which frames a node accepts cues, predictions and poses for.

The sync node's triggers define the frames that exist. A node keeps a ``FrameWindow`` fed with
the triggers it receives and asks it about every cues / prediction / pose message:

* the message's ``rig`` must be the node's rig (else dropped, reason ``rig``);
* cues and poses must name a frame the sync triggered, no more than ``behind`` frames before
  the newest trigger (``stale``), and carry that trigger's ``t_mono_ns`` (``stamp``): a
  message for a frame that was never triggered inside the window is ``unknown``;
* a cues or pose message up to ``ahead`` frames *after* the newest trigger is held, not
  dropped: its trigger may still be on its way on another link. It is handed back by
  ``on_trigger`` when that trigger arrives, and dropped as ``unknown`` once the window has
  passed it. Anything further ahead is ``future``;
* a prediction is for the *next* frame, which is not triggered yet: it is accepted up to
  ``ahead`` frames after the newest trigger (and back to ``behind`` before it).

Triggers themselves are the reference (on an authenticated bus only the sync node may publish
them, see ``deploy/zenoh``). On an open bus the window still refuses a trigger whose frame and
time do not fit the previous triggers': frames must increase, and with a fixed period no frame
may come more than ``TRIGGER_SLACK_FRAMES`` periods before its slot ``t0 + k * period`` (the sync
never sends a frame early; a late one may come any time later, and the slots it missed are
skipped). ``REANCHOR_TRIGGERS`` consecutive refused triggers that
fit one another (a restarted sync, or a forged first trigger) re-anchor the window.

Every drop is counted per reason (``drops``) and logged at most once per ``LOG_PERIOD_S``.
The class is thread-safe: Zenoh callbacks of several links may call it at once.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict

log = logging.getLogger(__name__)

WINDOW_BEHIND = 32             # frames: older cues / poses / predictions are stale
RECORD_BEHIND = 900            # frames (30 s at 30 fps) and
RECORD_AHEAD = 150             # frames (5 s): the recorder and the monitor keep every pose of a triggered
                               # frame even when a busy host delays their Zenoh callbacks (a pose seen after
                               # many newer triggers, or long before its own); a pose held for a trigger
                               # still needs that trigger's stamp, and HELD_MAX bounds what is held
WINDOW_AHEAD = 8               # frames after the newest trigger held (cues, poses) or accepted (predictions)
TRIGGER_SLACK_FRAMES = 2       # frame step vs time step / period of consecutive triggers
REANCHOR_TRIGGERS = 5          # consecutive refused but mutually consistent triggers that re-anchor
HELD_MAX = 256                 # messages held for triggers still on their way
LOG_PERIOD_S = 1.0
REASONS = ("rig", "future", "stale", "unknown", "stamp", "trigger")


def _fits(prev: tuple[int, int, int], frame: int, t_ns: int, period_ns: int) -> bool:
    """A trigger ``(frame, t_ns)`` can follow ``prev = (last frame, schedule origin, period_ns)``:
    a later frame, not sent before its slot. The sync sends frame ``k`` at ``t0 + k * period``
    or later (a descheduled sync is late, then skips the slots it missed), so ``t - k * period``
    never falls below the origin ``t0``, the smallest such value seen."""
    f0, origin, p0 = prev
    if frame <= f0:
        return False
    if period_ns <= 0 or p0 != period_ns:
        return period_ns == p0          # free-running: no time relation; a new rate: refuse
    return t_ns - frame * period_ns >= origin - TRIGGER_SLACK_FRAMES * period_ns


def _origin(prev: tuple[int, int, int] | None, frame: int, t_ns: int, period_ns: int) -> int:
    """The schedule origin after a fitting trigger: the smallest ``t - frame * period``."""
    mine = t_ns - frame * max(period_ns, 0)
    return mine if prev is None or prev[2] != period_ns else min(prev[1], mine)


class FrameWindow:
    """The frames a node accepts messages for (module doc). ``name`` labels the log lines."""

    def __init__(self, rig: str, name: str = "node", behind: int = WINDOW_BEHIND,
                 ahead: int = WINDOW_AHEAD) -> None:
        self.rig = rig
        self.name = name
        self.behind = int(behind)
        self.ahead = int(ahead)
        self.current: int | None = None                      # newest accepted trigger's frame
        self._last: tuple[int, int, int] | None = None       # (frame, schedule origin ns, period_ns)
        self._triggered: OrderedDict[int, int] = OrderedDict()   # frame -> t_mono_ns, window only
        self._held: list[tuple[int, int | None, object]] = []    # (frame, stamp, item)
        self._refused: list[tuple[int, int, int]] = []           # consistent refused triggers
        self.drops: dict[str, int] = dict.fromkeys(REASONS, 0)
        self.accepted = 0
        self._lock = threading.Lock()
        self._last_log = 0.0
        self._unlogged = 0

    # ------------------------------------------------------------ counting
    def _drop(self, reason: str, what: str, frame) -> None:
        self.drops[reason] += 1
        self._unlogged += 1
        now = time.monotonic()
        if now - self._last_log >= LOG_PERIOD_S:
            log.warning("%s: dropped %s for frame %s (%s; newest trigger %s); %d dropped since the last "
                        "report, by reason %s", self.name, what, frame, reason, self.current, self._unlogged,
                        {k: v for k, v in self.drops.items() if v})
            self._last_log, self._unlogged = now, 0

    @property
    def total_drops(self) -> int:
        return sum(self.drops.values())

    def counters(self) -> dict[str, int]:
        """``{"window_<reason>": n}`` for a node's status ``extra``."""
        with self._lock:
            return {f"window_{k}": v for k, v in self.drops.items()}

    # ------------------------------------------------------------ triggers
    def on_trigger(self, rig: str, frame: int, t_mono_ns: int, period_ns: int) -> tuple[bool, list]:
        """Feed one trigger. Returns (accepted, items held for this frame, now admitted)."""
        with self._lock:
            if rig != self.rig:
                self._drop("rig", "trigger", frame)
                return False, []
            if self._last is not None and not _fits(self._last, frame, t_mono_ns, period_ns):
                chain = self._refused[-1] if self._refused else None
                if chain is not None and _fits(chain, frame, t_mono_ns, period_ns):
                    self._refused.append((frame, _origin(chain, frame, t_mono_ns, period_ns), period_ns))
                else:
                    self._refused = [(frame, _origin(None, frame, t_mono_ns, period_ns), period_ns)]
                if len(self._refused) < REANCHOR_TRIGGERS:
                    self._drop("trigger", "trigger", frame)
                    return False, []
                log.warning("%s: %d consistent triggers outside the window: re-anchored at frame %d "
                            "(was %s)", self.name, len(self._refused), frame, self.current)
                self._triggered.clear()
                self._last = None
            self._refused = []
            self._last = (frame, _origin(self._last, frame, t_mono_ns, period_ns), period_ns)
            self.current = frame
            self._triggered[frame] = t_mono_ns
            while self._triggered and next(iter(self._triggered)) < frame - self.behind:
                self._triggered.popitem(last=False)
            return True, self._release()

    def _release(self) -> list:
        out, keep = [], []
        for frame, stamp, item in self._held:
            if frame in self._triggered:
                if stamp is not None and stamp != self._triggered[frame]:
                    self._drop("stamp", "held message", frame)
                else:
                    self.accepted += 1
                    out.append(item)
            elif frame <= self.current:
                self._drop("unknown", "held message", frame)
            elif frame > self.current + self.ahead:
                self._drop("future", "held message", frame)
            else:
                keep.append((frame, stamp, item))
        self._held = keep
        return out

    # ------------------------------------------------------------ messages
    def accept(self, msg, item=None) -> list:
        """The one hook of a node: feed any received message; returns what to process now, in
        order (``item``, default the message itself; a trigger's list also holds the items
        that were waiting for it). ``Trigger``, ``Cues``, ``Pose`` and ``Prediction`` are
        checked; any other message passes."""
        from nodes.messages import Cues, Pose, Prediction, Trigger

        item = msg if item is None else item
        if isinstance(msg, Trigger):
            ok, released = self.on_trigger(msg.rig, msg.frame, msg.t_mono_ns, msg.period_ns)
            return [item, *released] if ok else []
        if isinstance(msg, (Cues, Pose)):
            return [item] if self.admit(msg.rig, msg.frame, msg.t_trigger_mono_ns, item, msg.TYPE) else []
        if isinstance(msg, Prediction):
            return [item] if self.admit_ahead(msg.rig, msg.prediction.frame) else []
        return [item]

    def admit(self, rig: str, frame: int, t_trigger_ns: int | None = None, item=None,
              what: str = "message") -> bool:
        """Cues or a pose for ``frame`` (with its trigger stamp, if it carries one): True to
        use it now; False when dropped (counted) or held (handed back by ``on_trigger``)."""
        with self._lock:
            reason = self._check(rig, frame)
            if reason is None:
                stamp = self._triggered.get(frame)
                if stamp is not None:
                    if t_trigger_ns is not None and t_trigger_ns != stamp:
                        self._drop("stamp", what, frame)
                        return False
                    self.accepted += 1
                    return True
                if self.current is not None and frame <= self.current:
                    self._drop("unknown", what, frame)
                    return False
                if len(self._held) >= HELD_MAX:
                    self._drop("future", what, frame)
                    return False
                self._held.append((frame, t_trigger_ns, item))
                return False
            self._drop(reason, what, frame)
            return False

    def admit_ahead(self, rig: str, frame: int, what: str = "prediction") -> bool:
        """A prediction (for a frame not triggered yet): True if inside the window."""
        with self._lock:
            reason = self._check(rig, frame) or ("unknown" if self.current is None else None)
            if reason is not None:
                self._drop(reason, what, frame)
                return False
            self.accepted += 1
            return True

    def _check(self, rig: str, frame: int) -> str | None:
        if rig != self.rig:
            return "rig"
        if self.current is None:
            return None                      # nothing triggered yet: held until the first trigger
        if frame > self.current + self.ahead:
            return "future"
        if frame < self.current - self.behind:
            return "stale"
        return None


def window_drops(node_table: dict, *windows: FrameWindow) -> dict[str, int]:
    """Drops per reason summed over the nodes of a ``ServiceMonitor.node_table()`` (their
    ``x_window_<reason>`` status fields) and the given windows (e.g. the monitor's own)."""
    out = dict.fromkeys(REASONS, 0)
    for st in node_table.values():
        for r in REASONS:
            out[r] += int(st.get(f"x_window_{r}", 0))
    for w in windows:
        for r in REASONS:
            out[r] += w.drops[r]
    return out
