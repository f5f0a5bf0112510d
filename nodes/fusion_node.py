"""Fusion node: gathers each frame's cues, fuses and solves IK, publishes pose + prediction.

Seed digest A.6 (the PC that does 3D reconstruction and motion generation). For frame ``k``
the node waits until every *live* camera answered or the deadline
``t_trigger + deadline_frac * period`` passed, whichever is first, then calls
``BodyTracker.fit_frame`` with the cameras it has and publishes the ``Pose`` (which names the
cameras used and the cameras missing), then runs ``identify_frame`` (left/right identity,
off the latency path) and publishes the next frame's ``CuePrediction`` for every
camera (a period before the next trigger; when free-running, predictions go first). A camera is live when its cues arrived
within ``LIVENESS_S``; a killed worker therefore costs at most a deadline on a few frames,
and a restarted one is counted again with its first answer.

    python -m nodes.fusion_node --rig RIG.toml [--deadline-frac 0.8] [--config fusion.toml]
"""

from __future__ import annotations

import logging
import math
import queue
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# frame gathering lives in the library (the first stage of fusion); its names are re-exported here
from mocap_rt.fusion.gather import (DEFAULT_DEADLINE_FRAC, FIRST_FRAME_GRACE_S, FREE_RUN_DEADLINE_S,  # noqa: F401
                                    LIVENESS_S, MAX_PENDING_FRAMES, FrameGatherer, PendingFrame)
from nodes.frame_window import FrameWindow
from nodes.messages import Cues, Keys, Pose, Prediction, Trigger
from nodes.node import NodeSettings, parse_settings, rig_fps, run_node, settings_parser
from nodes.runtime import IdleGC, NodeRuntime

log = logging.getLogger(__name__)

QUICK_EXIT = True               # it holds no file: the fork server ends it without the interpreter's teardown
# a standing person's cues (head, hand_l, hand_r, foot_l, foot_r, torso), metres, world
WARM_UP_CUES_M = np.array([[0.0, 0.0, 1.7], [0.35, 0.0, 1.0], [-0.35, 0.0, 1.0],
                           [0.12, 0.0, 0.05], [-0.12, 0.0, 0.05], [0.0, 0.0, 1.25]])
WARM_UP_FRAMES = 3
WARM_UP_COV_PX2 = 4.0


@dataclass(frozen=True)
class FusionSettings(NodeSettings):
    """deadline_frac : wait for late cameras at most this fraction of the frame period, in
    (0, 1]; fps : frame rate of the frame ids (None: the rig's); bones : the subject's bone
    lengths TOML ([bones] table; None: estimated from the first seconds of cues)."""

    node: str = "fusion"
    deadline_frac: float = DEFAULT_DEADLINE_FRAC
    fps: float | None = None
    bones: Path | None = None

    def __post_init__(self) -> None:
        NodeSettings.__post_init__(self)
        if not (math.isfinite(self.deadline_frac) and 0.0 < self.deadline_frac <= 1.0):
            raise ValueError(f"deadline_frac must be in (0, 1], got {self.deadline_frac}")


def make_tracker(rig, fps: float, bone_lengths=None, background: bool = True):
    """D's ``BodyTracker`` with its default config at the stream's frame rate; the bone
    lengths are estimated from the first seconds of cues unless given, their fit to the
    silhouettes in another process (the frames do not wait for it; ``background`` False: in
    the frame, for a tracker that never gets that far)."""
    from mocap_rt.fusion.config import FusionConfig
    from mocap_rt.fusion.tracker import BodyTracker

    return BodyTracker(rig, FusionConfig(fps=fps, bone_lengths=bone_lengths), background_calibration=background)


def warm_up(rig, fps: float) -> float:
    """Run a throw-away tracker on synthetic cues so every numba kernel is compiled/loaded
    before the first real frame (the first step otherwise takes seconds). Returns seconds."""
    from mocap_rt.cues import N_CUES, CameraCues, CompactSilhouette

    t0 = time.perf_counter()
    tracker = make_tracker(rig, fps, background=False)     # calibrates after seconds: no fit's process
    for f in range(WARM_UP_FRAMES):
        cues = {}
        for cam in rig.cameras:
            uv, _ = cam.project(WARM_UP_CUES_M + [0.01 * f, 0.0, 0.0])
            sil = CompactSilhouette.box_around(uv)     # a silhouette: the silhouette fit is loaded too
            cues[cam.name] = CameraCues(cam.name, f, uv, np.tile(np.eye(2) * WARM_UP_COV_PX2, (N_CUES, 1, 1)),
                                        np.full(N_CUES, 50.0), np.ones(N_CUES), silhouette=sil)
        tracker.step(f, cues)
        tracker.predict(f + 1)
    return time.perf_counter() - t0


def stage_timings(pf: PendingFrame, t_ready_ns: int) -> dict[str, float]:
    """The critical path of one frame, ms after its trigger: the slowest camera's trigger
    receipt / processing start / cues publication (``w_*``), the first and last answers' arrival
    here (``f_first_cue``, ``f_last_cue``) and the start of fusion (``f_ready``)."""
    out: dict[str, float] = {}
    for key in ("w_recv", "w_start", "w_pub", "w_cpu"):
        vals = [float(c.timings_ms[key]) for c in pf.cues.values() if key in c.timings_ms]
        if vals:
            out[key] = max(vals)
            out[key + "_min"] = min(vals)
    # perception time (wall, incl. preemption) of the frame, summed over the cameras and the slowest
    work = [float(c.timings_ms["total"]) for c in pf.cues.values() if "total" in c.timings_ms]
    if work:
        out["w_perceive_sum"] = sum(work)
        out["w_perceive_max"] = max(work)
    # the workers' own per-stage perception times (mocap_rt.perception.pipeline), mean over the
    # cameras, and their mean CPU per frame (the cluster's compute floor, bench/bench_service.py)
    for key in ("silhouette", "colour", "blobs", "torso", "w_cpu"):
        vals = [float(c.timings_ms[key]) for c in pf.cues.values() if key in c.timings_ms]
        if vals:
            out[("p_" + key) if key != "w_cpu" else "w_cpu_mean"] = sum(vals) / len(vals)
    if pf.t_first_ns:
        out["f_first_cue"] = (pf.t_first_ns - pf.t_trigger_mono_ns) / 1e6
    if pf.t_last_ns:
        out["f_last_cue"] = (pf.t_last_ns - pf.t_trigger_mono_ns) / 1e6
    out["f_ready"] = (t_ready_ns - pf.t_trigger_mono_ns) / 1e6
    return out


def fuse_and_publish(tracker, keys: Keys, pf: PendingFrame, rig_cameras: list[str], pred_pubs: dict,
                     pose_pub, rt: NodeRuntime, pose_first: bool = True) -> Pose | None:
    """Step the tracker on one gathered frame and publish the pose and the next frame's
    predictions.

    ``pose_first`` (triggered rates): the pose goes out right after ``fit_frame``, then the
    identity (``identify_frame``), ``predict`` and the predictions; the next trigger is a period away, so the workers still
    have them in time, and the work the predictions release in the workers (their deferred
    decode) cannot preempt the pose. Free-running (the sync triggers on the pose): the
    predictions go first, else the next trigger could overtake them.
    """
    t_ready_ns = time.monotonic_ns()
    t0, c0 = time.perf_counter(), time.thread_time()
    try:
        result = tracker.fit_frame(pf.frame, pf.cues)
        t1, c1 = time.perf_counter(), time.thread_time()
        predictions = None
        if not pose_first:
            result = tracker.identify_frame(result)     # a switch shows in this very pose
            predictions = tracker.predict(pf.frame + 1)
    except Exception as exc:  # a fusion failure on one frame must not end the service
        log.exception("fusion: frame %d failed: %s", pf.frame, exc)
        rt.extra["fusion_errors"] = rt.extra.get("fusion_errors", 0) + 1
        return None
    t2 = time.perf_counter()
    if predictions is not None:
        publish_predictions(keys, predictions, pred_pubs)
    t3 = time.perf_counter()
    used = tuple(c for c in rig_cameras if c in pf.cues)
    missing = tuple(c for c in rig_cameras if c not in pf.cues)
    timings = {"step_ms": (t1 - t0) * 1e3, "step_cpu_ms": (c1 - c0) * 1e3, "gather_ms": (t_ready_ns - pf.t_trigger_mono_ns) / 1e6}
    if predictions is not None:
        timings.update(predict_ms=(t2 - t1) * 1e3, pred_pub_ms=(t3 - t2) * 1e3)
    timings.update(stage_timings(pf, t_ready_ns))
    timings.update({f"lib_{k}": float(v) for k, v in dict(getattr(result, "timings_ms", {})).items()})
    pose = Pose(keys.rig, pf.frame, pf.t_trigger_mono_ns, time.monotonic_ns(),
                np.asarray(result.cues_3d, np.float64), np.asarray(result.cue_valid, bool),
                np.asarray(result.joints, np.float64), np.asarray(result.bvh_frame, np.float64),
                used, missing, tracker.lengths.as_array(), timings)
    pose_pub.put(pose.to_msgpack())
    if predictions is None:
        t4 = t_id = time.perf_counter()
        try:
            tracker.identify_frame(result)
            t_id = time.perf_counter()
            predictions = tracker.predict(pf.frame + 1)
        except Exception as exc:  # noqa: BLE001 - as above: count, log, carry on
            log.exception("fusion: identity or prediction for frame %d failed: %s", pf.frame + 1, exc)
            rt.extra["fusion_errors"] = rt.extra.get("fusion_errors", 0) + 1
            predictions = {}
        t5 = time.perf_counter()
        publish_predictions(keys, predictions, pred_pubs)
        rt.extra["identify_ms"] = (t_id - t4) * 1e3
        rt.extra["predict_ms"] = (t5 - t_id) * 1e3
        rt.extra["pred_pub_ms"] = (time.perf_counter() - t5) * 1e3
        t2 += t5 - t4
    rt.meter.add((t2 - t0) * 1e3)
    return pose


def publish_predictions(keys: Keys, predictions: dict, pred_pubs: dict) -> None:
    """One ``Prediction`` per camera that has a publisher."""
    for cam, pred in predictions.items():
        pub = pred_pubs.get(cam)
        if pub is not None:
            pub.put(Prediction(keys.rig, pred).to_msgpack())


def run_fusion(session, keys: Keys, rig, tracker, rt: NodeRuntime,
               deadline_frac: float = DEFAULT_DEADLINE_FRAC) -> None:
    """The fusion loop until ``rt.stop``."""
    rig_cameras = list(rig.names)
    gather = FrameGatherer(rig_cameras, deadline_frac)
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    window = FrameWindow(keys.rig, rt.node)     # only cues of triggered frames near the newest

    def on_trigger(sample) -> None:
        recv_ns = time.monotonic_ns()
        msg = rt.decoder.decode(sample.payload, Trigger)
        for item in window.accept(msg, (msg, recv_ns)) if msg is not None else ():
            inbox.put(item)

    def on_cues(sample) -> None:
        recv_ns = time.monotonic_ns()
        msg = rt.decoder.decode(sample.payload, Cues)
        for item in window.accept(msg, (msg, recv_ns)) if msg is not None else ():
            inbox.put(item)

    pose_pub = session.declare_publisher(keys.pose, express=True)
    pred_pubs = {c: session.declare_publisher(keys.prediction(c), express=True) for c in rig_cameras}
    rt.subscribe(keys.trigger, on_trigger, direct=True)
    rt.subscribe(keys.cues(), on_cues, direct=True)
    rt.publish_status("running", force=True)
    gcs = IdleGC()
    gcs.start()
    try:
        while not rt.stop.is_set():
            now = time.monotonic_ns()
            nd = gather.next_deadline_ns()
            timeout = 0.1 if nd is None else min(0.1, max(0.0, (nd - now) / 1e9))
            try:
                msg = inbox.get(timeout=timeout)
            except queue.Empty:
                msg = None
            while msg is not None:
                msg, recv_ns = msg
                if isinstance(msg, Trigger):
                    gather.on_trigger(msg, recv_ns)
                else:
                    gather.on_cues(msg, recv_ns)
                try:
                    msg = inbox.get_nowait()
                except queue.Empty:
                    msg = None
            fused = 0
            for pf in gather.ready(time.monotonic_ns()):
                fuse_and_publish(tracker, keys, pf, rig_cameras, pred_pubs, pose_pub, rt,
                                 pose_first=gather.period_ns > 0)
                fused += 1
            if fused and not any(pf.cues for pf in gather.pending.values()):
                gcs.idle()           # published, and no answers for a later frame yet
            rt.drops = gather.frames_dropped + int(rt.extra.get("fusion_errors", 0))
            rt.extra["late_cues"] = gather.late_cues
            rt.extra.update(window.counters())
            rt.extra["cameras_live"] = len(gather.live(time.monotonic_ns()))
            rt.publish_status()
    finally:
        gcs.stop()
        rt.unsubscribe()


def _flags(p) -> None:
    p.add_argument("--deadline-frac", type=float,
                   help="wait for late cameras at most this fraction of the frame period (default %(default)s)")
    p.add_argument("--fps", type=float, help="frame rate of the frame ids (default rig metadata fps or 30)")
    p.add_argument("--bones", type=Path, metavar="TOML",
                   help="the subject's bone lengths ([bones] table); default: estimated from the "
                        "first seconds of cues")


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    return settings_parser(FusionSettings, __doc__.splitlines()[0], _flags)


def main(argv: list[str] | None = None) -> int:
    s = parse_settings(build_parser(), FusionSettings, argv)

    def prepare(rig, stack):
        from mocap_rt.body.skeleton import read_bone_lengths

        return read_bone_lengths(s.bones) if s.bones else None     # fails before joining

    def setup(rt: NodeRuntime, rig, bones):
        fps = s.fps or rig_fps(rig)
        log.info("fusion: warm-up took %.2f s", warm_up(rig, fps))
        return make_tracker(rig, fps, bones)

    def serve(rt: NodeRuntime, rig, tracker) -> None:
        run_fusion(rt.session, rt.keys, rig, tracker, rt, s.deadline_frac)

    return run_node("fusion", s, serve, prepare=prepare, setup=setup)


if __name__ == "__main__":
    sys.exit(main())
