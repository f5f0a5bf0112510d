"""GStreamer sources vs ``replay:``: the poses of the whole cluster fed through file pipelines.

For one recorded segment per camera (6 cameras, 320x240, a real CMU walk rendered by the
studio), the cluster runs once on ``replay:`` and once per pipeline
(``filesrc ! avidemux ! DECODER``), and the recorded joints of the same frames are compared:
MPJPE difference (mean over joints and frames, mm) and its maximum, plus the pixel
difference of the decoded images to OpenCV's. Both runs trigger at a fifth of the
recording's rate (6 fps) with a whole period as fusion's deadline, so every camera answers every frame.

    python -m bench gst
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from bench.bench_service import REPO, data_root

CLIP = "bvh/cmu/cmu_02_01_walk.bvh"
SPEED = 0.2         # 6 fps: a 167 ms deadline (fusion presumes a camera dead after 0.25 s)


def recording(path: Path, codec: str) -> Path:
    from mocap_rt.studio.synth import make_rig, synthesize

    if not (path / "recording.toml").is_file():
        synthesize(data_root() / CLIP, path, rig=make_rig(n_cameras=6, size=(320, 240)), seconds=1.0,
                   truth_masks=False, codec=codec)
    return path


def cluster(rec: Path, source: str, out: Path, **kw) -> np.lib.npyio.NpzFile:
    import shutil

    from nodes.launcher import Launcher, RunConfig

    shutil.rmtree(out, ignore_errors=True)     # the recorder never overwrites: start clean
    cfg = RunConfig(rig_path=rec / "rig.toml", source=source, record=out / "rec", log_dir=out / "logs",
                    status_line=False, speed=SPEED, deadline_frac=1.0, **kw)
    Launcher(cfg).run()
    return np.load(out / "rec" / "poses.npz")


def pixel_difference(rec: Path, decoder: str, n: int = 10) -> tuple[float, float]:
    """(max, mean) |gst - OpenCV| over ``n`` frames of cam_1, 8-bit levels."""
    from mocap_rt.io.recording import Recording
    from nodes.gst_source import open_gst_source

    r = Recording(rec)
    src = open_gst_source(f"filesrc location={rec}/video/{{camera}}/seg_000000.avi ! avidemux ! {decoder}",
                          r.rig["cam_1"], 0, rec)
    try:
        d = [np.abs(src.grab(k).image.astype(int) - r.read_frame("cam_1", k).astype(int)) for k in range(n)]
    finally:
        src.close()
    return float(max(x.max() for x in d)), float(np.mean([x.mean() for x in d]))


def compare(ref, got, n: int) -> dict:
    common = np.intersect1d(ref["frames"][ref["frames"] < n], got["frames"][got["frames"] < n])
    a = ref["joints"][np.searchsorted(ref["frames"], common)]
    b = got["joints"][np.searchsorted(got["frames"], common)]
    ok = np.isfinite(a).all(axis=2) & np.isfinite(b).all(axis=2)
    d = np.linalg.norm(a - b, axis=2)[ok] * 1e3
    return {"frames": int(len(common)), "mpjpe_diff_mm": float(d.mean()), "max_mm": float(d.max()),
            "frames_identical": int(np.sum(np.all(np.where(ok, np.linalg.norm(a - b, axis=2), 0) < 1e-9, axis=1)))}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", type=Path, default=REPO / "out" / "bench" / "gst")
    args = p.parse_args(argv or [])
    from mocap_rt.io.recording import Recording

    try:
        from nodes.gst_source import gst_modules

        gst_modules()
    except ImportError as exc:
        print(f"gst bench skipped: {exc}")
        return 0
    rows = []
    for codec, decoders in (("MJPG", ("avdec_mjpeg", "jpegdec")), ("FFV1", ("avdec_ffv1",))):
        rec = recording(args.work / f"walk_{codec.lower()}", codec)
        n = Recording(rec).segment_frames
        ref = cluster(rec, f"replay:{rec}", args.work / f"run_{codec}_replay")
        for dec in decoders:
            src = f"gst:filesrc location={rec}/video/{{camera}}/seg_000000.avi ! avidemux ! {dec}"
            got = cluster(rec, src, args.work / f"run_{codec}_{dec}", backgrounds_from=rec,
                          duration_s=(n + 8) / (30.0 * SPEED))
            px_max, px_mean = pixel_difference(rec, dec)
            rows.append((codec, dec, px_max, px_mean, compare(ref, got, n)))
    print(f"gst bench: loadavg {os.getloadavg()[0]:.1f}; cluster at {30 * SPEED:g} fps, one 30-frame segment "
          f"per camera, 6 cameras 320x240")
    print("| segments | decoder | pixel diff max / mean (levels) | frames | MPJPE diff vs replay (mm) | max (mm) "
          "| identical frames |\n|---|---|---|---|---|---|---|")
    for codec, dec, pmax, pmean, c in rows:
        print(f"| {codec} | {dec} | {pmax:.0f} / {pmean:.2f} | {c['frames']} | {c['mpjpe_diff_mm']:.3f} | "
              f"{c['max_mm']:.1f} | {c['frames_identical']} |")
    print("target: MPJPE difference <= 1 mm")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))
