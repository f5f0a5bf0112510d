"""Camera worker: one process per camera (seed digest A.6, the 2D-processing PCs).

On each trigger: grab (replay: the recording frame of that id; live: the grabber's newest
frame), perceive with ``CameraPerceiver`` using fusion's prediction for that frame when it
arrived (labelling + occlusion, seed A.4), publish the cues. Triggers that arrive while a
frame is still being processed wait in a short queue (``TriggerQueue``): a replay worker
serves the few it fell behind by, in order; a live one keeps only the newest (its grabber
has no older image). Triggers pushed out unread are counted as drops.

Optional outputs: a JPEG preview every ``--preview-every`` frames (for the viewer) and, for
live sources with ``--publish-frames``, the raw images and backgrounds (for the recorder).

    python -m nodes.camera_worker --rig RIG.toml --camera cam_1 --source replay:REC_DIR

With ``--standby`` the process is a *hot spare* (the launcher keeps one): it imports and loads
every JIT kernel by warming up on the given camera (a replay's frames; synthetic frames for a
live source, whose device belongs to the running worker), without joining the service, then
waits for one JSON line on stdin, ``{"argv": [worker flags], "log": "FILE"}``, and becomes that
worker. Replacing a dead worker so costs its per-camera set-up, not a process start.
"""

from __future__ import annotations

import collections
import json
import logging
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from nodes.frame_window import FrameWindow
from nodes.messages import Background, Cues, Frame, Keys, Prediction, Preview, Trigger
from nodes.node import NodeSettings, parse_settings, rig_fps, run_node, settings_parser, setup_logging
from nodes.runtime import IdleGC, NodeRuntime, ThreadPriority

log = logging.getLogger(__name__)

QUICK_EXIT = True               # it holds no file: the fork server ends it without the interpreter's teardown
PREVIEW_JPEG_QUALITY = 70
TRIGGER_WAIT_S = 0.2           # wake up this often to send status while idle
PREDICTIONS_KEPT = 8           # predictions for the coming frames kept by frame id
CATCH_UP_DEPTH = 4             # triggers a replay worker keeps (TriggerQueue)
DEFER_FRACTION = 0.5           # deferred work waits for fusion's answer at most this part of a period


@dataclass(frozen=True)
class WorkerSettings(NodeSettings):
    """camera : the rig camera; source : replay:REC_DIR | v4l2:/dev/videoN | fake:REC_DIR |
    gst:PIPELINE; backgrounds_from : a recording whose stored backgrounds a gst: source uses;
    fps : a live device's frame rate (None: the rig's); perception_config : perception TOML
    (None: built-in); preview_every : a JPEG every N frames (0 = never); publish_frames :
    raw frames + backgrounds for the recorder; cv_threads : OpenCV threads; standby : the
    hot spare (module doc). ``node`` defaults to ``worker-<camera>``."""

    camera: str = ""
    source: str = ""
    backgrounds_from: Path | None = None
    fps: float | None = None
    perception_config: Path | None = None
    preview_every: int = 0
    publish_frames: bool = False
    cv_threads: int = 1
    standby: bool = False


class TriggerQueue:
    """The newest ``depth`` triggers, filled by the Zenoh callback and taken oldest first; a
    trigger pushed out unread counts as a drop (``overwritten``).

    Depth 1 (a live camera: its grabber holds only the newest image, so an older trigger
    cannot be served) keeps the newest only. A replay worker keeps ``CATCH_UP_DEPTH``: after
    a stall that hit the whole machine (tens of ms, every worker at once) it serves the
    frames it missed, in order, instead of losing them.
    """

    def __init__(self, depth: int = 1) -> None:
        self._cond = threading.Condition()
        self._queue: collections.deque[tuple[Trigger, int]] = collections.deque()
        self.depth = depth
        self.taken_recv_ns = 0      # when the last taken trigger arrived (monotonic ns)
        self.overwritten = 0

    def put(self, trig: Trigger, recv_ns: int = 0) -> None:
        with self._cond:
            if len(self._queue) >= self.depth:
                self._queue.popleft()
                self.overwritten += 1
            self._queue.append((trig, recv_ns))
            self._cond.notify()

    def take(self, timeout_s: float) -> Trigger | None:
        """The oldest trigger kept, waiting up to ``timeout_s``; None on timeout or ``poke``."""
        with self._cond:
            if not self._queue:
                self._cond.wait(timeout_s)
            if not self._queue:
                return None
            trig, self.taken_recv_ns = self._queue.popleft()
            return trig

    def poke(self) -> None:
        """Wake a waiting ``take`` (e.g. a prediction arrived: time for the deferred work)."""
        with self._cond:
            self._cond.notify()


class PredictionBox:
    """Predictions by frame id (a few kept), filled by the Zenoh callback."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_frame: dict[int, object] = {}

    def put(self, pred) -> None:
        with self._lock:
            self._by_frame[pred.frame] = pred
            if len(self._by_frame) > PREDICTIONS_KEPT:
                for f in sorted(self._by_frame)[:-PREDICTIONS_KEPT]:
                    del self._by_frame[f]

    def get(self, frame: int):
        with self._lock:
            return self._by_frame.get(frame)


def make_perceiver(camera, backgrounds, config_path=None, origin: str = "live"):
    """``CameraPerceiver`` with the given (or default) config, adapted to where the frames
    come from (``origin``: a recording's source such as "studio", or "live")."""
    from mocap_rt.perception import pipeline

    config = pipeline.load_perception_config(config_path) if config_path is not None else pipeline.PerceptionConfig()
    return pipeline.CameraPerceiver(camera, backgrounds, pipeline.config_for_source(config, origin))


def warm_up(camera, source, backgrounds, config_path=None) -> None:
    """Run a throw-away perceiver once (JIT kernels, caches) so the first triggered frame is
    as fast as any other; a live source is not read (a background frame stands in)."""
    warm = make_perceiver(camera, backgrounds, config_path, source.origin)
    warm.process(source.grab(0).image if not source.live else backgrounds[0], 0, None)


def standby(parser, s: WorkerSettings) -> WorkerSettings | None:
    """The hot spare (module doc): warm up on ``s``' camera, wait for the assignment on
    stdin, return its settings (None at end of input: the launcher stopped)."""
    import numpy as np

    from mocap_rt.geometry.rig import read_rig
    from nodes.sources import open_source

    rig = read_rig(s.rig)
    camera = rig[s.camera]
    fps = s.fps or rig_fps(rig)
    source = open_source(s.source, camera, fps) if s.source.startswith("replay:") else None
    if source is not None:
        warm_up(camera, source, source.backgrounds(), s.perception_config)
        source.close()
    else:
        w, h = camera.size
        noise = np.random.default_rng(0).integers(0, 8, (3, h, w, 3), dtype=np.uint8)
        backgrounds = noise + np.array([90, 100, 110], np.uint8)
        make_perceiver(camera, backgrounds, s.perception_config).process(backgrounds[0], 0, None)
    log.info("standby: warm, waiting for a camera to take over")
    line = sys.stdin.readline()
    if not line.strip():
        return None
    job = json.loads(line)
    if job.get("log"):
        fd = os.open(job["log"], os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
    new = parse_settings(parser, WorkerSettings, job["argv"])
    log.info("standby: taking over as %s", new.node or new.camera)
    return new


def run_worker(session, keys: Keys, camera, source, perceiver, rt: NodeRuntime,
               preview_every: int = 0, publish_frames: bool = False) -> None:
    """The worker loop until ``rt.stop``: trigger -> grab -> perceive -> publish."""
    import cv2

    name = camera.name
    triggers, preds = TriggerQueue(1 if source.live else CATCH_UP_DEPTH), PredictionBox()
    window = FrameWindow(keys.rig, rt.node)     # triggers that fit, predictions near the newest

    def on_trigger(sample) -> None:
        recv_ns = time.monotonic_ns()
        trig = rt.decoder.decode(sample.payload, Trigger)
        if trig is not None and window.accept(trig):
            triggers.put(trig, recv_ns)

    def on_prediction(sample) -> None:
        msg = rt.decoder.decode(sample.payload, Prediction)
        if msg is not None and msg.prediction.camera == name and window.accept(msg):
            preds.put(msg.prediction)
            triggers.poke()

    cues_pub = session.declare_publisher(keys.cues(name), express=True)
    preview_pub = session.declare_publisher(keys.preview(name)) if preview_every > 0 else None
    frame_pub = session.declare_publisher(keys.frame(name)) if publish_frames else None
    rt.subscribe(keys.trigger, on_trigger, direct=True)
    rt.subscribe(keys.prediction(name), on_prediction, direct=True)
    rt.publish_status("running", force=True)
    gcs = IdleGC()
    gcs.start()
    prio = ThreadPriority()       # deferred work at normal priority (when the node is real-time)
    used_pred = 0
    deferred = None      # (frame, grab, not-after monotonic s): work kept off the critical path

    def do_deferred() -> None:
        """Preview JPEG, raw frame and the next replay image: done once fusion has answered
        (its prediction for the next frame arrived) or half a period passed, so that they do
        not compete with the other cameras' perception of the same frame."""
        frame, grab, _ = deferred
        if frame_pub is not None:
            frame_pub.put(Frame(keys.rig, name, frame, grab.t_wall_ns, grab.image).to_msgpack())
        if preview_pub is not None and frame % preview_every == 0:
            ok, jpg = cv2.imencode(".jpg", grab.image, [cv2.IMWRITE_JPEG_QUALITY, PREVIEW_JPEG_QUALITY])
            if ok:
                preview_pub.put(Preview(keys.rig, name, frame, jpg.tobytes()).to_msgpack())
        c0 = time.thread_time()
        try:
            source.prefetch(frame + 1)
        except (OSError, ValueError) as exc:
            log.warning("%s: prefetch of frame %d failed: %s", name, frame + 1, exc)
        rt.extra["prefetch_cpu_ms"] = (time.thread_time() - c0) * 1e3

    try:
        while not rt.stop.is_set():
            wait = TRIGGER_WAIT_S if deferred is None else max(0.0, deferred[2] - time.monotonic())
            trig = triggers.take(wait)
            rt.drops = triggers.overwritten
            rt.extra.update(window.counters())
            if deferred is not None and (trig is not None or preds.get(deferred[0] + 1) is not None
                                         or time.monotonic() >= deferred[2]):
                if trig is None:
                    prio.normal()        # off the critical path; else this frame needs it now
                do_deferred()
                prio.realtime_again()    # wait for the next trigger real-time (prompt wake-up)
                deferred = None
            if trig is None:
                gcs.idle()               # between frames: the next trigger is not here yet
                rt.publish_status()
                continue
            t0, c0 = time.perf_counter(), time.thread_time()
            t_start_ns = time.monotonic_ns()
            try:
                grab = source.grab(trig.frame)
            except (TimeoutError, OSError, ValueError) as exc:
                rt.source_drops += 1           # reported as decode_drops (status line, --stats)
                if rt.source_drops <= 5 or rt.source_drops % 100 == 0:
                    log.warning("%s: frame %d not grabbed (%d so far): %s", name, trig.frame, rt.source_drops, exc)
                rt.publish_status()
                continue
            pred = preds.get(trig.frame)
            used_pred += pred is not None
            cues = perceiver.process(grab.image, trig.frame, pred)
            work_ms = (time.perf_counter() - t0) * 1e3
            # where this frame's time went, ms after the trigger (fusion forwards the
            # slowest camera's in the pose's timings)
            cues.timings_ms.update(w_recv=(triggers.taken_recv_ns - trig.t_mono_ns) / 1e6,
                                   w_start=(t_start_ns - trig.t_mono_ns) / 1e6,
                                   w_pub=(time.monotonic_ns() - trig.t_mono_ns) / 1e6,
                                   w_cpu=(time.thread_time() - c0) * 1e3)
            cues_pub.put(Cues(keys.rig, cues, trig.t_mono_ns, grab.t_mono_ns, work_ms).to_msgpack())
            rt.meter.add(work_ms)
            rt.extra["predictions_used"] = used_pred
            deferred = (trig.frame, grab, time.monotonic() + DEFER_FRACTION * trig.period_ns / 1e9)
            rt.publish_status()
    finally:
        gcs.stop()
        rt.unsubscribe()


def _flags(p) -> None:
    p.add_argument("--camera", help="camera name in the rig (required)")
    p.add_argument("--source", help="replay:REC_DIR | v4l2:/dev/videoN | fake:REC_DIR | gst:PIPELINE (required)")
    p.add_argument("--backgrounds-from", type=Path, metavar="REC_DIR",
                   help="gst: sources: use this recording's stored backgrounds (and source kind)")
    p.add_argument("--fps", type=float, help="live device frame rate (default: rig metadata fps or 30)")
    p.add_argument("--perception-config", type=Path, help="perception TOML (default: built-in)")
    p.add_argument("--preview-every", type=int, help="publish a JPEG every N frames (0 = never)")
    p.add_argument("--publish-frames", action="store_true", help="publish raw frames + backgrounds (recorder)")
    p.add_argument("--cv-threads", type=int,
                   help="OpenCV threads in this worker (one process per camera already runs in parallel)")
    p.add_argument("--standby", action="store_true",
                   help="hot spare: warm up, then take the worker flags to run from stdin (module doc)")


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    return settings_parser(WorkerSettings, __doc__.splitlines()[0], _flags)


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    s = parse_settings(p, WorkerSettings, argv)
    if not (s.camera and s.source):
        p.error("--camera and --source are required (flags or --config)")
    if s.standby:
        setup_logging(s.log_level)
        s = standby(p, s)
        if s is None:
            return 0
    import cv2

    from nodes.sources import open_source

    cv2.setNumThreads(s.cv_threads)
    t = [time.perf_counter()]

    def prepare(rig, stack):
        source = open_source(s.source, rig[s.camera], s.fps or rig_fps(rig), s.backgrounds_from)
        stack.callback(source.close)
        return rig[s.camera], source

    def setup(rt: NodeRuntime, rig, state):
        camera, source = state
        t.append(time.perf_counter())
        backgrounds = source.backgrounds()
        perceiver = make_perceiver(camera, backgrounds, s.perception_config, source.origin)
        t.append(time.perf_counter())
        warm_up(camera, source, backgrounds, s.perception_config)
        source.prefetch(0)          # the first trigger's image is ready (no seek back)
        t.append(time.perf_counter())
        log.info("%s: set up in %.2f s (source + session %.2f, perceiver %.2f, warm-up %.2f)",
                 rt.node, t[-1] - t[0], *(b - a for a, b in zip(t, t[1:])))
        if s.publish_frames and source.live:
            rt.session.put(rt.keys.background(camera.name),
                           Background(rt.keys.rig, camera.name, backgrounds).to_msgpack())
        return camera, source, perceiver

    def serve(rt: NodeRuntime, rig, state) -> None:
        camera, source, perceiver = state
        run_worker(rt.session, rt.keys, camera, source, perceiver, rt, s.preview_every,
                   s.publish_frames and source.live)

    return run_node("camera", s, serve, prepare=prepare, setup=setup, node=s.node or f"worker-{s.camera}")


if __name__ == "__main__":
    sys.exit(main())
