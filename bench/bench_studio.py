"""Studio speed and codec table.

1. ``mocap-rt synth`` target: 10 s of 6 cameras at 640x480, 30 fps (1800 images) rendered
   AND encoded in <= 90 s on 2 cores; the same at 320x240.
2. Codec candidates for the stream format (cv2.VideoWriter): size, encode and decode
   time per frame, random seek time, PSNR against the rendered frames.

Usage: ``python -m bench studio`` (or ``python -m bench.bench_studio --quick``).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from mocap_rt.shared_data import data_root
from mocap_rt.studio.body_map import body_motion
from mocap_rt.studio.body_shape import body_primitives
from mocap_rt.studio.render import StudioRenderer
from mocap_rt.studio.synth import make_rig, synthesize

REPO = Path(__file__).resolve().parents[1]
TARGET_S = 90.0
CODECS = (("MJPG", ".avi"), ("XVID", ".avi"), ("mp4v", ".mp4"), ("FFV1", ".avi"))


def _clip() -> Path:
    # 22.9 s of jumps and turns: long enough for 10 s, lots of occlusion
    return data_root() / "bvh" / "cmu" / "cmu_01_01_playground_forward_jumps.bvh"


def bench_synth(size: tuple[int, int], seconds: float, workdir: Path) -> dict:
    out = workdir / f"synth_{size[0]}x{size[1]}"
    shutil.rmtree(out, ignore_errors=True)
    rig = make_rig("ring", 6, size)
    t0 = time.perf_counter()
    stats = synthesize(_clip(), out, rig=rig, fps=30.0, seconds=seconds, seed=0)
    wall = time.perf_counter() - t0
    size_mb = sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) / 1e6
    shutil.rmtree(out, ignore_errors=True)
    return {"size": f"{size[0]}x{size[1]}", "images": stats.n_images, "wall_s": wall,
            "render_s": stats.render_s, "encode_s": stats.encode_s,
            "ms_per_image": 1e3 * wall / stats.n_images, "MB": size_mb}


def _frames(n: int, size: tuple[int, int]) -> list[np.ndarray]:
    from mocap_rt.io.bvh import read_bvh

    rig = make_rig("ring", 6, size)
    body = body_motion(read_bvh(_clip()), fps=30.0, n_frames=n, placement="centre")
    renderer = StudioRenderer(rig, seed=0)
    return [renderer.render(0, body_primitives(body.points[f]), f).image for f in range(n)]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def bench_codecs(frames: list[np.ndarray], workdir: Path, fps: float = 30.0) -> list[dict]:
    h, w = frames[0].shape[:2]
    rows = []
    for fourcc, ext in CODECS:
        path = workdir / f"codec_{fourcc}{ext}"
        wr = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
        if not wr.isOpened():
            rows.append({"codec": fourcc, "error": "cannot open writer"})
            continue
        if fourcc == "MJPG":
            wr.set(cv2.VIDEOWRITER_PROP_QUALITY, 95)
        enc = []
        for f in frames:
            t = time.perf_counter()
            wr.write(f)
            enc.append(time.perf_counter() - t)
        wr.release()
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        dec, psnr = [], []
        for f in frames:
            t = time.perf_counter()
            ok, img = cap.read()
            dec.append(time.perf_counter() - t)
            if not ok:
                break
            psnr.append(_psnr(img, f))
        seek = []
        rng = np.random.default_rng(0)
        for k in rng.integers(0, len(frames), 10):
            t = time.perf_counter()
            cap.set(cv2.CAP_PROP_POS_FRAMES, int(k))
            ok, img = cap.read()
            seek.append(time.perf_counter() - t)
        cap.release()
        rows.append({"codec": fourcc, "KB_per_frame": path.stat().st_size / len(frames) / 1024,
                     "encode_ms": 1e3 * statistics.median(enc), "decode_ms": 1e3 * statistics.median(dec),
                     "seek_ms": 1e3 * statistics.median(seek), "psnr_db": statistics.median(psnr) if psnr else 0,
                     "frames_read": len(psnr)})
        path.unlink()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench_studio", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 s instead of 10 s")
    ap.add_argument("--skip-synth", action="store_true")
    args = ap.parse_args(argv or [])
    seconds = 2.0 if args.quick else 10.0
    workdir = Path(tempfile.mkdtemp(prefix="bench_studio_", dir=REPO / "out" if (REPO / "out").is_dir() else None))
    status = 0
    try:
        if not args.skip_synth:
            print(f"synth: cmu_01_01, 6-camera ring, 30 fps, {seconds:g} s, seed 0, MJPG q95, 2 render threads")
            print(f"{'size':>8} {'images':>6} {'wall s':>7} {'render s':>8} {'encode s':>8} {'ms/img':>7} {'MB':>6}")
            for size in ((640, 480), (320, 240)):
                r = bench_synth(size, seconds, workdir)
                print(f"{r['size']:>8} {r['images']:>6} {r['wall_s']:7.1f} {r['render_s']:8.1f} "
                      f"{r['encode_s']:8.1f} {r['ms_per_image']:7.1f} {r['MB']:6.1f}")
                if size == (640, 480):
                    projected = r["ms_per_image"] * 1800 / 1e3
                    ok = projected <= TARGET_S
                    status |= 0 if ok else 1
                    print(f"  target: 1800 images 640x480 in <= {TARGET_S:.0f} s -> "
                          f"{projected:.1f} s ({'PASS' if ok else 'MISS'})")
        print("\ncodecs: 60 rendered 640x480 frames of cam_1 (median per frame)")
        print(f"{'codec':>6} {'KB/frame':>9} {'enc ms':>7} {'dec ms':>7} {'seek ms':>8} {'PSNR dB':>8}")
        for r in bench_codecs(_frames(60, (640, 480)), workdir):
            if "error" in r:
                print(f"{r['codec']:>6} {r['error']}")
                continue
            print(f"{r['codec']:>6} {r['KB_per_frame']:9.1f} {r['encode_ms']:7.2f} {r['decode_ms']:7.2f} "
                  f"{r['seek_ms']:8.2f} {r['psnr_db']:8.1f}")
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
