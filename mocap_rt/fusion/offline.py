"""Offline processing of a recorded multi-view stream, no transport (``mocap-rt process``).

Per frame: perception of every camera (``CameraPerceiver``, fed with the tracker's
prediction), then ``BodyTracker.step``. When the identity switches the labels, the frames
before it that its evidence came from (while the track acquires its identity: all of the
track's frames) are given the new labels too (``_relabel_back``: what the live service,
which has published them, cannot do). At the end, frames solved before the bone lengths
were estimated are re-solved with the final lengths, so the whole clip uses one skeleton, and
the poses are low-passed both ways (``fusion.smooth``, ``FusionConfig.offline_smooth_hz``).
Writes ``OUT_DIR/poses.bvh``, ``OUT_DIR/bones.toml`` (the bone lengths used,
given or estimated; reusable with ``--bones``), ``OUT_DIR/poses.c3d`` and ``OUT_DIR/poses.trc``
(the joints as markers, ``mocap_rt.io.exports``) and ``OUT_DIR/poses.npz``:

* ``joints`` (F, J, 3) float64 metres, world; NaN before the first full pose; smoothed
  (``FusionConfig.offline_smooth_hz``) like the BVH's poses;
* ``joint_names`` (J,) str (the truth's names), ``frames`` (F,) int;
* ``cues`` (F, 6, 3) the per-frame triangulated cues (NaN = not reconstructed),
  ``cue_names``, ``cue_valid`` (F, 6) bool, ``joint_valid`` (F, J) bool (False where a
  limb's cue was missing: the limb held or at rest), ``pan_rad`` (F,) (the tracker's heading
  per frame, not smoothed), ``bone_lengths`` (11,)
  and ``bone_length_names``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.evaluate import Accuracy, accuracy, align_truth, truth_camera_cues
from mocap_rt.fusion.identity import ALTERNATIVE_PAIRS, ALTERNATIVES
from mocap_rt.fusion.smooth import smooth_poses
from mocap_rt.fusion.tracker import BodyTracker, FusionResult
from mocap_rt.names import C_TORSO, CUE_NAMES, JOINT_NAMES, N_CUES

log = logging.getLogger(__name__)

RELABEL_BACK_FRAMES = 150   # how far back a switch of the labels is carried at most (frames)
PAIR_APART_M = 0.2          # two hands (feet) this far apart cannot exchange their tracks


@dataclass
class ProcessOutput:
    """What ``process_recording`` computed (arrays as in ``poses.npz``)."""

    frames: np.ndarray
    joints: np.ndarray
    cues: np.ndarray
    cue_valid: np.ndarray
    joint_valid: np.ndarray
    bvh_rows: np.ndarray
    pan_rad: np.ndarray
    timings_ms: dict = field(default_factory=dict)
    fusion_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))   # (F,) per frame
    camera_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, N_CUES, 2)))  # (C, F, 6, 2) 2D cues, px
    accuracy: Accuracy | None = None


def _resolve_early(tracker: BodyTracker, results: list[FusionResult], first_calibrated: int | None) -> None:
    """Re-solve frames before calibration with the final bone lengths (in place), with the
    limb swivels and silhouettes their fit had."""
    if tracker.config.bone_lengths is not None or not tracker.calibrated or first_calibrated is None:
        return
    stop = first_calibrated
    last = None
    for r in results[:stop]:
        if np.isfinite(r.cues_ik).all() and r.axes is not None:
            r.root_pos, r.angles, r.joints = tracker.published.solve(r.cues_ik, r.axes, r.swivel, r.targets)
            last = (r.root_pos, r.angles)
        if last is not None:
            r.bvh_frame = tracker.published.bvh_row(*last)


def _tracked_apart(results: list[FusionResult], pairs: tuple, end: int) -> int:
    """How many frames before index ``end`` (at most ``RELABEL_BACK_FRAMES``) every pair of
    ``pairs`` (cue index pairs) was measured and at least ``PAIR_APART_M`` apart: frames whose
    labels tracking alone carried (the filter cannot exchange two tracks that far apart)."""
    n = 0
    for r in reversed(results[max(0, end - RELABEL_BACK_FRAMES):end]):
        if not all(r.cue_valid[a] and r.cue_valid[b] and np.linalg.norm(r.cues_3d[a] - r.cues_3d[b]) >= PAIR_APART_M
                   for a, b in pairs):
            break
        n += 1
    return n


def _relabel_back(tracker: BodyTracker, results: list[FusionResult], switches: int,
                  previous: tuple[int, int] | None) -> tuple[int, int] | None:
    """When the frame just stepped switched the labels (``tracker.identity.switches`` passed
    ``switches``), the frames before it that carried the same labels get the new ones too (in
    place): while acquiring, or for feet that nothing had decided, the track's frames, else
    those the alternative won in a row (``IdentityState.last_switch``), and for the exchange of
    one pair further back, the frames tracking alone carried that pair to this one
    (``_tracked_apart``; not for the mirror, which after the acquisition is mostly wrong,
    docs/body.md). A mirror that follows a mirror
    (``previous``: the last switch's alternative and first frame carried back) undoes it: it
    reaches back as far as that one did. Never before the track, at most
    ``RELABEL_BACK_FRAMES``. The live service cannot: it has published them. Returns this
    switch's (alternative, first frame carried back), else ``previous``."""
    state = tracker.identity
    if state.switches == switches:
        return previous
    k, won = state.last_switch
    now = len(results) - 1
    mirror = ALTERNATIVES[k] == "mirror"
    back = max(won - 1, 0 if mirror else _tracked_apart(results, ALTERNATIVE_PAIRS[k], now))
    if mirror and previous is not None and previous[0] == k:
        back = max(back, now - previous[1])
    back = min(back, state.frames - 1, RELABEL_BACK_FRAMES, now)
    for j in range(now - back, now):
        results[j] = tracker.with_labels(results[j], k)
    return k, now - back


def _smooth(tracker: BodyTracker, results: list[FusionResult], cutoff_hz: float) -> None:
    """The poses of ``results`` low-passed both ways (``fusion.smooth``), in place: their root,
    angles, joints and BVH rows."""
    posed = np.array([np.isfinite(r.root_pos).all() for r in results], dtype=bool)
    solver = tracker.published
    root, angles, joints = smooth_poses(solver.pose_model, np.array([r.root_pos for r in results]),
                                        np.array([r.angles for r in results]), posed,
                                        np.array([r.joint_valid for r in results]), tracker.config.fps, cutoff_hz)
    for i in np.flatnonzero(posed):
        r = results[i]
        r.root_pos, r.angles, r.joints = root[i], angles[i], joints[i]
        r.bvh_frame = solver.bvh_row(root[i], angles[i])


def run_tracker(tracker: BodyTracker, frame_cues, n_frames: int, progress: bool = True) -> list[FusionResult]:
    """Step ``tracker`` over ``frame_cues(frame_index, predictions) -> (frame, cues)``."""
    from tqdm import tqdm

    results: list[FusionResult] = []
    first_cal = None
    predictions = None
    last_switch = None
    for i in tqdm(range(n_frames), disable=not progress, unit="frame", desc="process"):
        frame, cues = frame_cues(i, predictions)
        was = tracker.calibrated
        switches = tracker.identity.switches
        results.append(tracker.step(frame, cues))
        last_switch = _relabel_back(tracker, results, switches, last_switch)
        if tracker.calibrated and not was:
            first_cal = len(results)
        # the silhouettes (a few 100 KB a frame) are kept for the frames up to the bone lengths'
        # estimate, which ``_resolve_early`` solves again, and for the last RELABEL_BACK_FRAMES,
        # which a switch may relabel (``_relabel_back``)
        old = len(results) - 1 - RELABEL_BACK_FRAMES
        if first_cal is not None and old >= first_cal:
            results[old].targets = None
        predictions = tracker.predict(frame + 1)
    if first_cal is None and tracker.finish_calibration():  # a clip shorter than calibration_s
        first_cal = len(results)
    _resolve_early(tracker, results, first_cal)
    if tracker.config.offline_smooth_hz > 0:
        _smooth(tracker, results, tracker.config.offline_smooth_hz)
    for r in results:
        r.targets = None
    return results


def with_fused_torso(camera_xy: np.ndarray, cameras, joints: np.ndarray, joint_valid: np.ndarray) -> np.ndarray:
    """The cameras' 2D cues ``camera_xy`` (C, F, 6, 2) px with the torso's replaced by the fused
    body's torso point, the pelvis-neck midpoint of ``joints`` (F, J, 3) (the torso cue's
    definition, ``studio.body_shape``), projected into each of ``cameras`` (C); where a camera
    found no torso it stays NaN, and frames without a pose (``joint_valid`` (F, J) False for
    the pelvis or the neck) keep the measured one.

    Why (issue 12, item 4): the measured torso is the trunk's visible centre on the line from
    the head through the silhouette's ridge, lost (> 20 px from the truth's midpoint) for
    seconds where arms cover the trunk; the body fitted to all cameras' cues and silhouettes
    places it better: over the hard-case suite 4.6 / 16.4 px (median of the clips' medians /
    worst p95) against 7.0 / 49.1, 5 lost camera-frames against 555 (docs/perception.md, "The
    torso from the fused body")."""
    xy = np.array(camera_xy, dtype=np.float64, copy=True)
    if len(joints) == 0:
        return xy
    ip, ineck = JOINT_NAMES.index("pelvis"), JOINT_NAMES.index("neck")
    mid = 0.5 * (joints[:, ip] + joints[:, ineck])
    posed = joint_valid[:, ip] & joint_valid[:, ineck] & np.isfinite(mid).all(axis=1)
    for c, cam in enumerate(cameras):
        seen = posed & np.isfinite(xy[c, :, C_TORSO]).all(axis=1)
        if seen.any():
            xy[c, seen, C_TORSO] = cam.project(mid[seen])[0]
    return xy


def process_recording(rec_dir: str | Path, out_dir: str | Path, config: FusionConfig | None = None,
                      perception_config=None, max_frames: int | None = None, truth_2d: bool = False,
                      noise_px: float = 1.0, seed: int = 0, progress: bool = True) -> ProcessOutput:
    """Perception + fusion + IK over a recording; writes poses.bvh, .npz, .c3d, .trc, bones.toml.

    config : fusion settings (default: ``FusionConfig()``; ``fps`` becomes the recording's).
    perception_config : ``PerceptionConfig`` of every camera (default: its defaults); without a
        skin model path, the shipped one for the recording's source (``config_for_source``).
    truth_2d : skip perception and feed the truth's 2D cues (+ ``noise_px`` Gaussian
        noise), to measure fusion apart from perception (studio recordings only).
    """
    from mocap_rt.body.skeleton import write_bone_lengths
    from mocap_rt.io.bvh_writer import write_bvh
    from mocap_rt.io.exports import write_pose_exports
    from mocap_rt.io.files import atomic_write
    from mocap_rt.io.recording import Recording

    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames must be >= 1, got {max_frames}")
    rec = Recording(rec_dir)
    if rec.n_frames < 1:
        raise ValueError(f"{rec_dir}: the recording has no frames")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    config = replace(config or FusionConfig(), fps=float(rec.fps))
    if config.offline_smooth_hz >= config.fps / 2:      # refused before the work, not after it
        raise ValueError(f"{rec_dir}: the smoothing cutoff (offline_smooth_hz, --smooth-hz) {config.offline_smooth_hz:g} Hz "
                         f"must be below half the recording's frame rate ({config.fps / 2:g} Hz)")
    tracker = BodyTracker(rec.rig, config)
    names = list(rec.rig.names)
    n = rec.n_frames if max_frames is None else min(rec.n_frames, int(max_frames))
    frames_idx = np.asarray(rec.frames)[:n]
    truth = rec.truth
    t_perc: list[float] = []
    cam_xy: list[np.ndarray] = []                   # per frame (C, 6, 2): the cues fusion was given
    if truth_2d:
        if truth is None:
            raise ValueError(f"{rec_dir}: --truth-2d needs truth.npz (studio recordings only)")
        tidx = align_truth(truth, frames_idx)
        rng = np.random.default_rng(seed)

        widths = {c.name: int(c.size[0]) for c in rec.rig.cameras}

        def frame_cues(i, predictions):
            return int(frames_idx[i]), truth_camera_cues(truth, names, int(tidx[i]), int(frames_idx[i]), noise_px, rng,
                                                         widths)
    else:
        from mocap_rt.perception.pipeline import CameraPerceiver, PerceptionConfig, config_for_source

        pc = config_for_source(perception_config or PerceptionConfig(), rec.source)
        perceivers = {nm: CameraPerceiver(rec.rig[nm], rec.backgrounds(nm), pc) for nm in names}
        iters = {nm: rec.iter_frames(nm) for nm in names}

        def frame_cues(i, predictions):
            cues = {}
            frame = int(frames_idx[i])
            t0 = time.perf_counter()
            for nm in names:
                fi, img = next(iters[nm])
                pred = None if predictions is None else predictions.get(nm)
                cues[nm] = perceivers[nm].process(img, int(fi), pred)
            t_perc.append((time.perf_counter() - t0) * 1e3)
            return frame, cues

    def recorded(i, predictions):
        frame, cues = frame_cues(i, predictions)
        cam_xy.append(np.stack([cues[nm].xy for nm in names]))
        return frame, cues

    results = run_tracker(tracker, recorded, n, progress)
    out = ProcessOutput(
        frames=np.array([r.frame for r in results], dtype=np.int64),
        joints=np.array([r.joints for r in results]),
        cues=np.array([r.cues_3d for r in results]),
        cue_valid=np.array([r.cue_valid for r in results]),
        joint_valid=np.array([r.joint_valid for r in results]),
        bvh_rows=np.array([r.bvh_frame for r in results]),
        pan_rad=np.array([r.pan_rad for r in results]),
    )
    if cam_xy:
        out.camera_xy = np.stack(cam_xy, axis=1)
    fusion_ms = out.fusion_ms = np.array([r.timings_ms["total"] for r in results])
    out.timings_ms = {"fusion_median": float(np.median(fusion_ms)) if len(fusion_ms) else float("nan")}
    if t_perc:
        out.timings_ms["perception_6cam_median"] = float(np.median(t_perc))
    lengths = tracker.lengths
    # every output is written whole under a temporary name and renamed (mocap_rt.io.files)
    write_bvh(out_dir / "poses.bvh", tracker.bvh_skeleton, out.bvh_rows, 1.0 / config.fps)
    with atomic_write(out_dir / "poses.npz", "wb") as fh:
        np.savez_compressed(fh, joints=out.joints, joint_names=np.array(JOINT_NAMES),
                            frames=out.frames, cues=out.cues, cue_names=np.array(CUE_NAMES),
                            cue_valid=out.cue_valid, joint_valid=out.joint_valid, pan_rad=out.pan_rad,
                            bone_lengths=np.array(list(asdict(lengths).values())),
                            bone_length_names=np.array(list(asdict(lengths).keys())))
    write_pose_exports(out_dir / "poses", out.frames, out.joints, config.fps)
    write_bone_lengths(lengths, out_dir / "bones.toml")
    if truth is not None:
        out.accuracy = accuracy(truth, out.frames, out.cues, np.where(out.joint_valid[..., None], out.joints, np.nan))
    rec.close()
    return out
