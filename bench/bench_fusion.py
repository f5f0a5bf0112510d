"""Fusion + IK accuracy and speed (issue 5, items 7-8).

Three sources of 2D cues, to separate fusion's error from perception's:

1. ``projected``: every shared BVH clip (CMU and Bandai-Namco) mapped to the body
   points by the studio's map, projected into the 6-camera ring (640x480) with
   Gaussian pixel noise; visibility from a Z-buffer of the cue discs (``predict_views``
   with the true positions) and the image bounds. No rendering, so all clips are cheap.
2. ``truth2d``: each studio recording in ``out/studio`` (helper B), using its
   ``truth.npz`` 2D cues and rendered visibility (+ noise).
3. ``perception``: the same recordings through the perception stage (``mocap-rt
   process``), when they are present.

Tables: per clip cue 3D error (median, p95) and MPJPE; per joint; all views vs the
frontal pair; analytic IK vs CCD refinement; truth vs estimated bone lengths; the
2-camera desktop rig (upper body). Speed: fusion + analytic IK per frame, and with CCD.

    python -m bench fusion            # or: python -m bench.bench_fusion --quick
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocap_rt.body.estimate import bone_lengths_from_joints
from mocap_rt.cues import CameraCues
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.evaluate import truth_camera_cues
from mocap_rt.fusion.identity import IdentityConfig
from mocap_rt.fusion.tracker import BodyTracker
from mocap_rt.fusion.views import CUE_RADII_M, RigProjector, predict_views
from mocap_rt.geometry.rig import desktop_rig, ring_rig
from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HAND_L, C_HAND_R, C_HEAD, C_TORSO, CUE_JOINT_INDEX, JOINT_NAMES
from mocap_rt.names import J as JOINT_INDEX
from mocap_rt.shared_data import data_root

REPO = Path(__file__).resolve().parents[1]
TARGETS = {"cue_median_mm": 10.0, "cue_p95_mm": 30.0, "mpjpe_mm": 30.0, "fusion_ms": 1.0}
UPPER = [JOINT_INDEX[n] for n in ("pelvis", "torso", "neck", "head", "shoulder_l", "elbow_l", "wrist_l",
                                        "hand_l", "shoulder_r", "elbow_r", "wrist_r", "hand_r")]


def clip_joints(path: Path, fps: float = 30.0, seconds: float = 4.0) -> np.ndarray:
    """(F, 20, 3) world joints of a BVH clip (studio map, centred in the ring)."""
    from mocap_rt.io.bvh import read_bvh
    from mocap_rt.studio.body_map import body_motion

    clip = read_bvh(path)
    dur = (clip.n_frames - 1) * clip.frame_time_s
    n = int(min(seconds, dur) * fps) + 1
    return body_motion(clip, fps=fps, n_frames=n, placement="centre").joints


def projected_cues(rig, cues_3d: np.ndarray, noise_px: float, rng) -> list[dict]:
    """Per frame {camera: CameraCues} from true 3D cues (F, 6, 3)."""
    proj = RigProjector(rig.cameras)
    out = []
    for f, X in enumerate(cues_3d):
        xy, vis, _ = predict_views(proj, X, CUE_RADII_M)
        d = {}
        for c, cam in enumerate(rig.cameras):
            p = xy[c] + rng.normal(0, noise_px, (6, 2))
            p[~vis[c]] = np.nan
            d[cam.name] = CameraCues(cam.name, f, p, np.zeros((6, 2, 2)), vis[c] * 100.0, vis[c] * 1.0)
        out.append(d)
    return out


def track(rig, frames_cues: list[dict], config: FusionConfig):
    """Run the tracker (with predictions, and the re-solve of the frames before the bone
    lengths were estimated, as ``mocap-rt process`` does)."""
    from mocap_rt.fusion.offline import run_tracker

    tracker = BodyTracker(rig, config)
    res = run_tracker(tracker, lambda i, pred: (i, frames_cues[i]), len(frames_cues), progress=False)
    cues = np.array([r.cues_3d for r in res])
    joints = np.array([np.where(r.joint_valid[:, None], r.joints, np.nan) for r in res])
    tms = np.array([r.timings_ms["total"] for r in res])
    return cues, joints, tms, tms


def errors(cues, joints, t_cues, t_joints, skip: int = 0, joint_idx=None):
    ce = np.linalg.norm(cues - t_cues, axis=-1)[skip:]
    je = np.linalg.norm(joints - t_joints, axis=-1)[skip:]
    if joint_idx is not None:
        je = je[:, joint_idx]
    return ce, je


def fmt_row(name, ce, je, ms=None):
    s = (f"{name:44s} {np.nanmedian(ce) * 1e3:6.1f} {np.nanpercentile(ce, 95) * 1e3:6.1f} "
         f"{np.nanmean(je) * 1e3:6.1f} {100 * np.isfinite(ce).mean():5.0f}%")
    if ms is not None:
        s += f" {np.median(ms):7.3f}"
    return s


HEADER = f"{'clip / variant':44s} {'cue50':>6s} {'cue95':>6s} {'MPJPE':>6s} {'cover':>6s} {'ms/fr':>7s}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two clips, 2 s each")
    ap.add_argument("--noise-px", type=float, default=1.0)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--no-perception", action="store_true")
    ap.add_argument("--recordings", nargs="*", default=[],
                    help="more recording dirs for the closed-loop table [4] (besides out/studio)")
    ap.add_argument("--closed-loop-only", action="store_true", help="only the closed-loop table [4]")
    args = ap.parse_args(argv)
    if args.closed_loop_only:
        _closed_loop(args)
        return 0
    rng = np.random.default_rng(0)
    root = data_root() / "bvh"
    clips = sorted(root.glob("cmu/*.bvh")) + sorted(root.glob("bandai_namco/*.bvh"))
    clips = [c for c in clips if "02_03" not in c.name]  # the 165-joint retargeted rig has no studio map
    if args.quick:
        clips, args.seconds = clips[1:2] + clips[-1:], 2.0
    rig = ring_rig()
    print(f"targets: cue median <= {TARGETS['cue_median_mm']} mm, p95 <= {TARGETS['cue_p95_mm']} mm, "
          f"MPJPE <= {TARGETS['mpjpe_mm']} mm, fusion + analytic IK <= {TARGETS['fusion_ms']} ms/frame")
    print(f"\n[1] projected truth cues, 6-camera ring 640x480, {args.noise_px} px noise, "
          f"{args.seconds:.0f} s per clip (errors in mm; MPJPE over the 20 joints)")
    print(HEADER)
    base = FusionConfig()
    variants = [("all views, analytic, truth bones", lambda L: replace(base, bone_lengths=L)),
                ("all views, analytic, estimated bones", lambda L: base),
                ("frontal pair, analytic, truth bones", lambda L: replace(base, views="pair", bone_lengths=L)),
                ("all views, analytic+CCD, truth bones", lambda L: replace(base, ik="ccd", bone_lengths=L)),
                ("all views, filtered cues, truth bones", lambda L: replace(base, use_filtered=True, bone_lengths=L))]
    agg = {v[0]: ([], []) for v in variants}
    per_joint = []
    ms_analytic, ms_ccd = [], []
    for clip in clips:
        J = clip_joints(clip, seconds=args.seconds)
        C = J[:, list(CUE_JOINT_INDEX)]
        L = bone_lengths_from_joints(J)
        fc = projected_cues(rig, C, args.noise_px, rng)
        print(f"{clip.stem[:44]}")
        for name, make in variants:
            cues, joints, ms, tms = track(rig, fc, make(L))
            ce, je = errors(cues, joints, C, J)
            agg[name][0].append(ce)
            agg[name][1].append(je)
            if name.startswith("all views, analytic, truth"):
                per_joint.append(np.nanmean(je, axis=0))
                ms_analytic.append(tms)
            if "CCD" in name:
                ms_ccd.append(tms)
            print(fmt_row("  " + name, ce, je, tms))
    print("\nall clips (projected):")
    print(HEADER)
    for name, (ce, je) in agg.items():
        print(fmt_row("  " + name, np.concatenate(ce), np.concatenate(je)))
    print("\nper joint, mean error mm (all views, analytic, truth bones), rows = clips:")
    print(f"{'clip':28s} " + " ".join(f"{n[:7]:>7s}" for n in JOINT_NAMES))
    for clip, pj in zip(clips, per_joint):
        print(f"{clip.stem[:28]:28s} " + " ".join(f"{v * 1e3:7.0f}" for v in pj))
    print(f"{'mean':28s} " + " ".join(f"{v * 1e3:7.0f}" for v in np.nanmean(per_joint, axis=0)))

    # desktop rig: upper body, in place
    print("\n[1b] 2-camera desktop rig (upper body; feet not used), moving in place")
    print(HEADER)
    drig = desktop_rig()
    for clip in clips[:3]:
        J = clip_joints(clip, seconds=args.seconds)
        J[..., :2] -= J[:, JOINT_INDEX["pelvis"], None, :2]
        C = J[:, list(CUE_JOINT_INDEX)]
        fc = projected_cues(drig, C, args.noise_px, rng)
        for d in fc:
            for cc in d.values():
                cc.xy[[C_FOOT_L, C_FOOT_R]] = np.nan
                cc.confidence[[C_FOOT_L, C_FOOT_R]] = 0
        cues, joints, ms, tms = track(drig, fc, replace(base, bone_lengths=bone_lengths_from_joints(J)))
        upper = [C_HEAD, C_HAND_L, C_HAND_R, C_TORSO]
        ce, je = errors(cues[:, upper], joints, C[:, upper], J, joint_idx=UPPER)
        print(fmt_row("  " + clip.stem[:42], ce, je, tms))

    # studio recordings
    studio = sorted((REPO / "out" / "studio").glob("*/truth.npz"))
    if studio:
        _recordings(studio, args, base)
    if not args.no_perception:
        _closed_loop(args)
    allms = np.concatenate(ms_analytic)
    print("\n[3] speed per frame (BodyTracker.step: triangulation + outlier rejection + filter + IK + BVH row):")
    print(f"  analytic IK: median {np.median(allms):.3f} ms, p95 {np.percentile(allms, 95):.3f} ms "
          f"(target <= {TARGETS['fusion_ms']} ms)")
    allc = np.concatenate(ms_ccd)
    print(f"  analytic + CCD refinement (38 DOF): median {np.median(allc):.3f} ms, p95 {np.percentile(allc, 95):.3f} ms")
    return 0


def _recordings(studio, args, base):
    from mocap_rt.fusion.offline import process_recording
    from mocap_rt.io.recording import Recording

    print(f"\n[2] studio recordings (out/studio): truth 2D cues + {args.noise_px} px noise, "
          f"and the perception stage")
    print(HEADER)
    rng = np.random.default_rng(1)
    import tempfile
    for t in studio:
        rec = Recording(t.parent)
        truth = rec.truth
        names = list(rec.rig.names)
        tj = np.asarray(truth["joints"])
        L = bone_lengths_from_joints(tj)
        fc = [truth_camera_cues(truth, names, i, int(f), args.noise_px, rng) for i, f in enumerate(truth["frames"])]
        tc = np.asarray(truth["cues"])
        cfg = replace(base, fps=rec.fps)
        upper = len(names) == 2
        jidx = UPPER if upper else None
        print(f"{t.parent.name} ({len(names)} cameras)")
        for name, c in (("truth2d, all views, truth bones", replace(cfg, bone_lengths=L)),
                        ("truth2d, all views, estimated bones", cfg),
                        ("truth2d, frontal pair, truth bones", replace(cfg, views="pair", bone_lengths=L)),
                        ("truth2d, analytic+CCD, truth bones", replace(cfg, ik="ccd", bone_lengths=L))):
            if upper and "pair" in name:
                continue
            cues, joints, ms, tms = track(rec.rig, fc, c)
            ce, je = errors(cues, joints, tc, tj, joint_idx=jidx)
            print(fmt_row("  " + name, ce, je, tms))
        if args.no_perception:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            for name, c in (("perception, all views, truth bones", replace(cfg, bone_lengths=L)),
                            ("perception, all views, estimated bones", cfg)):
                out = process_recording(t.parent, tmp, c, progress=False)
                idx = np.arange(len(out.frames))
                joints = np.where(out.joint_valid[..., None], out.joints, np.nan)
                ce, je = errors(out.cues, joints, tc[idx], tj[idx], joint_idx=jidx)
                print(fmt_row("  " + name, ce, je) + f"  (perception {out.timings_ms.get('perception_6cam_median', 0):.0f} ms/frame)")
        rec.close()


def _closed_loop(args) -> None:
    """[4] The closed loop (perception <- prediction <- fusion) per recording and cue, with
    the identity fixes of issues 4/5 switched off as the "before" row."""
    import tempfile

    from mocap_rt.fusion.offline import process_recording
    from mocap_rt.io.recording import Recording
    from mocap_rt.names import CUE_NAMES
    from mocap_rt.perception.blobs import BlobParams
    from mocap_rt.perception.pipeline import PerceptionConfig, config_for_source

    dirs = [t.parent for t in sorted((REPO / "out" / "studio").glob("*6cam*/truth.npz"))]
    dirs += [Path(d) for d in args.recordings]
    print("\n[4] closed loop: perception of every camera -> fusion -> prediction -> next frame's perception"
          " (mocap-rt process; estimated bones)")
    print("    'before' = perception without region snap and lone-region acquisition;"
          " fusion without the identity hypotheses")
    cue_hdr = " ".join(f"{n[:6]:>11s}" for n in CUE_NAMES)
    print(f"{'recording / variant':44s} {'cue50':>6s} {'cue95':>6s} {'MPJPE':>6s} {'cover':>6s}  per cue median/p95 mm:")
    print(f"{'':72s}{cue_hdr}")
    for d in dirs:
        rec = Recording(d)
        if rec.truth is None:
            continue
        fps, source = rec.fps, rec.source
        rec.close()
        pc = config_for_source(PerceptionConfig(), source)
        old_blobs = BlobParams(snap_to_regions=False, acquire_lone_region=False)
        before = replace(pc, skin_blobs=old_blobs, shoe_blobs=old_blobs)
        print(f"{d.name}")
        for name, pcfg, fcfg in (("closed loop (default)", pc, FusionConfig(fps=fps)),
                                 ("before (issue-5 behaviour)", before, FusionConfig(fps=fps, identity=IdentityConfig(enabled=False)))):
            with tempfile.TemporaryDirectory() as tmp:
                out = process_recording(d, tmp, fcfg, perception_config=pcfg, progress=False)
            acc = out.accuracy
            per = acc.per_cue_mm()
            cells = " ".join(f"{per[n][0]:5.0f}/{per[n][1]:<5.0f}" for n in CUE_NAMES)
            print(fmt_row("  " + name, acc.cue_err, acc.joint_err) + f"  {cells}")


if __name__ == "__main__":
    raise SystemExit(main())
