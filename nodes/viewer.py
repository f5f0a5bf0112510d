"""Viewer node: the service in Rerun — skeleton, cue points, camera frusta, images, latency.

Entity layout (world: right-handed, Z up, metres)::

    world/cameras/<cam>              Transform3D (camera -> world) + Pinhole (OpenCV RDF)
    world/cameras/<cam>/image        the camera's JPEG preview (every ``--preview-every``)
    world/cameras/<cam>/image/cues   2D cue points + 2-sigma ellipses of the blobs, of the
                                     image's own frame (logged together with the image)
    world/skeleton                   3D bones (line strips) and joints
    world/cues                       triangulated cue points
    plots/latency_ms                 trigger -> pose published, per frame
    plots/cameras_used               number of cameras fused per frame
    viewer                           text: what the viewer shows and what it left out

The viewer works on what the frame path leaves (the launcher runs it niced): it shows the
images the workers send (one per ``--preview-every`` frames), drops the oldest items when it
falls behind, and says so in its log, its status (``extra``) and the ``viewer`` text entity.

Where the stream goes (``--rerun``) is ``nodes/rerun_sink.py``. Visualisation never stops the
service: a logging error is a warning, and when the viewer falls behind, old items are dropped.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from nodes.frame_window import FrameWindow
from nodes.messages import Cues, Keys, Pose, Preview, Trigger
from nodes.node import NodeSettings, parse_settings, run_node, settings_parser
from nodes.rerun_sink import parse_rerun, start_sink, web_viewer_url  # noqa: F401  (web_viewer_url: API)
from nodes.runtime import NodeRuntime

log = logging.getLogger(__name__)

QUEUE_MAX = 256                 # items waiting to be logged; beyond that the oldest are dropped
DRAIN_S = 3.0                   # at stop: log what is still queued for at most this long
PAIR_FRAMES_KEPT = 32           # cues / images waiting for their partner, per camera
REPORT_PERIOD_S = 10.0          # how often the viewer writes what it did into the recording
ELLIPSE_SIGMA = 2.0             # cue ellipses drawn at 2 standard deviations
ELLIPSE_POINTS = 24
CUE_COLOURS = np.array([[255, 220, 0], [255, 60, 60], [60, 160, 255], [255, 120, 0], [0, 200, 255],
                        [160, 255, 80]], np.uint8)   # head, hand_l, hand_r, foot_l, foot_r, torso
# bones of the 20-joint body (mocap_rt.names.JOINT_NAMES), as chains
BONE_CHAINS = (("pelvis", "torso", "neck", "head"),
               ("neck", "shoulder_l", "elbow_l", "wrist_l", "hand_l"),
               ("neck", "shoulder_r", "elbow_r", "wrist_r", "hand_r"),
               ("pelvis", "hip_l", "knee_l", "ankle_l", "foot_l"),
               ("pelvis", "hip_r", "knee_r", "ankle_r", "foot_r"))


@dataclass(frozen=True)
class ViewerSettings(NodeSettings):
    """rerun : save:FILE.rrd | serve[:WEB_PORT[:GRPC_PORT]] | spawn | connect:URL (required);
    preview_every : the workers send an image every N frames (0 = unknown: every frame's cues)."""

    node: str = "viewer"
    rerun: str = ""
    preview_every: int = 0


def ellipse_points(center: np.ndarray, cov: np.ndarray, sigma: float = ELLIPSE_SIGMA,
                   n: int = ELLIPSE_POINTS) -> np.ndarray:
    """(n+1, 2) closed polyline of the ``sigma`` ellipse of a 2D covariance (pixels)."""
    w, v = np.linalg.eigh(cov)
    w = np.sqrt(np.clip(w, 0.0, None)) * sigma
    t = np.linspace(0, 2 * np.pi, n + 1)
    circle = np.stack([np.cos(t) * w[0], np.sin(t) * w[1]], axis=1)     # (n+1, 2)
    return center + circle @ v.T


def skeleton_strips(joints: np.ndarray) -> list[np.ndarray]:
    """Bone chains as (k, 3) polylines; chains with a non-finite joint are cut there."""
    from mocap_rt.names import JOINT_NAMES

    out = []
    for chain in BONE_CHAINS:
        pts = joints[[JOINT_NAMES.index(j) for j in chain]]
        ok = np.isfinite(pts).all(axis=1)
        if ok.all():
            out.append(pts)
    return out


class SameFrame:
    """Pairs each camera's preview image with the cues of the same frame, so a camera panel
    never shows ellipses over an image of another frame.

    ``add_cues`` / ``add_preview`` return the (cues, preview) pair once both halves of a
    frame are there; a camera that never sent an image gets its cues back at once (no image
    to disagree with). Unpaired halves older than ``PAIR_FRAMES_KEPT`` frames are forgotten.
    """

    def __init__(self, keep: int = PAIR_FRAMES_KEPT) -> None:
        self.keep = keep
        self._cues: dict[str, dict[int, Cues]] = {}
        self._images: dict[str, dict[int, Preview]] = {}

    def _store(self, table: dict, camera: str, frame: int, msg) -> None:
        d = table.setdefault(camera, {})
        d[frame] = msg
        for f in [f for f in d if f <= frame - self.keep]:
            del d[f]

    def add_cues(self, msg: Cues) -> tuple[Cues, Preview | None] | None:
        cam, frame = msg.cues.camera, msg.cues.frame
        if cam not in self._images:
            return msg, None
        img = self._images[cam].pop(frame, None)
        if img is None:
            self._store(self._cues, cam, frame, msg)
            return None
        return msg, img

    def add_preview(self, msg: Preview) -> tuple[Cues, Preview] | None:
        self._images.setdefault(msg.camera, {})
        cues = self._cues.get(msg.camera, {}).pop(msg.frame, None)
        if cues is None:
            self._store(self._images, msg.camera, msg.frame, msg)
            return None
        return cues, msg


class RerunLogger:
    """Logs the service's messages to the global Rerun recording."""

    def __init__(self, rig) -> None:
        import rerun as rr

        self.rr = rr
        self.rig = rig

    def blueprint(self):
        """3D view + latency plots on the left, one 2D view per camera on the right."""
        import rerun.blueprint as rrb

        cams = [rrb.Spatial2DView(origin=f"world/cameras/{c}", name=c) for c in self.rig.names]
        return rrb.Blueprint(rrb.Horizontal(
            rrb.Vertical(rrb.Spatial3DView(origin="world", name="3D"),
                         rrb.Horizontal(rrb.TimeSeriesView(origin="plots/latency_ms", name="latency ms"),
                                        rrb.TimeSeriesView(origin="plots/cameras_used", name="cameras used")),
                         row_shares=[3, 1]),
            rrb.Grid(*cams, grid_columns=2), column_shares=[3, 2]), collapse_panels=True)

    def log_static(self) -> None:
        rr = self.rr
        try:
            rr.send_blueprint(self.blueprint())
        except Exception as exc:  # layout is a nicety; never fatal
            log.warning("viewer: blueprint not sent: %s", exc)
        rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for cam in self.rig.cameras:
            base = f"world/cameras/{cam.name}"
            rr.log(base, rr.Transform3D(translation=cam.center, mat3x3=np.asarray(cam.R).T), static=True)
            rr.log(base, rr.Pinhole(image_from_camera=np.asarray(cam.K), resolution=[cam.width, cam.height],
                                    camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.4), static=True)
        ground = [np.array([[x, -3, 0], [x, 3, 0]]) for x in range(-3, 4)] + \
                 [np.array([[-3, y, 0], [3, y, 0]]) for y in range(-3, 4)]
        rr.log("world/ground", rr.LineStrips3D(ground, colors=[[90, 90, 90]], radii=0.004), static=True)

    def log_pose(self, pose: Pose) -> None:
        rr = self.rr
        rr.set_time("frame", sequence=pose.frame)
        strips = skeleton_strips(pose.joints)
        rr.log("world/skeleton", rr.LineStrips3D(strips, radii=0.015, colors=[[230, 230, 230]]))
        ok = np.isfinite(pose.joints).all(axis=1)
        rr.log("world/skeleton/joints", rr.Points3D(pose.joints[ok], radii=0.025, colors=[[200, 200, 255]]))
        v = np.asarray(pose.cue_valid, bool) & np.isfinite(pose.cues_3d).all(axis=1)
        rr.log("world/cues", rr.Points3D(pose.cues_3d[v], radii=0.05, colors=CUE_COLOURS[v]))
        rr.log("plots/latency_ms", rr.Scalars((pose.t_pub_mono_ns - pose.t_trigger_mono_ns) / 1e6))
        rr.log("plots/cameras_used", rr.Scalars(float(len(pose.cameras_used))))

    def log_cues(self, msg: Cues) -> None:
        rr = self.rr
        c = msg.cues
        rr.set_time("frame", sequence=c.frame)
        found = c.found
        path = f"world/cameras/{c.camera}/image/cues"
        rr.log(path, rr.Points2D(c.xy[found], colors=CUE_COLOURS[found], radii=4.0))
        strips = [ellipse_points(c.xy[i], c.cov[i]) for i in np.flatnonzero(found)
                  if np.isfinite(c.cov[i]).all()]
        rr.log(f"{path}/ellipses", rr.LineStrips2D(strips, colors=CUE_COLOURS[found][:len(strips)], radii=1.5))

    def log_preview(self, msg: Preview) -> None:
        rr = self.rr
        rr.set_time("frame", sequence=msg.frame)
        rr.log(f"world/cameras/{msg.camera}/image", rr.EncodedImage(contents=msg.jpeg, media_type="image/jpeg"))

    def log_pair(self, pair: tuple[Cues, Preview | None]) -> None:
        """A camera's cues, and its image of the same frame if there is one."""
        cues, image = pair
        if image is not None:
            self.log_preview(image)
        self.log_cues(cues)

    def log_note(self, text: str) -> None:
        """A line of text in the recording (entity ``viewer``), at the current time."""
        self.rr.log("viewer", self.rr.TextLog(text))


class Inbox:
    """Items waiting to be logged, filled by Zenoh's threads: at most ``maxlen``; when full,
    ``put`` drops the oldest for the newest (and says so)."""

    def __init__(self, maxlen: int) -> None:
        self._items: deque = deque(maxlen=maxlen)
        self._cond = threading.Condition()

    def put(self, item) -> bool:
        """Queue ``item``; True if the oldest item was dropped to make room."""
        with self._cond:
            full = len(self._items) == self._items.maxlen
            self._items.append(item)
            self._cond.notify()
            return full

    def get(self, timeout_s: float):
        """The oldest item, waiting up to ``timeout_s``; None if there is none."""
        with self._cond:
            if not self._items and timeout_s > 0:
                self._cond.wait(timeout_s)
            return self._items.popleft() if self._items else None


class ViewerReport:
    """What the viewer shows and what it leaves out, in its log, its status and the recording
    (``viewer`` text entity): images per second, image size, items dropped, niceness."""

    def __init__(self, logger: RerunLogger, rt: NodeRuntime) -> None:
        self.logger, self.rt = logger, rt
        self.t0 = time.monotonic()
        self.t_last = self.t0
        self.poses = self.images = self.image_bytes = 0
        self.size = ""

    def pose(self, pose: Pose) -> None:
        self.poses += 1
        if time.monotonic() - self.t_last >= REPORT_PERIOD_S:
            self.write()

    def item(self, msg, pair) -> None:
        if isinstance(msg, Preview):
            self.images += 1
            self.image_bytes += len(msg.jpeg)
            if not self.size:
                self.size = _jpeg_size(msg.jpeg)

    def write(self, final: bool = False) -> None:
        now = time.monotonic()
        self.t_last = now
        dt = max(now - self.t0, 1e-3)
        text = (f"viewer{' (end)' if final else ''}: {self.poses} poses, {self.images} camera images "
                f"({self.images / dt:.1f}/s over all cameras, {self.size or 'no images'} JPEG, "
                f"{self.image_bytes / max(self.images, 1) / 1e3:.0f} kB each); {self.rt.drops} items dropped "
                f"because the viewer fell behind; niceness {os.getpriority(os.PRIO_PROCESS, 0)} "
                f"(the frame path comes first: real-time scheduling above the viewer, or this niceness); "
                f"each camera image is shown with the cues of its own frame")
        self.rt.extra.update(images_per_s=round(self.images / dt, 2), viewer_dropped=self.rt.drops)
        log.info("%s", text)
        try:
            self.logger.log_note(text)
        except Exception as exc:  # a note is a nicety
            log.warning("viewer: note not logged: %s", exc)


def _jpeg_size(jpeg: bytes) -> str:
    """'WxH' of a JPEG from its SOF marker ('' if not found)."""
    i = 2
    while i + 9 < len(jpeg):
        if jpeg[i] != 0xFF:
            return ""
        marker, length = jpeg[i + 1], int.from_bytes(jpeg[i + 2:i + 4], "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h, w = int.from_bytes(jpeg[i + 5:i + 7], "big"), int.from_bytes(jpeg[i + 7:i + 9], "big")
            return f"{w}x{h}"
        i += 2 + length
    return ""


def run_viewer(session, keys: Keys, rig, rt: NodeRuntime, preview_every: int = 0) -> None:
    """Log everything that arrives until ``rt.stop`` (off the Zenoh threads). With
    ``preview_every`` N > 0 (the workers' image rate), cues of frames without an image are
    not queued: a camera panel only draws the cues of its image's frame."""
    import rerun as rr

    logger = RerunLogger(rig)
    logger.log_static()
    inbox = Inbox(QUEUE_MAX)

    def enqueue(item) -> None:
        if inbox.put(item):      # behind: the oldest item was dropped for the newest
            rt.drops += 1

    window = FrameWindow(keys.rig, rt.node)     # only poses and cues of triggered frames

    def handler(cls):
        def cb(sample) -> None:
            msg = rt.decoder.decode(sample.payload, cls)
            for item in window.accept(msg) if msg is not None else ():
                if isinstance(item, Trigger) or (preview_every > 0 and isinstance(item, Cues)
                                                 and item.cues.frame % preview_every):
                    continue
                enqueue(item)
        return cb

    for key, cls in ((keys.trigger, Trigger), (keys.pose, Pose), (keys.cues(), Cues), (keys.preview(), Preview)):
        rt.subscribe(key, handler(cls))
    rt.publish_status("running", force=True)
    report = ViewerReport(logger, rt)
    pairs = SameFrame()
    n = 0
    t_drain = None
    try:
        while True:
            if rt.stop.is_set() and t_drain is None:      # stopping: log what is queued, briefly
                t_drain = time.monotonic() + DRAIN_S
            if t_drain is not None and time.monotonic() > t_drain:
                break
            msg = inbox.get(timeout_s=0.2 if t_drain is None else 0.0)
            if msg is None:
                if t_drain is not None:
                    break
                rt.extra.update(window.counters())
                rt.publish_status()
                continue
            t0 = time.perf_counter()
            try:
                if isinstance(msg, Pose):
                    logger.log_pose(msg)
                    rt.meter.add((time.perf_counter() - t0) * 1e3)
                    report.pose(msg)
                else:
                    pair = pairs.add_cues(msg) if isinstance(msg, Cues) else pairs.add_preview(msg)
                    report.item(msg, pair)
                    if pair is not None:
                        logger.log_pair(pair)
            except Exception as exc:  # visualisation must never stop the service
                n += 1
                if n <= 5:
                    log.warning("viewer: could not log %s: %s", type(msg).__name__, exc)
            rt.extra.update(window.counters())
            rt.publish_status()
        report.write(final=True)
    finally:
        rt.unsubscribe()
        try:
            rr.get_global_data_recording().flush()
        except Exception as exc:
            log.warning("viewer: flush failed: %s", exc)


def _flags(p) -> None:
    p.add_argument("--rerun", help="save:FILE.rrd | serve[:WEB_PORT[:GRPC_PORT]] | spawn | connect:URL (required)")
    p.add_argument("--preview-every", type=int,
                   help="the workers send an image every N frames: only those frames' cues are drawn "
                        "(0 = unknown: every frame's)")


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    return settings_parser(ViewerSettings, __doc__.splitlines()[0], _flags)


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    s = parse_settings(p, ViewerSettings, argv)
    if not s.rerun:
        p.error("--rerun is required (flag or --config)")

    def prepare(rig, stack) -> None:
        web = start_sink(s.rerun)
        if web is not None:        # no rr.disconnect(): it can block ~10 s on a served stream; run_viewer flushed
            stack.callback(web.wait, timeout=5)
            stack.callback(web.terminate)

    return run_node("viewer", s, lambda rt, rig, _: run_viewer(rt.session, rt.keys, rig, rt, s.preview_every),
                    prepare=prepare)


if __name__ == "__main__":
    sys.exit(main())
