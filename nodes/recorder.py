"""Recorder node: poses to BVH + NPZ + C3D + TRC, and (live sources) the raw multi-view stream.

Outputs in ``--out DIR``:

(a second recorder run in the same directory writes ``poses_001.*``, ``stream_001`` ...)

* ``poses.bvh`` — ``BvhStreamWriter`` on the skeleton of the poses (their ``bones``), flushed
  every second; when fusion has estimated the subject's bone lengths the file is given the
  new hierarchy (rewritten once, atomically) and ``bones.toml`` is written for later sessions
  (``mocap-rt run --bones``);
* ``poses.npz`` — every pose so far (see ``PoseLog``), rewritten atomically every
  ``SNAPSHOT_PERIOD_S`` (write to a temporary file, then rename);
* ``poses.c3d``, ``poses.trc`` — the joints as markers (``mocap_rt.io.exports``: C3D Z up,
  TRC Y up, millimetres), rewritten atomically like the NPZ, every ``EXPORT_MIN_PERIOD_S`` or
  ``EXPORT_COST_FACTOR`` times the last rewrite's duration if longer (long sessions), and at close;
* ``stream/`` — with ``--raw``: the cameras' raw images via ``RecordingWriter`` (the
  recorded-stream format, ~1 s video segments), so a live session can be replayed.

Crash safety: after SIGKILL every file opens and at most the last second is lost (BVH and
the stream by their writers' design, NPZ by the atomic snapshot; C3D/TRC hold every pose up
to their last rewrite, the NPZ has the rest).

    python -m nodes.recorder --rig RIG.toml --out DIR [--raw] [--fps 30]
"""

from __future__ import annotations

import logging
import queue
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap_rt.body.bvh_export import bvh_skeleton_of
from mocap_rt.body.skeleton import BoneLengths, write_bone_lengths
from mocap_rt.io.bvh_writer import BvhStreamWriter
from mocap_rt.io.files import atomic_write
from nodes.frame_window import RECORD_AHEAD, RECORD_BEHIND, FrameWindow
from nodes.messages import Background, Frame, Keys, Pose, Trigger
from nodes.node import NodeSettings, parse_settings, rig_fps, run_node, settings_parser
from nodes.runtime import NodeRuntime

log = logging.getLogger(__name__)

SNAPSHOT_PERIOD_S = 1.0        # NPZ snapshot period: the most a crash can lose
RAW_GATHER_S = 1.0             # wait this long for every camera's image of a frame
STREAM_DIR = "stream"
EXPORT_MIN_PERIOD_S = 1.0      # C3D/TRC rewrite period (short sessions)
EXPORT_COST_FACTOR = 20.0      # ... at least this times the last rewrite's duration (<= 5 % CPU)


@dataclass(frozen=True)
class RecorderSettings(NodeSettings):
    """out : the output directory (required); fps : frame rate of the BVH and the stream (None:
    the rig's); raw : also record the raw multi-view stream (live sources)."""

    node: str = "recorder"
    out: Path | None = None
    fps: float | None = None
    raw: bool = False


class PoseLog:
    """Poses accumulated in memory and snapshotted to ``poses.npz`` atomically.

    Arrays (F frames): ``frames`` (F,) int64; ``joints`` (F, 20, 3) float64 metres, world;
    ``cues_3d`` (F, 6, 3); ``cue_valid`` (F, 6) bool; ``cameras_used`` (F, C) bool in
    ``camera_names`` order; ``latency_ms`` (F,) trigger -> pose published (same host);
    ``bvh_motion`` (F, n_channels); plus ``joint_names``, ``cue_names``, ``camera_names``.
    """

    def __init__(self, path: Path, camera_names: list[str]) -> None:
        self.path = Path(path)
        self.camera_names = list(camera_names)
        self._rows: dict[str, list] = {k: [] for k in
                                       ("frames", "joints", "cues_3d", "cue_valid", "cameras_used",
                                        "latency_ms", "bvh_motion")}
        self._dirty = False

    def __len__(self) -> int:
        return len(self._rows["frames"])

    def add(self, pose: Pose) -> None:
        r = self._rows
        r["frames"].append(pose.frame)
        r["joints"].append(pose.joints)
        r["cues_3d"].append(pose.cues_3d)
        r["cue_valid"].append(pose.cue_valid)
        r["cameras_used"].append([c in pose.cameras_used for c in self.camera_names])
        r["latency_ms"].append((pose.t_pub_mono_ns - pose.t_trigger_mono_ns) / 1e6)
        r["bvh_motion"].append(pose.bvh_frame)
        self._dirty = True

    def arrays(self) -> dict[str, np.ndarray]:
        from mocap_rt.names import CUE_NAMES, JOINT_NAMES

        r = self._rows
        n_ch = len(r["bvh_motion"][0]) if r["bvh_motion"] else 0
        return {"frames": np.asarray(r["frames"], np.int64),
                "joints": np.asarray(r["joints"], np.float64).reshape(-1, len(JOINT_NAMES), 3),
                "cues_3d": np.asarray(r["cues_3d"], np.float64).reshape(-1, len(CUE_NAMES), 3),
                "cue_valid": np.asarray(r["cue_valid"], bool).reshape(-1, len(CUE_NAMES)),
                "cameras_used": np.asarray(r["cameras_used"], bool).reshape(-1, len(self.camera_names)),
                "latency_ms": np.asarray(r["latency_ms"], np.float64),
                "bvh_motion": np.asarray(r["bvh_motion"], np.float64).reshape(-1, n_ch),
                "joint_names": np.asarray(JOINT_NAMES), "cue_names": np.asarray(CUE_NAMES),
                "camera_names": np.asarray(self.camera_names)}

    def snapshot(self) -> None:
        """Write ``poses.npz`` atomically (tmp file + fsync + rename)."""
        if not self._dirty:
            return
        with atomic_write(self.path, "wb") as fh:
            np.savez(fh, **self.arrays())
        self._dirty = False


class RawStream:
    """Assembles per-camera ``Frame`` messages into synchronised rows of a RecordingWriter.

    A frame is written once every camera's image arrived, or after ``RAW_GATHER_S`` with
    black images (timestamp NaN) for the cameras that did not send one.
    """

    def __init__(self, path: Path, rig, fps: float) -> None:
        from mocap_rt.io.recording import RecordingWriter

        self.rig = rig
        self.writer = RecordingWriter(path, rig, fps, source="live")
        self.pending: dict[int, dict[str, Frame]] = {}
        self.first_seen: dict[int, float] = {}
        self.last_written = -1
        self.backgrounds_done: set[str] = set()
        self.frames_written = 0
        self.frames_incomplete = 0
        self.late = 0

    def on_background(self, msg: Background) -> None:
        if msg.camera in self.backgrounds_done or msg.camera not in self.rig.names:
            return
        self.writer.write_backgrounds(msg.camera, msg.images)
        self.backgrounds_done.add(msg.camera)

    def on_frame(self, msg: Frame, now: float) -> None:
        if msg.frame <= self.last_written:
            self.late += 1
            return
        self.pending.setdefault(msg.frame, {})[msg.camera] = msg
        self.first_seen.setdefault(msg.frame, now)

    def flush_ready(self, now: float, force: bool = False) -> None:
        names = list(self.rig.names)
        for f in sorted(self.pending):
            got = self.pending[f]
            if not (force or len(got) == len(names) or now - self.first_seen[f] > RAW_GATHER_S):
                break
            images, stamps = [], []
            for cam in self.rig.cameras:
                m = got.get(cam.name)
                ok = m is not None and m.image.shape == (cam.height, cam.width, 3)
                images.append(m.image if ok else np.zeros((cam.height, cam.width, 3), np.uint8))
                stamps.append(m.t_grab_wall_ns / 1e9 if ok else float("nan"))
            self.frames_incomplete += len(got) < len(names)
            try:
                self.writer.write_frame(f, images, stamps)
                self.frames_written += 1
            except ValueError as exc:      # a bad frame must not end the recording
                log.warning("recorder: stream frame %d not written: %s", f, exc)
            self.last_written = f
            del self.pending[f], self.first_seen[f]

    def close(self) -> None:
        self.flush_ready(time.monotonic(), force=True)
        self.writer.close()


def output_paths(out_dir: Path) -> tuple[Path, Path, Path, Path]:
    """(poses.npz, poses.bvh, bones.toml, stream/) in ``out_dir``; when a previous run (or a
    recorder that crashed and was restarted) left files there, new names ``poses_001.npz``
    ... are used so that nothing already recorded is ever overwritten."""
    for i in range(10_000):
        sfx = "" if i == 0 else f"_{i:03d}"
        paths = (out_dir / f"poses{sfx}.npz", out_dir / f"poses{sfx}.bvh", out_dir / f"bones{sfx}.toml",
                 out_dir / f"{STREAM_DIR}{sfx}")
        exports = (out_dir / f"poses{sfx}.c3d", out_dir / f"poses{sfx}.trc")
        if not any(p.exists() for p in paths + exports):
            return paths
    raise FileExistsError(f"{out_dir}: too many recordings already")


class PoseFiles:
    """The pose outputs of one recording: NPZ log, streamed BVH, bones TOML, C3D and TRC."""

    def __init__(self, npz_path: Path, bvh_path: Path, bones_path: Path, camera_names: list[str],
                 fps: float) -> None:
        self.log = PoseLog(npz_path, camera_names)
        self.bvh_path, self.bones_path, self.fps = bvh_path, bones_path, fps
        self.bvh = None                  # opened on the first pose, with its skeleton
        self._bones: np.ndarray | None = None
        self.last_frame = -1
        self.export_stem = Path(npz_path).with_suffix("")       # .../poses_001 -> .c3d, .trc
        self._exported = 0                                      # poses in the exports
        self._export_due = 0.0

    def add(self, pose: Pose) -> None:
        """Record one pose; ValueError (nothing written) for an old frame or bad values."""
        if pose.frame <= self.last_frame:
            raise ValueError(f"pose {pose.frame} is not newer than {self.last_frame}")
        if self._bones is None or not np.array_equal(pose.bones, self._bones):
            lengths = BoneLengths.from_array(pose.bones)
            skeleton = bvh_skeleton_of(lengths)
            if len(pose.bvh_frame) != skeleton.n_channels:
                raise ValueError(f"pose {pose.frame}: {len(pose.bvh_frame)} BVH values, "
                                 f"the skeleton has {skeleton.n_channels}")
            if self.bvh is None:
                self.bvh = BvhStreamWriter(self.bvh_path, skeleton, 1.0 / self.fps)
            else:
                self.bvh.set_skeleton(skeleton)
            write_bone_lengths(lengths, self.bones_path)
            self._bones = np.array(pose.bones)
        self.bvh.write(pose.bvh_frame)
        self.log.add(pose)
        self.last_frame = pose.frame

    def write_exports(self) -> float:
        """Rewrite ``poses.c3d`` / ``poses.trc`` with every pose so far (atomically);
        returns the seconds it took (0 when nothing new)."""
        from mocap_rt.io.exports import write_pose_exports

        if len(self.log) == self._exported:
            return 0.0
        t0 = time.perf_counter()
        a = self.log.arrays()
        write_pose_exports(self.export_stem, a["frames"], a["joints"], self.fps)
        self._exported = len(a["frames"])
        return time.perf_counter() - t0

    def snapshot(self, now: float) -> None:
        """The NPZ snapshot, and the C3D/TRC rewrite when it is due (monotonic ``now``, s)."""
        self.log.snapshot()
        if now >= self._export_due:
            took = self.write_exports()
            self._export_due = now + max(EXPORT_MIN_PERIOD_S, EXPORT_COST_FACTOR * took)

    def close(self) -> None:
        self.log.snapshot()
        self.write_exports()
        if self.bvh is not None:
            self.bvh.close()


def run_recorder(session, keys: Keys, rig, out_dir: Path, fps: float, raw: bool, rt: NodeRuntime) -> None:
    """Record until ``rt.stop``; every file is closed cleanly on the way out."""
    out_dir.mkdir(parents=True, exist_ok=True)
    npz_path, bvh_path, bones_path, stream_path = output_paths(out_dir)
    poses = PoseFiles(npz_path, bvh_path, bones_path, list(rig.names), fps)
    stream = RawStream(stream_path, rig, fps) if raw else None
    log.info("recorder: writing %s, %s%s", npz_path, bvh_path, f", {stream_path}" if raw else "")
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    window = FrameWindow(keys.rig, rt.node, RECORD_BEHIND, RECORD_AHEAD)   # every pose of a triggered frame, even late

    def subscriber(msg_type):
        def on_sample(sample) -> None:
            msg = rt.decoder.decode(sample.payload, msg_type)
            for item in window.accept(msg) if msg is not None else ():
                inbox.put(item)
        return on_sample

    def handle(msg) -> None:
        if isinstance(msg, Pose):
            t0 = time.perf_counter()
            try:
                poses.add(msg)
            except ValueError as exc:
                rt.drops += 1
                log.warning("recorder: pose not written: %s", exc)
            rt.meter.add((time.perf_counter() - t0) * 1e3)
        elif isinstance(msg, Frame) and stream is not None:
            stream.on_frame(msg, time.monotonic())
        elif isinstance(msg, Background) and stream is not None:
            stream.on_background(msg)

    rt.subscribe(keys.pose, subscriber(Pose))
    rt.subscribe(keys.trigger, subscriber(Trigger))
    if raw:
        rt.subscribe(keys.frame(), subscriber(Frame))
        rt.subscribe(keys.background(), subscriber(Background))
    rt.publish_status("running", force=True)
    last_snap = time.monotonic()
    try:
        while not rt.stop.is_set():
            try:
                handle(inbox.get(timeout=0.1))
            except queue.Empty:
                pass
            now = time.monotonic()
            if stream is not None:
                stream.flush_ready(now)
                rt.extra["raw_frames"] = stream.frames_written
            if now - last_snap >= SNAPSHOT_PERIOD_S:
                poses.snapshot(now)
                last_snap = now
            rt.extra["poses"] = len(poses.log)
            rt.extra.update(window.counters())
            rt.publish_status()
    finally:
        rt.unsubscribe()
        while True:     # what already arrived is still written
            try:
                handle(inbox.get_nowait())
            except queue.Empty:
                break
        poses.close()
        if stream is not None:
            stream.close()
        log.info("recorder: %d poses written to %s", len(poses.log), out_dir)


def _flags(p) -> None:
    p.add_argument("--out", type=Path, help="output directory (required)")
    p.add_argument("--fps", type=float, help="frame rate for BVH/stream (default rig metadata or 30)")
    p.add_argument("--raw", action="store_true", help="also record the raw multi-view stream (live sources)")


def build_parser():
    """The node's command line (also checked against the deploy units in the tests)."""
    return settings_parser(RecorderSettings, __doc__.splitlines()[0], _flags)


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    s = parse_settings(p, RecorderSettings, argv)
    if s.out is None:
        p.error("--out is required (flag or --config)")

    def serve(rt: NodeRuntime, rig, _) -> None:
        run_recorder(rt.session, rt.keys, rig, s.out, s.fps or rig_fps(rig), s.raw, rt)

    return run_node("recorder", s, serve)


if __name__ == "__main__":
    sys.exit(main())
