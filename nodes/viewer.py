"""Viewer node: the service in Rerun — skeleton, cue points, camera frusta, images, latency.

Entity layout (world: right-handed, Z up, metres)::

    world/cameras/<cam>              Transform3D (camera -> world) + Pinhole (OpenCV RDF)
    world/cameras/<cam>/image        the camera's JPEG preview (every ``--preview-every``)
    world/cameras/<cam>/image/cues   2D cue points + 2-sigma ellipses of the blobs
    world/skeleton                   3D bones (line strips) and joints
    world/cues                       triangulated cue points
    plots/latency_ms                 trigger -> pose published, per frame
    plots/cameras_used               number of cameras fused per frame

``--rerun save:FILE.rrd`` writes a file; ``serve[:WEB_PORT[:GRPC_PORT]]`` keeps a gRPC
server bound to 127.0.0.1 and hosts the web viewer on 127.0.0.1 (``rerun --serve-web
--bind 127.0.0.1``); ``spawn`` starts the native viewer (needs a display);
``connect:URL`` streams to a running viewer. Visualisation never stops the service: a
logging error is a warning, and when the viewer falls behind, old items are dropped.
"""

from __future__ import annotations

import logging
import os
import queue
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from nodes.frame_window import FrameWindow
from nodes.messages import Cues, Keys, Pose, Preview, Trigger
from nodes.runtime import NodeRuntime, base_parser, load_rig, node_session, setup_logging

log = logging.getLogger(__name__)

DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
QUEUE_MAX = 256                 # items waiting to be logged; beyond that the oldest are dropped
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


def parse_rerun(spec: str) -> tuple[str, list[str]]:
    """``"save:x.rrd"`` -> ``("save", ["x.rrd"])``; ``"serve:9090:9876"`` -> ports."""
    mode, _, rest = str(spec).partition(":")
    if mode == "save" and rest:
        return mode, [rest]
    if mode == "serve":
        ports = [p for p in rest.split(":") if p] if rest else []
        if len(ports) > 2 or not all(p.isdigit() for p in ports):
            raise ValueError(f"--rerun {spec!r}: expected serve[:WEB_PORT[:GRPC_PORT]]")
        return mode, ports
    if mode == "spawn" and not rest:
        return mode, []
    if mode == "connect" and rest:
        return mode, [rest]
    raise ValueError(f"--rerun {spec!r}: expected save:FILE.rrd | serve[:WEB[:GRPC]] | spawn | connect:URL")


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


def start_sink(spec: str, app_id: str = "mocap_rt") -> subprocess.Popen | None:
    """Initialise Rerun for ``--rerun spec``; returns the web-viewer process for ``serve``."""
    import rerun as rr

    mode, args = parse_rerun(spec)
    rr.init(app_id, spawn=False)
    if mode == "save":
        Path(args[0]).parent.mkdir(parents=True, exist_ok=True)
        rr.save(args[0])
        return None
    if mode == "connect":
        rr.connect_grpc(args[0])
        return None
    if mode == "spawn":
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise ValueError("--rerun spawn needs a display (DISPLAY/WAYLAND_DISPLAY unset); "
                             "use --rerun save:FILE.rrd or serve")
        rr.spawn()
        return None
    web = int(args[0]) if args else DEFAULT_WEB_PORT
    grpc = int(args[1]) if len(args) > 1 else DEFAULT_GRPC_PORT
    rr.set_sinks(rr.GrpcServerSink(bind_ip="127.0.0.1", port=grpc))
    url = f"rerun+http://127.0.0.1:{grpc}/proxy"
    exe = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if exe is None:
        raise FileNotFoundError("the 'rerun' executable (from rerun-sdk) is needed to host the web viewer")
    proc = subprocess.Popen([exe, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web), url],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    log.info("viewer: open %s", web_viewer_url(web, grpc))
    return proc


def web_viewer_url(web_port: int, grpc_port: int) -> str:
    from urllib.parse import quote

    return f"http://127.0.0.1:{web_port}/?url={quote(f'rerun+http://127.0.0.1:{grpc_port}/proxy', safe='')}"


def run_viewer(session, keys: Keys, rig, rt: NodeRuntime) -> None:
    """Log everything that arrives until ``rt.stop`` (off the Zenoh threads)."""
    import rerun as rr

    logger = RerunLogger(rig)
    logger.log_static()
    inbox: queue.Queue = queue.Queue(maxsize=QUEUE_MAX)

    def enqueue(item) -> None:
        try:
            inbox.put_nowait(item)
        except queue.Full:       # behind: drop the oldest, keep the newest
            try:
                inbox.get_nowait()
            except queue.Empty:
                pass
            rt.drops += 1
            inbox.put_nowait(item)

    window = FrameWindow(keys.rig, rt.node)     # only poses and cues of triggered frames

    def handler(cls):
        def cb(sample) -> None:
            msg = rt.decoder.decode(sample.payload, cls)
            for item in window.accept(msg) if msg is not None else ():
                if not isinstance(item, Trigger):
                    enqueue(item)
        return cb

    subs = [session.declare_subscriber(keys.trigger, handler(Trigger)),
            session.declare_subscriber(keys.pose, handler(Pose)),
            session.declare_subscriber(keys.cues(), handler(Cues)),
            session.declare_subscriber(keys.preview(), handler(Preview))]
    rt.publish_status("running", force=True)
    n = 0
    try:
        while not rt.stop.is_set():
            try:
                msg = inbox.get(timeout=0.2)
            except queue.Empty:
                rt.extra.update(window.counters())
                rt.publish_status()
                continue
            t0 = time.perf_counter()
            try:
                if isinstance(msg, Pose):
                    logger.log_pose(msg)
                    rt.meter.add((time.perf_counter() - t0) * 1e3)
                elif isinstance(msg, Cues):
                    logger.log_cues(msg)
                else:
                    logger.log_preview(msg)
            except Exception as exc:  # visualisation must never stop the service
                n += 1
                if n <= 5:
                    log.warning("viewer: could not log %s: %s", type(msg).__name__, exc)
            rt.extra.update(window.counters())
            rt.publish_status()
    finally:
        for s in subs:
            s.undeclare()
        try:
            rr.get_global_data_recording().flush()
        except Exception as exc:
            log.warning("viewer: flush failed: %s", exc)


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    p = base_parser(__doc__.splitlines()[0], "viewer")
    p.add_argument("--rerun", required=True, help="save:FILE.rrd | serve[:WEB_PORT[:GRPC_PORT]] | spawn | connect:URL")
    return p


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    parse_rerun(args.rerun)
    rig = load_rig(args)
    web = start_sink(args.rerun)
    try:
        with node_session(args, "viewer") as rt:
            rt.publish_status("ready", force=True)
            run_viewer(rt.session, rt.keys, rig, rt)
            rt.publish_status("stopping", force=True)
    finally:
        # no rr.disconnect(): it can block ~10 s on a served stream; run_viewer flushed
        if web is not None:
            web.terminate()
            web.wait(timeout=5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
