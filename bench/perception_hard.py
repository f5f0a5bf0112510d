"""Hard-case perception suite (issue 12, item 3): ``python -m bench perception --hard``.

Clips: the procedural motions with contacts and crossings (bench/suite.py ``CONTACT``:
hands crossing in front of the face, clap, hands on the head, a hand behind the head, arms
overhead, crouching with the hands at the feet, feet crossing, jumping jacks while
turning) plus every shared clip; 6-camera ring, 640x480, 30 fps, 4 s each, rendered once
(bench/out/suite, shared with ``bench body_suite``).

Two loops per clip:

* ``closed``: the loop of ``mocap-rt process`` (``process_recording``): every frame's
  perception gets fusion's 3D prediction projected into each camera (Z-buffer visibility);
  the 2D cues fusion was given are scored, with the torso as ``mocap-rt perceive`` writes it:
  the fused body's torso point projected (``fusion.offline.with_fused_torso``); the torso each
  camera measured (fusion's input) is scored beside it (``torso_measured``);
* ``open``: each camera alone on its own 2D tracks (``perceive_recording`` without fusion).

Scoring (``mocap_rt.perception.evaluate``), per cue over all cameras and frames where the
truth cue is >= 50 % visible and inside the image: median / p95 pixel error, with each
hand and foot pair scored under the better left/right labelling per camera and frame
(left/right is fusion's job, issue 10); lost = a visible cue not found or > 20 px (at 640
wide) from its truth; longest loss (s) = the longest episode from a lost frame to the next
frame where the cue is back (the frames it was hidden in between included; "seen" in the
pooled lines leaves them out); re-acquisition = the median and longest of the episodes that
ended with the cue back. Targets (closed loop): median <= 1.5 px, p95 <= 5 px, no loss
longer than 0.2 s; open loop: head never lost longer than 0.5 s.
"""

from __future__ import annotations

import argparse
import inspect
import json
import tempfile
import time

import numpy as np

from bench.suite import CONTACT, ensure_recording, select, suite_clips
from bench.yardstick import header, timing_lock, yardstick_ms
from mocap_rt.names import CUE_NAMES

TARGETS = {"median_px": 1.5, "p95_px": 5.0, "closed_longest_s": 0.2, "open_head_longest_s": 0.5}


def hard_clips(which: str = "default") -> list:
    """The contact procedural clips (seed 0, or the held-out seeds) plus every shared clip."""
    pool = suite_clips("held-out" if which == "held-out" else "default")
    contact = [c for c in pool if c.kind in ("procedural", "held-out") and
               any(c.name.startswith(f"proc_{n}_s") for n in CONTACT)]
    shared = [c for c in suite_clips("default") if c.kind == "shared"]
    if which == "quick":
        return [c for c in contact if c.name in ("proc_hands_cross_face_s0", "proc_clap_s0")] + \
            [c for c in shared if c.name == "cmu_05_06_modern_dance"]
    return contact + shared


def run_loops(rec_dir, loops=("closed", "open")) -> dict[str, np.ndarray]:
    """(C, F, 6, 2) 2D cues of the recording per loop (and "closed_measured": the closed loop's
    cues with the torso each camera measured)."""
    from mocap_rt.cli.perceive import perceive_recording
    from mocap_rt.fusion.offline import process_recording
    from mocap_rt.io.recording import Recording
    from mocap_rt.perception.pipeline import PerceptionConfig, config_for_source

    out = {}
    if "closed" in loops:
        from mocap_rt.fusion.offline import with_fused_torso

        with tempfile.TemporaryDirectory() as tmp, Recording(rec_dir) as rec:
            p = process_recording(rec_dir, tmp, progress=False)
            out["closed_measured"] = p.camera_xy
            out["closed"] = with_fused_torso(p.camera_xy, rec.rig.cameras, p.joints, p.joint_valid)
    if "open" in loops:
        with Recording(rec_dir) as rec:
            cfg = config_for_source(PerceptionConfig(), rec.source)
            kw = {"closed_loop": False} if "closed_loop" in inspect.signature(perceive_recording).parameters else {}
            out["open"] = perceive_recording(rec, list(rec.camera_names), cfg, **kw)["cues_2d"]
    return out


def score(rec_dir, xy: np.ndarray) -> dict:
    """Per-cue ``CueTrackStats`` (as dicts) of one recording's 2D cues, with ``along_px`` and
    ``across_px``: the medians of the error's components along and across the limb
    (``along_limb_errors``) over the frames the cue is visible and not lost."""
    from dataclasses import asdict

    from mocap_rt.io.recording import Recording
    from mocap_rt.perception.evaluate import (ADJOINING_JOINT, LOST_PX_640, along_limb_errors, cue_track_stats,
                                              truth_visible)

    with Recording(rec_dir) as rec:
        truth = rec.truth
        W, H = rec.rig[0].width, rec.rig[0].height
        F = xy.shape[1]
        vis = truth_visible(truth, W, H)[:, :F]
        t2d = np.asarray(truth["cues_2d"])[:, :F]
        lost_px = LOST_PX_640 * W / 640
        stats = cue_track_stats(xy, t2d, vis, rec.fps, lost_px)
        names = [str(n) for n in truth["joint_names"]]
        joints = np.asarray(truth["joints"], np.float64)[:F]
        joint_xy = np.full(t2d.shape, np.nan)
        for k, cue in enumerate(CUE_NAMES):
            if cue in ADJOINING_JOINT:
                for c, cam in enumerate(rec.rig.cameras):
                    joint_xy[c, :, k] = cam.project(joints[:, names.index(ADJOINING_JOINT[cue])])[0]
    split = along_limb_errors(xy, t2d, joint_xy)
    near = np.linalg.norm(split, axis=-1) <= lost_px          # NaN (not found, no limb) compares False
    out = {}
    for k, n in enumerate(CUE_NAMES):
        sel = vis[..., k] & near[..., k]
        out[n] = asdict(stats[n]) | {
            "along_px": float(np.median(split[..., k, 0][sel])) if sel.any() else float("nan"),
            "across_px": float(np.median(split[..., k, 1][sel])) if sel.any() else float("nan")}
    return out


def _row(name: str, loop: str, s: dict) -> str:
    cells = " ".join(f"{s[n]['median_px']:5.1f}/{s[n]['p95_px']:<6.1f}" for n in CUE_NAMES)
    lost = sum(s[n]["lost_frames"] for n in CUE_NAMES)
    vis = sum(s[n]["visible_frames"] for n in CUE_NAMES)
    longest = max(s[n]["longest_loss_s"] for n in CUE_NAMES)
    worst = max(CUE_NAMES, key=lambda n: s[n]["longest_loss_s"])
    reacq = [s[n]["reacq_median_s"] for n in CUE_NAMES if np.isfinite(s[n]["reacq_median_s"])]
    return (f"{name[:28]:28s} {loop:6s} {cells} {lost:5d}/{vis:<6d} {longest:5.2f} {worst[:6]:6s} "
            f"{(np.median(reacq) if reacq else float('nan')):5.2f}")


def _head() -> str:
    return (f"{'clip':28s} {'loop':6s} " + " ".join(f"{n + ' med/p95':>12s}" for n in CUE_NAMES) +
            f" {'lost/visible':>12s} {'longest s':>9s} {'reacq s':>7s}")


def _finite_median(vals: list[float]) -> float:
    vals = [v for v in vals if np.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def _pooled(rows: list[dict], cues=CUE_NAMES) -> dict:
    """Per cue over clips: median of medians, max p95, summed lost frames, longest loss."""
    out = {}
    for n in cues:
        out[n] = {"median_px": float(np.nanmedian([r[n]["median_px"] for r in rows])),
                  "p95_px": float(np.nanmax([r[n]["p95_px"] for r in rows])),
                  "lost_frames": int(sum(r[n]["lost_frames"] for r in rows)),
                  "visible_frames": int(sum(r[n]["visible_frames"] for r in rows)),
                  "longest_loss_s": float(max(r[n]["longest_loss_s"] for r in rows)),
                  "longest_seen_loss_s": float(max(r[n]["longest_seen_loss_s"] for r in rows)),
                  "reacq_median_s": _finite_median([r[n]["reacq_median_s"] for r in rows]),
                  **{k: _finite_median([r[n].get(k, np.nan) for r in rows]) for k in ("along_px", "across_px")}}
    if all("torso_measured" in r for r in rows):
        out["torso_measured"] = _pooled([{"torso": r["torso_measured"]} for r in rows], ("torso",))["torso"]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="3 clips (hands at the face, clap, dance)")
    g.add_argument("--held-out", action="store_true", help="contact clips at the held-out seeds + shared clips")
    ap.add_argument("--clips", default=None, help="comma-separated suite clip names")
    ap.add_argument("--loops", default="closed,open", help="closed, open or both")
    ap.add_argument("--json", default=None, help="write the figures to this JSON file")
    ap.add_argument("--no-lock", action="store_true", help="do not take /tmp/mocap-timing.lock")
    args = ap.parse_args(argv)
    which = "quick" if args.quick else "held-out" if args.held_out else "default"
    clips = select(hard_clips(which), args.clips)
    loops = tuple(x.strip() for x in args.loops.split(",") if x.strip())
    with timing_lock(not args.no_lock):
        ys = yardstick_ms()
    print(header(ys))
    print(f"hard-case perception suite: {len(clips)} clips, 6-camera ring 640x480, 30 fps; per cue median/p95 px "
          "(hand and foot pairs under the better left/right labelling per camera and frame), lost frames "
          "(missing or > 20 px), longest loss and median re-acquisition (s)")
    print(_head())
    results: dict[str, dict] = {loop: {} for loop in loops}
    t0 = time.perf_counter()
    for c in clips:
        rec = ensure_recording(c)
        xy = run_loops(rec, loops)                 # accuracy only: no timing lock needed
        for loop in loops:
            results[loop][c.name] = score(rec, xy[loop])
            if loop == "closed":
                results[loop][c.name]["torso_measured"] = score(rec, xy["closed_measured"])["torso"]
            print(_row(c.name, loop, results[loop][c.name]), flush=True)
    print(f"\n== all clips ({len(clips)}, {time.perf_counter() - t0:.0f} s): per cue median of medians / worst p95, "
          "lost frames, longest loss ==")
    for loop in loops:
        pooled = _pooled(list(results[loop].values()))
        print(_row("ALL (pooled)", loop, pooled))
        print("   " + ", ".join(f"{n}: lost {pooled[n]['lost_frames']}/{pooled[n]['visible_frames']}, "
                               f"longest {pooled[n]['longest_loss_s']:.2f} s (seen {pooled[n]['longest_seen_loss_s']:.2f})"
                               for n in CUE_NAMES))
        print("   (longest: from a lost frame to the next frame the cue is back, the frames it was hidden in "
              "between included; seen: those frames left out)")
        if "torso_measured" in pooled:
            t = pooled["torso_measured"]
            print(f"   torso: the fused body's torso point projected (what `mocap-rt perceive` writes); as the cameras "
                  f"measured it (fusion's input): {t['median_px']:.1f}/{t['p95_px']:.1f} px, lost "
                  f"{t['lost_frames']}/{t['visible_frames']}, longest {t['longest_loss_s']:.2f} s")
        print("   error along / across the limb, px (median of the clips' medians; along > 0: away from the "
              "joint the blob adjoins, where collar, sleeve or trouser leg covers it): " + ", ".join(
                  f"{n} {pooled[n]['along_px']:+.2f} / {pooled[n]['across_px']:+.2f}" for n in CUE_NAMES
                  if np.isfinite(pooled[n]["along_px"])))
    print("targets: closed loop median <= 1.5 px, p95 <= 5 px per cue, no loss > 0.2 s; "
          "open loop: head never lost > 0.5 s")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"yardstick_ms": ys, "results": results}, fh, indent=1)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
