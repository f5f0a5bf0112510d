"""The motion suite for the body (issue 10): every shared clip, variants and generated motions.

    python -m bench body_suite                      # default suite (bench/suite.py), ~31 clips
    python -m bench body_suite --quick              # 4 clips: backwards walk, jumping jacks, dance, hands at the face
    python -m bench body_suite --held-out           # procedural seeds 1000+ and variants never tuned on
    python -m bench body_suite --clips proc_clap_s0,walk_backwards_131_01 --json after.json --compare before.json
    python -m bench body_suite --quick --truth-bones   # the truth's bone lengths: the estimate's share of the error
    python -m bench body_suite --render-seed 1      # another render of the same clips: the suite's noise floor

Each clip's studio recording (6-camera ring, 640x480, 30 fps; bench/out/suite, rendered once)
goes through ``mocap_rt.fusion.offline.process_recording`` (what ``mocap-rt process`` runs:
perception of every camera in the closed loop with fusion, estimated bone lengths) and is
scored against its truth with ``mocap_rt.fusion.evaluate.suite_metrics``:

* MPJPE / PA-MPJPE (mm; PA = per-frame similarity Procrustes), elbow and knee mean error,
  over the joints the fusion estimated (``FusionResult.joint_valid``); "shown" = MPJPE over
  every joint of the published figure, the ones not estimated (a hand no view measured) where
  the figure put them: what a user of the BVH sees;
* mirr% = % of frames whose hands or feet are labelled with the wrong side: the crossed
  labelling of a pair is closer to the truth than the straight one by > 5 cm (summed);
* heading error median / p95 (deg): trunk heading (forward = (hip_r -> hip_l) x (pelvis -> neck))
  estimated vs truth;
* cue 3D error median / p95 (mm), per cue in the second table;
* joint-angle RMSE (deg) of hips (flex + abd), knees, shoulders (flex + abd), elbows, angles
  read geometrically from the joints (``anatomical_angles``);
* fusion ms per frame median / p99 (``BodyTracker.step``), also as x yardstick.

Processing runs under the shared timing lock (/tmp/mocap-timing.lock) one clip at a time.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import numpy as np

from bench.suite import ensure_recording, select, suite_clips
from bench.yardstick import header, timing_lock, yardstick_ms
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.names import C_FOOT_L, C_FOOT_R, CUE_NAMES, J

TARGETS = {"mpjpe_mm": 30.0, "mirrored_pct": 0.0, "heading_p95_deg": 15.0, "elbow_mm": 40.0, "knee_mm": 40.0}
COLS = (("MPJPE", "mpjpe_mm", 6, 0), ("shown", "mpjpe_shown_mm", 6, 0), ("PA", "pa_mpjpe_mm", 5, 0),
        ("mirr%", "mirrored_pct", 5, 0),
        ("hd50", "heading_med_deg", 5, 0), ("hd95", "heading_p95_deg", 5, 0), ("elbow", "elbow_mm", 5, 0),
        ("knee", "knee_mm", 5, 0), ("cue50", "cue_med_mm", 5, 0), ("cue95", "cue_p95_mm", 5, 0),
        ("aHip", "rmse_hips_deg", 5, 0), ("aKnee", "rmse_knees_deg", 5, 0), ("aShd", "rmse_shoulders_deg", 5, 0),
        ("aElb", "rmse_elbows_deg", 5, 0), ("fus50", "fusion_ms_med", 6, 2), ("fus99", "fusion_ms_p99", 6, 2))
LEGS = [J[n] for s in ("l", "r") for n in (f"knee_{s}", f"ankle_{s}", f"foot_{s}")]


def run_clip(rec_dir, lock: bool, legs: bool = True, truth_bones: bool = False,
             smooth_hz: float = FusionConfig.offline_smooth_hz) -> dict:
    """Process one recording and score it (``legs=False``: the desktop rig, legs not scored;
    ``truth_bones``: the truth's bone lengths instead of the estimate, to tell the estimate's
    share of the error from the rest; ``smooth_hz``: the offline smoothing's cutoff, 0 = off:
    the live service's poses)."""
    from mocap_rt.body.estimate import bone_lengths_from_joints
    from mocap_rt.fusion.evaluate import suite_metrics
    from mocap_rt.fusion.offline import process_recording
    from mocap_rt.io.recording import Recording

    rec = Recording(rec_dir)
    truth = {k: rec.truth[k] for k in ("frames", "joints", "cues", "joint_names")}
    rec.close()
    config = FusionConfig(bone_lengths=bone_lengths_from_joints(truth["joints"]) if truth_bones else None,
                          offline_smooth_hz=smooth_hz)
    with tempfile.TemporaryDirectory() as tmp, timing_lock(lock):
        t0 = time.perf_counter()
        out = process_recording(rec_dir, tmp, config, progress=False)
        wall = time.perf_counter() - t0
    joints = np.where(out.joint_valid[..., None], out.joints, np.nan)
    shown = out.joints.copy()
    cues = out.cues.copy()
    if not legs:
        joints[:, LEGS] = shown[:, LEGS] = np.nan
        cues[:, [C_FOOT_L, C_FOOT_R]] = np.nan
    m = suite_metrics(truth, out.frames, cues, joints, out.fusion_ms, shown)
    m["process_s"] = wall
    return m


def _row(name: str, m: dict, width: int = 30) -> str:
    cells = []
    for _, key, w, d in COLS:
        v = m.get(key, float("nan"))
        cells.append(f"{v:{w}.{d}f}")
    return f"{name[:width]:{width}s} " + " ".join(cells)


def _head(width: int = 30) -> str:
    return f"{'clip':{width}s} " + " ".join(f"{h:>{w}s}" for h, _, w, _ in COLS)


def print_tables(results: dict, ys: float) -> None:
    print(_head())
    for name, m in results.items():
        print(_row(name, m))
    vals = list(results.values())
    mean = {k: float(np.nanmean([m.get(k, np.nan) for m in vals])) for _, k, _, _ in COLS}
    print(_row("mean over clips", mean))
    ok = {k: sum(m.get(k, np.inf) <= t + 1e-9 for m in vals) for k, t in TARGETS.items()}
    print(f"clips meeting the issue-10 targets (of {len(vals)}): MPJPE <= 30 mm {ok['mpjpe_mm']}, "
          f"mirrored 0 % {ok['mirrored_pct']}, heading p95 <= 15 deg {ok['heading_p95_deg']}, "
          f"elbow <= 40 mm {ok['elbow_mm']}, knee <= 40 mm {ok['knee_mm']}")
    fus = [m["fusion_ms_med"] for m in vals if "fusion_ms_med" in m]
    f99 = [m["fusion_ms_p99"] for m in vals if "fusion_ms_p99" in m]
    if fus:
        print(f"fusion per frame over clips: median of medians {np.median(fus):.2f} ms = {np.median(fus) / ys:.1f}x "
              f"yardstick, worst p99 {np.max(f99):.2f} ms = {np.max(f99) / ys:.1f}x")
    print("\ncue 3D error per cue, median/p95 mm:")
    print(f"{'clip':30s} " + " ".join(f"{n:>11s}" for n in CUE_NAMES))
    for name, m in results.items():
        print(f"{name[:30]:30s} " + " ".join(
            f"{m.get(f'cue_{n}_med_mm', np.nan):5.0f}/{m.get(f'cue_{n}_p95_mm', np.nan):<5.0f}" for n in CUE_NAMES))


def compare(before: dict, after: dict) -> None:
    """Before -> after per clip for the issue-10 figures; flags a clip whose cue p95 got worse."""
    keys = (("MPJPE", "mpjpe_mm"), ("mirr%", "mirrored_pct"), ("hd95", "heading_p95_deg"),
            ("elbow", "elbow_mm"), ("knee", "knee_mm"), ("cue95", "cue_p95_mm"))
    print(f"\n{'clip':30s} " + " ".join(f"{h:>13s}" for h, _ in keys))
    common = [name for name in after if name in before]
    n_worse = 0
    for name in common:
        a, b = after[name], before[name]
        cells = " ".join(f"{b.get(k, np.nan):6.0f}->{a.get(k, np.nan):<5.0f}" for _, k in keys)
        worse = a.get("cue_p95_mm", 0) > 1.05 * b.get("cue_p95_mm", np.inf) + 1.0
        n_worse += worse
        print(f"{name[:30]:30s} {cells}{'  cue 3D WORSE' if worse else ''}")
    if common:
        def mean(res: dict, k: str) -> float:
            return float(np.nanmean([res[n].get(k, np.nan) for n in common]))
        print(f"{'mean over clips':30s} " + " ".join(f"{mean(before, k):6.1f}->{mean(after, k):<5.1f}" for _, k in keys))
        print(f"cue 3D worse on {n_worse} of {len(common)} clips")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="4 clips (backwards walk, jumping jacks, dance, face)")
    g.add_argument("--held-out", action="store_true", help="the held-out set (procedural seeds 1000+, variants)")
    g.add_argument("--all", action="store_true", help="default + held-out")
    ap.add_argument("--clips", default=None, help="comma-separated suite clip names (overrides the set)")
    ap.add_argument("--size", default="640x480", help="image size WxH")
    ap.add_argument("--json", default=None, help="write every figure to this JSON file")
    ap.add_argument("--compare", default=None, help="a JSON from an earlier run: print before -> after")
    ap.add_argument("--no-desktop", action="store_true", help="skip the 2-camera desktop rig rows")
    ap.add_argument("--no-lock", action="store_true", help="do not take /tmp/mocap-timing.lock")
    ap.add_argument("--render-seed", type=int, default=0,
                    help="the studio render's seed (camera gains, flicker, sensor noise): another capture of "
                         "the same motions, to tell a change's effect from the suite's noise floor")
    ap.add_argument("--smooth-hz", type=float, default=FusionConfig.offline_smooth_hz,
                    help="the offline smoothing's cutoff (FusionConfig.offline_smooth_hz); 0: off, the poses "
                         "the live service publishes")
    ap.add_argument("--truth-bones", action="store_true",
                    help="the truth's bone lengths instead of the estimate (the estimate's share of the error)")
    args = ap.parse_args(argv)
    which = "quick" if args.quick else "held-out" if args.held_out else "all" if args.all else "default"
    clips = select(suite_clips(which), args.clips)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    smooth_hz = args.smooth_hz
    with timing_lock(not args.no_lock):
        ys = yardstick_ms()
    print(header(ys))
    print(f"suite '{which if not args.clips else 'selected'}': {len(clips)} clips, 6-camera ring {size[0]}x{size[1]} "
          f"(render seed {args.render_seed}), "
          f"30 fps, mocap-rt process (closed loop, {'truth' if args.truth_bones else 'estimated'} bones, "
          f"{'not smoothed, as live' if smooth_hz == 0 else f'smoothed offline at {smooth_hz:g} Hz'}); "
          "errors mm, angles deg")
    results, t0 = {}, time.perf_counter()
    for c in clips:
        rec = ensure_recording(c, size, render_seed=args.render_seed)
        results[c.name] = run_clip(rec, not args.no_lock, truth_bones=args.truth_bones, smooth_hz=smooth_hz)
        print(_row(c.name, results[c.name]), flush=True)
    print(f"\n== motion suite ({len(clips)} clips, {time.perf_counter() - t0:.0f} s) ==")
    print_tables(results, ys)
    desktop = {}
    if not args.no_desktop:
        print("\n2-camera desktop rig (upper body scored: legs and foot cues left out):")
        print(_head())
        for c in select(suite_clips("all"), "proc_clap_s0,proc_hands_cross_face_s0"):
            desktop[c.name] = run_clip(ensure_recording(c, size, rig="desktop", render_seed=args.render_seed),
                                       not args.no_lock, legs=False,
                                       truth_bones=args.truth_bones, smooth_hz=smooth_hz)
            print(_row(c.name, desktop[c.name]))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"yardstick_ms": ys, "size": list(size), "render_seed": args.render_seed, "clips": results,
                       "desktop": desktop}, fh, indent=1)
        print(f"wrote {args.json}")
    if args.compare:
        with open(args.compare) as fh:
            compare(json.load(fh)["clips"], results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
