"""Camera worker: one process per camera (seed digest A.6, the 2D-processing PCs).

On each trigger: grab (replay: the recording frame of that id; live: the grabber's newest
frame), perceive with ``CameraPerceiver`` using fusion's prediction for that frame when it
arrived (labelling + occlusion, seed A.4), publish the cues. Triggers that arrive while a
frame is still being processed are not queued: only the newest is kept, the others are
counted as drops (a late frame is worthless to a real-time fusion).

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

import json
import logging
import os
import sys
import threading
import time

from nodes.frame_window import FrameWindow
from nodes.messages import Background, Cues, Frame, Keys, Prediction, Preview, Trigger
from nodes.runtime import IdleGC, NodeRuntime, ThreadPriority, base_parser, load_rig, node_session, setup_logging
from nodes.transport import direct_callback

log = logging.getLogger(__name__)

PREVIEW_JPEG_QUALITY = 70
TRIGGER_WAIT_S = 0.2           # wake up this often to send status while idle
PREDICTIONS_KEPT = 8           # predictions for the coming frames kept by frame id
DEFER_FRACTION = 0.5           # deferred work waits for fusion's answer at most this part of a period


class TriggerSlot:
    """The newest trigger, filled by the Zenoh callback; older unread ones count as drops."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._trigger: Trigger | None = None
        self._recv_ns = 0
        self.taken_recv_ns = 0      # when the last taken trigger arrived (monotonic ns)
        self.overwritten = 0

    def put(self, trig: Trigger, recv_ns: int = 0) -> None:
        with self._cond:
            if self._trigger is not None:
                self.overwritten += 1
            self._trigger, self._recv_ns = trig, recv_ns
            self._cond.notify()

    def take(self, timeout_s: float) -> Trigger | None:
        """The newest trigger, waiting up to ``timeout_s``; None on timeout or ``poke``."""
        with self._cond:
            if self._trigger is None:
                self._cond.wait(timeout_s)
            trig, self._trigger = self._trigger, None
            if trig is not None:
                self.taken_recv_ns = self._recv_ns
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


def standby(parser, args):
    """The hot spare (module doc): warm up on ``args``' camera, wait for the assignment on
    stdin, return its parsed flags (None at end of input: the launcher stopped)."""
    import numpy as np

    from nodes.sources import open_source

    camera = load_rig(args)[args.camera]
    source = open_source(args.source, camera, args.fps) if args.source.startswith("replay:") else None
    if source is not None:
        warm_up(camera, source, source.backgrounds(), args.perception_config)
        source.close()
    else:
        w, h = camera.size
        noise = np.random.default_rng(0).integers(0, 8, (3, h, w, 3), dtype=np.uint8)
        backgrounds = noise + np.array([90, 100, 110], np.uint8)
        make_perceiver(camera, backgrounds, args.perception_config).process(backgrounds[0], 0, None)
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
    new = parser.parse_args(job["argv"])
    log.info("standby: taking over as %s", new.node or new.camera)
    return new


def run_worker(session, keys: Keys, camera, source, perceiver, rt: NodeRuntime,
               preview_every: int = 0, publish_frames: bool = False) -> None:
    """The worker loop until ``rt.stop``: trigger -> grab -> perceive -> publish."""
    import cv2

    name = camera.name
    slot, preds = TriggerSlot(), PredictionBox()
    window = FrameWindow(keys.rig, rt.node)     # triggers that fit, predictions near the newest

    def on_trigger(sample) -> None:
        recv_ns = time.monotonic_ns()
        trig = rt.decoder.decode(sample.payload, Trigger)
        if trig is not None and window.accept(trig):
            slot.put(trig, recv_ns)

    def on_prediction(sample) -> None:
        msg = rt.decoder.decode(sample.payload, Prediction)
        if msg is not None and msg.prediction.camera == name and window.accept(msg):
            preds.put(msg.prediction)
            slot.poke()

    cues_pub = session.declare_publisher(keys.cues(name), express=True)
    preview_pub = session.declare_publisher(keys.preview(name)) if preview_every > 0 else None
    frame_pub = session.declare_publisher(keys.frame(name)) if publish_frames else None
    subs = [session.declare_subscriber(keys.trigger, direct_callback(on_trigger)),
            session.declare_subscriber(keys.prediction(name), direct_callback(on_prediction))]
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
            trig = slot.take(wait)
            rt.drops = slot.overwritten
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
            cues.timings_ms.update(w_recv=(slot.taken_recv_ns - trig.t_mono_ns) / 1e6,
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
        for s in subs:
            s.undeclare()


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    p = base_parser(__doc__.splitlines()[0], "")
    p.add_argument("--camera", required=True, help="camera name in the rig")
    p.add_argument("--source", required=True, help="replay:REC_DIR | v4l2:/dev/videoN | fake:REC_DIR | gst:PIPELINE")
    p.add_argument("--backgrounds-from", default=None, metavar="REC_DIR",
                   help="gst: sources: use this recording's stored backgrounds (and source kind)")
    p.add_argument("--fps", type=float, default=30.0, help="live device frame rate")
    p.add_argument("--perception-config", default=None, help="perception TOML (default: built-in)")
    p.add_argument("--preview-every", type=int, default=0, help="publish a JPEG every N frames (0 = never)")
    p.add_argument("--publish-frames", action="store_true", help="publish raw frames + backgrounds (recorder)")
    p.add_argument("--cv-threads", type=int, default=1,
                   help="OpenCV threads in this worker (one process per camera already runs in parallel)")
    p.add_argument("--standby", action="store_true",
                   help="hot spare: warm up, then take the worker flags to run from stdin (module doc)")
    return p


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    if args.standby:
        args = standby(p, args)
        if args is None:
            return 0
    import cv2

    cv2.setNumThreads(args.cv_threads)
    rig = load_rig(args)
    camera = rig[args.camera]
    from nodes.sources import open_source

    t = [time.perf_counter()]
    source = open_source(args.source, camera, args.fps, args.backgrounds_from)
    with node_session(args, "camera", args.node or f"worker-{camera.name}") as rt:
        t.append(time.perf_counter())
        session, keys, node = rt.session, rt.keys, rt.node
        rt.publish_status("starting", force=True)
        try:
            backgrounds = source.backgrounds()
            perceiver = make_perceiver(camera, backgrounds, args.perception_config, source.origin)
            t.append(time.perf_counter())
            warm_up(camera, source, backgrounds, args.perception_config)
            source.prefetch(0)          # the first trigger's image is ready (no seek back)
            t.append(time.perf_counter())
            log.info("%s: set up in %.2f s (source + session %.2f, perceiver %.2f, warm-up %.2f)",
                     node, t[-1] - t[0], *(b - a for a, b in zip(t, t[1:])))
            if args.publish_frames and source.live:
                session.put(keys.background(camera.name),
                            Background(keys.rig, camera.name, backgrounds).to_msgpack())
            rt.enter_realtime(args.rt_priority)
            rt.publish_status("ready", force=True)
            run_worker(session, keys, camera, source, perceiver, rt, args.preview_every,
                       args.publish_frames and source.live)
            rt.publish_status("stopping", force=True)
        finally:
            source.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
