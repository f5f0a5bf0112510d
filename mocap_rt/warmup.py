"""Compile every numba kernel once, in one process, into the cache every process reads.

The library's kernels are ``@njit(cache=True)``: the first process that calls one compiles
it (seconds each, a minute or more for all of them on a small machine) and saves it in
numba's cache; later processes load it in milliseconds. Left to the first use, the six
camera workers, the hot spare and fusion of a first ``mocap-rt run`` would all compile the
same kernels at once. ``ensure_warm`` does it once instead, before anything else starts
(``make setup``, the launcher when it finds the cache cold, the test session):

* it runs the real frame path on a tiny studio scene: render ``WARM_SECONDS`` of a walk
  (studio kernels), perceive it with predictions (perception kernels), fuse it and solve IK
  (triangulation, CCD/Jacobian, analytic IK, BVH export) — every kernel the service, the
  demo and ``mocap-rt process`` call, with the argument types they call it with;
* it writes a stamp (``stamp_path()``) holding a digest of the kernel sources (every module
  of ``mocap_rt`` that uses numba), numba's and Python's versions and the cache directory.
  ``is_warm()`` compares it without importing numba (milliseconds).

numba invalidates a cached kernel when its own file changes, but not when a kernel it calls
in another file changed (``ik_kernels`` and ``analytic`` call ``kinematics``'):
so when the digest differs, every kernel's cache entry is dropped first and all are built
again. The cache lives where numba puts it: ``__pycache__`` beside each source file, or
``$NUMBA_CACHE_DIR`` when set (every process started with that environment shares it).
A file lock lets concurrent callers wait for one warm-up instead of doing it twice.

    python -m mocap_rt.warmup [--motion CLIP.bvh | --rec REC_DIR] [--force] [--check]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import os
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from mocap_rt.io.files import atomic_write_text
from mocap_rt.shared_data import data_root

PACKAGE_DIR = Path(__file__).resolve().parent
STAMP_NAME = "mocap_rt-numba-kernels.json"
DEFAULT_CLIP = "bvh/cmu/cmu_02_01_walk.bvh"     # under $MOCAP_RT_DATA
WARM_SIZE = (320, 240)                          # image size of the warm-up scene (px)
WARM_SECONDS = 1.0                              # frames of it: perception tracks, fusion predicts
WARM_CAMERAS = 6
SYNTHETIC_SCENE = "synthetic frames"            # the stamp's scene without a clip or a recording


def kernel_sources() -> list[Path]:
    """The package's modules that use numba (sorted): what the cache depends on."""
    return sorted(p for p in PACKAGE_DIR.rglob("*.py")
                  if "__pycache__" not in p.parts and "numba" in p.read_text(errors="replace"))


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
    return ".".join(rel.parts)


def sources_digest() -> str:
    """SHA-256 of the kernel sources, numba's and Python's versions and the cache dir."""
    from importlib.metadata import version

    h = hashlib.sha256()
    h.update(f"numba {version('numba')} python {sys.version_info[:3]} "
             f"cache {os.environ.get('NUMBA_CACHE_DIR', '')}".encode())
    for p in kernel_sources():
        h.update(str(p.relative_to(PACKAGE_DIR)).encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def stamp_path() -> Path:
    """Where the stamp lives: in ``$NUMBA_CACHE_DIR`` if set, else beside the package's
    own ``__pycache__`` (a read-only install: the temp dir)."""
    base = os.environ.get("NUMBA_CACHE_DIR")
    d = Path(base) if base else PACKAGE_DIR / "__pycache__"
    try:
        d.mkdir(parents=True, exist_ok=True)
        if os.access(d, os.W_OK):
            return d / STAMP_NAME
    except OSError:
        pass
    return Path(tempfile.gettempdir()) / STAMP_NAME


def read_stamp() -> dict | None:
    try:
        return json.loads(stamp_path().read_text())
    except (OSError, ValueError):
        return None


def is_warm() -> bool:
    """True when ``ensure_warm`` ran for exactly these kernel sources (no numba import) and,
    when the data's clip is at hand (``default_motion``), not on synthetic frames only: those
    compile about half the kernels' signatures (56 of the walk's), and a cluster started on
    such a cache compiled the rest in every node at once (all six cameras silent for ~3 s of
    the demo)."""
    stamp = read_stamp()
    if not stamp or stamp.get("digest") != sources_digest():
        return False
    return stamp.get("scene") != SYNTHETIC_SCENE or default_motion() is None


@contextmanager
def _locked():
    import fcntl

    path = stamp_path().with_suffix(".lock")
    with open(path, "a+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def cached_dispatchers(packages: tuple[str, ...] = ("mocap_rt",)) -> list:
    """Every ``cache=True`` numba dispatcher of the modules under ``packages`` (imports
    those kernel modules)."""
    from numba.core.dispatcher import Dispatcher

    out, seen = [], set()
    for path in kernel_sources():
        if not _module_name(path).startswith(packages):
            continue
        mod = importlib.import_module(_module_name(path))
        for obj in vars(mod).values():
            if isinstance(obj, Dispatcher) and getattr(obj, "_cache", None) is not None \
                    and obj.__module__ == mod.__name__ and id(obj) not in seen \
                    and type(obj._cache).__name__ != "NullCache":
                seen.add(id(obj))
                out.append(obj)
    return out


def clear_cache(dispatchers) -> None:
    """Drop every cached entry of ``dispatchers`` (their index files are emptied)."""
    for d in dispatchers:
        d._cache.flush()


def _compiled(dispatchers) -> tuple[int, int]:
    """(signatures compiled in this process, signatures loaded from the cache)."""
    misses = sum(sum(d.stats.cache_misses.values()) for d in dispatchers)
    hits = sum(sum(d.stats.cache_hits.values()) for d in dispatchers)
    return misses, hits


SERVICE_PACKAGES = ("mocap_rt.perception", "mocap_rt.body", "mocap_rt.geometry", "mocap_rt.fusion")


def load_cached_kernels(packages: tuple[str, ...] = SERVICE_PACKAGES) -> tuple[int, float]:
    """Load every signature the cache holds for the kernels of ``packages`` now, instead of
    at each kernel's first call (a frame that first takes a new code path, e.g. the first
    with a prediction, would otherwise wait for the load). Never compiles: only entries whose
    index key matches this machine and this bytecode are loaded. Returns (loaded, seconds)."""
    t0 = time.perf_counter()
    n = 0
    for d in cached_dispatchers(packages):
        try:
            codegen = d.targetctx.codegen()
            for key in list(d._cache._cache_file._load_index()):
                sig = key[0]
                if d._cache._index_key(sig, codegen) == key:
                    d.compile(sig)
                    n += 1
        except Exception:  # numba internals changed: the kernels load at their first call
            continue
    return n, time.perf_counter() - t0


def default_motion() -> Path | None:
    """``$MOCAP_RT_DATA/bvh/cmu/cmu_02_01_walk.bvh`` when it exists; without the variable, the
    project's data beside the checkout (``../shared/data``, where the benches read it): a bench
    run from a plain shell had warmed the cache on synthetic frames and stamped it warm, and the
    service run after it compiled the rest in its nodes (69 of 1801 frames lost at its start)."""
    p = data_root() / DEFAULT_CLIP
    return p if p.is_file() else None


def exercise(motion: Path | None, work: Path, rec: Path | None = None) -> None:
    """Run the frame path once: perceive with predictions, fuse, IK, BVH export on the first
    ``WARM_SECONDS`` of recording ``rec``, or of a scene rendered from ``motion`` (studio
    kernels too). With neither: perception on synthetic frames and fusion on synthetic cues
    (what a node's own warm-up runs)."""
    from mocap_rt.fusion.offline import process_recording
    from mocap_rt.studio.synth import make_rig

    rig = make_rig(n_cameras=WARM_CAMERAS, size=WARM_SIZE)
    if rec is not None:
        from mocap_rt.io.recording import Recording

        n = max(2, int(round(WARM_SECONDS * Recording(rec).fps)))
        process_recording(rec, work / "poses", max_frames=n, progress=False)
        return
    if motion is not None:
        from mocap_rt.studio.synth import synthesize

        scene = work / "scene"
        synthesize(motion, scene, rig=rig, seconds=WARM_SECONDS, truth_masks=True, threads=1)
        process_recording(scene, work / "poses", progress=False)
        return
    import numpy as np

    from mocap_rt.body.calibrate import frame_costs
    from mocap_rt.body.silhouette import SilhouetteTargets
    from mocap_rt.cues import N_CUES, CameraCues, CompactSilhouette
    from mocap_rt.fusion.config import FusionConfig
    from mocap_rt.fusion.tracker import BodyTracker
    from mocap_rt.perception.pipeline import CameraPerceiver

    cam = rig.cameras[0]
    w, h = cam.size
    noise = np.random.default_rng(0).integers(0, 8, (3, h, w, 3), dtype=np.uint8)
    bgs = noise + np.array([90, 100, 110], np.uint8)
    CameraPerceiver(cam, bgs).process(bgs[0], 0, None)
    tracker = BodyTracker(rig, FusionConfig(fps=30.0))
    pts = np.array([[0.0, 0.0, 1.7], [0.35, 0.0, 1.0], [-0.35, 0.0, 1.0], [0.12, 0.0, 0.05],
                    [-0.12, 0.0, 0.05], [0.0, 0.0, 1.25]])
    for f in range(3):
        cues = {}
        for c in rig.cameras:
            uv = c.project(pts + [0.01 * f, 0, 0])[0]
            cues[c.name] = CameraCues(c.name, f, uv, np.tile(np.eye(2) * 4.0, (N_CUES, 1, 1)), np.full(N_CUES, 50.0),
                                      np.ones(N_CUES), silhouette=CompactSilhouette.box_around(uv))
        tracker.step(f, cues)
        tracker.predict(f + 1)
    # the bone lengths' fit to the silhouettes (after the first seconds: body.calibrate)
    frame_costs(tracker.lengths, [(pts, np.eye(3), SilhouetteTargets.from_cues(rig.cameras, cues))])


def exercise_outputs() -> None:
    """The kernels off the frame path: the VMC stream's humanoid conversion and the
    GStreamer sources' I420 -> BGR (a first pose or frame must not wait for a compilation)."""
    import numpy as np

    from mocap_rt.body.bvh_export import bvh_frame
    from mocap_rt.body.humanoid import HumanoidRig, humanoid_pose_from_bvh_row
    from mocap_rt.body.skeleton import body_model
    from mocap_rt.io.yuv import i420_to_bgr

    model = body_model(None, "paper")
    humanoid_pose_from_bvh_row(HumanoidRig.of(model), model, bvh_frame(model, np.zeros(3), np.zeros((20, 3))))
    for writeable in (True, False):         # GStreamer's mapped buffers are read-only arrays
        y, chroma = np.zeros((2, 4), np.uint8), np.zeros((1, 2), np.uint8)
        y.flags.writeable = chroma.flags.writeable = writeable
        i420_to_bgr(y, chroma, chroma)


def _say(msg: str) -> None:
    print(msg, flush=True)


def ensure_warm(motion: Path | None = None, force: bool = False, log=_say, rec: Path | None = None) -> dict:
    """Build the kernel cache unless the stamp says it is warm (``exercise`` on ``rec``, else
    ``motion``, else ``default_motion()``); returns the stamp dict (``digest``,
    ``compiled``, ``loaded``, ``seconds``, ``scene``; ``skipped`` if it was warm)."""
    if not force and is_warm():
        return dict(read_stamp(), skipped=True)
    with _locked():
        if not force and is_warm():            # another process did it while we waited
            return dict(read_stamp(), skipped=True)
        t0 = time.perf_counter()
        digest = sources_digest()
        motion = None if rec is not None else (motion or default_motion())
        scene = f"recording {rec}" if rec else (f"rendering {motion}" if motion else SYNTHETIC_SCENE)
        log(f"warm-up: building the numba kernel cache once, in one process ({scene}) ...")
        dispatchers = cached_dispatchers()
        held = [d.__name__ for d in dispatchers if d.signatures]
        if held:       # numba never writes a kernel it already holds: the cache would stay empty
            raise RuntimeError(f"warm-up must run in a fresh process (`python -m mocap_rt.warmup`): "
                               f"{len(held)} kernels are already compiled in this one ({', '.join(held[:3])} ...)")
        clear_cache(dispatchers)               # callers' caches may hold a changed callee
        with tempfile.TemporaryDirectory(prefix="mocap-rt-warmup-") as tmp:
            exercise(motion, Path(tmp), rec)
        exercise_outputs()
        compiled, loaded = _compiled(dispatchers)
        stamp = {"digest": digest, "compiled": compiled, "loaded": loaded,
                 "kernels": len(dispatchers), "seconds": round(time.perf_counter() - t0, 1),
                 "scene": scene, "time": time.time()}
        path = stamp_path()
        atomic_write_text(path, json.dumps(stamp, indent=1))
        log(f"warm-up: {compiled} kernel signatures compiled in {stamp['seconds']:.1f} s "
            f"({len(dispatchers)} cached kernels; stamp {path})")
        return stamp


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--motion", type=Path, default=None,
                   help=f"BVH clip to render the warm-up scene from (default: $MOCAP_RT_DATA/{DEFAULT_CLIP}; "
                        "none: synthetic frames)")
    p.add_argument("--rec", type=Path, default=None,
                   help="a recording directory to run the frame path on instead of rendering a scene")
    p.add_argument("--force", action="store_true", help="rebuild even if the stamp says warm")
    p.add_argument("--check", action="store_true", help="only report: exit 0 if warm, 1 if cold")
    args = p.parse_args(argv)
    if args.check:
        warm = is_warm()
        print(f"numba kernel cache {'warm' if warm else 'cold'} ({stamp_path()})")
        return 0 if warm else 1
    if args.motion is not None and not args.motion.is_file():
        print(f"warm-up: --motion {args.motion}: no such file", file=sys.stderr)
        return 2
    stamp = ensure_warm(args.motion, args.force, rec=args.rec)
    if stamp.get("skipped"):
        print(f"warm-up: numba kernel cache already warm ({stamp_path()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
