"""The motion suite of the body and perception benches (issues 10 and 12).

Clips (``suite_clips``): every shared BVH clip (a 4 s segment), variants of a few of them
(time-reversed = walking backwards, mirrored, turned by a heading ramp) and the
procedural motions (``mocap_rt.studio.procedural``) at the tuning seed 0; ``held-out``
is the procedural set at seeds 1000+ (never used for tuning) plus variants at other
turn rates; ``quick`` is four clips (a backwards walk, jumping jacks while turning, the
modern dance, hands crossing in front of the face).

Recordings are rendered once (6-camera ring, 30 fps, studio defaults) and cached under
``bench/out/suite/<clip>[_g<generator version>]_<rig><W>x<H>_r<render seed>`` (or
``$MOCAP_RT_SUITE_CACHE``); an interrupted render is redone.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from mocap_rt.shared_data import data_root

REPO = Path(__file__).resolve().parents[1]
# MOCAP_RT_SUITE_CACHE: share the renders between worktrees (they are deterministic)
CACHE = Path(os.environ.get("MOCAP_RT_SUITE_CACHE", REPO / "bench" / "out" / "suite"))
SEGMENT_S = 4.0
START_S = 1.0
PROC_START_S = 0.8
HELD_OUT_SEED = 1000
PROCEDURAL = ("sidestep", "crouch", "arms_overhead", "hands_cross_face", "jump", "jumping_jacks", "clap",
              "hands_on_head", "hand_behind_head", "crouch_hands_to_feet", "feet_cross", "turn_in_place")
# procedural clips with contacts and crossings (the perception hard cases, issue 12)
CONTACT = ("hands_cross_face", "clap", "hands_on_head", "hand_behind_head", "arms_overhead",
           "crouch_hands_to_feet", "feet_cross", "jumping_jacks")


@dataclass(frozen=True)
class SuiteClip:
    """One suite entry. motion: a BVH path relative to the data root's ``bvh/`` or
    ``procedural:NAME:SEED``; variant: see ``mocap_rt.studio.variants``; start_s, seconds:
    the segment rendered; kind: shared / variant / procedural / held-out."""

    name: str
    motion: str
    variant: str | None
    start_s: float
    seconds: float
    kind: str

    def spec(self) -> str:
        return self.motion if self.motion.startswith("procedural:") else str(data_root() / "bvh" / self.motion)


def _shared() -> list[SuiteClip]:
    root = data_root() / "bvh"
    return [SuiteClip(p.stem, str(p.relative_to(root)), None, START_S, SEGMENT_S, "shared")
            for p in sorted(root.glob("*/*.bvh"))]


_VARIANTS = (  # (name, clip, variant, start)
    ("walk_backwards_131_01", "cmu/cmu_131_01_start_walk_stop.bvh", "reversed", 2.0),
    ("walk_backwards_02_01", "cmu/cmu_02_01_walk.bvh", "reversed", 0.0),
    ("dance_05_06_mirrored", "cmu/cmu_05_06_modern_dance.bvh", "mirrored", 1.0),
    ("walk_bandai_mirrored", "bandai_namco/dataset-1_walk_normal_001.bvh", "mirrored", 0.5),
    ("walk_02_01_turn45", "cmu/cmu_02_01_walk.bvh", "turn:45", 0.0),
    ("hop_131_03_turn90", "cmu/cmu_131_03_start_hop_stop.bvh", "turn:90", 1.0),
    ("dance_05_06_reversed_turn60", "cmu/cmu_05_06_modern_dance.bvh", "reversed+turn:60", 1.0),
)
_HELD_OUT_VARIANTS = (
    ("walk_backwards_131_01_turn-30", "cmu/cmu_131_01_start_walk_stop.bvh", "reversed+turn:-30", 1.5),
    ("dance_bandai_mirrored_turn70", "bandai_namco/dataset-1_dance-short_normal_001.bvh", "mirrored+turn:70", 10.0),
    ("kick_bandai_reversed", "bandai_namco/dataset-1_kick_normal_001.bvh", "reversed", 0.0),
)


def _variants(table) -> list[SuiteClip]:
    return [SuiteClip(n, c, v, s, SEGMENT_S, "variant") for n, c, v, s in table]


def _procedural(seed: int, kind: str, names=PROCEDURAL) -> list[SuiteClip]:
    return [SuiteClip(f"proc_{n}_s{seed + i if kind == 'held-out' else seed}",
                      f"procedural:{n}:{seed + i if kind == 'held-out' else seed}", None, PROC_START_S, SEGMENT_S, kind)
            for i, n in enumerate(names)]


def suite_clips(which: str = "default") -> list[SuiteClip]:
    """``default`` (shared + variants + procedural seed 0), ``quick``, ``held-out`` or ``all``."""
    default = _shared() + _variants(_VARIANTS) + _procedural(0, "procedural")
    held = _variants(_HELD_OUT_VARIANTS) + _procedural(HELD_OUT_SEED, "held-out")
    if which == "default":
        return default
    if which == "held-out":
        return held
    if which == "all":
        return default + held
    if which == "quick":
        want = ("walk_backwards_131_01", "proc_jumping_jacks_s0", "cmu_05_06_modern_dance", "proc_hands_cross_face_s0")
        return [c for c in default if c.name in want]
    raise ValueError(f"suite must be default, quick, held-out or all, got {which!r}")


def _procedural_named(name: str) -> SuiteClip | None:
    """``proc_<motion>_s<seed>`` for any seed (fresh held-out clips, e.g. ``proc_feet_cross_s2020``), else None."""
    for motion in PROCEDURAL:
        seed = name.removeprefix(f"proc_{motion}_s")
        if seed != name and seed.isdigit():
            return SuiteClip(name, f"procedural:{motion}:{seed}", None, PROC_START_S, SEGMENT_S, "held-out")
    return None


def _window_named(name: str) -> SuiteClip | None:
    """``<shared clip>@<start s>``: another 4-s window of a shared recording (fresh held-out real
    motion, e.g. ``cmu_01_01_playground_forward_jumps@14``), else None."""
    stem, at, start = name.partition("@")
    shared = {c.name: c for c in _shared()}
    if not at or stem not in shared:
        return None
    try:
        start_s = float(start)
    except ValueError:
        return None
    return SuiteClip(name, shared[stem].motion, None, start_s, SEGMENT_S, "held-out") if start_s >= 0 else None


def select(clips: list[SuiteClip], names: str | None) -> list[SuiteClip]:
    """Clips whose name is in the comma-separated ``names`` (all when None; ``proc_<motion>_s<seed>`` at
    any seed and ``<shared clip>@<start s>`` too); unknown names raise."""
    if not names:
        return clips
    pool = {c.name: c for c in suite_clips("all") + clips}
    wanted = [n.strip() for n in names.split(",") if n.strip()]
    pool.update({n: c for n in wanted if n not in pool and (c := _procedural_named(n) or _window_named(n)) is not None})
    unknown = [n for n in wanted if n not in pool]
    if unknown:
        raise SystemExit(f"unknown suite clip(s) {unknown}; known: {', '.join(sorted(pool))}")
    return [pool[n] for n in wanted]


def ensure_recording(clip: SuiteClip, size: tuple[int, int] = (640, 480), rig: str = "ring",
                     render_seed: int = 0) -> Path:
    """The clip's studio recording (rendered on first use, then cached)."""
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    from mocap_rt.studio.procedural import GENERATOR_VERSION

    gen = f"_g{GENERATOR_VERSION}" if clip.motion.startswith("procedural:") else ""
    out = CACHE / f"{clip.name}{gen}_{rig}{size[0]}x{size[1]}_r{render_seed}"
    if (out / "truth.npz").exists():
        return out
    CACHE.mkdir(parents=True, exist_ok=True)
    with open(CACHE / f".{out.name}.lock", "w") as lock:       # one renderer per clip, across processes
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (out / "truth.npz").exists():
            return out
        if out.exists():
            shutil.rmtree(out)                   # an interrupted earlier render
        bvh, name = load_motion(clip.spec(), clip.variant)
        duration = (bvh.n_frames - 1) * bvh.frame_time_s
        if "@" in clip.name and clip.start_s >= duration:        # a named window must lie in its recording
            raise SystemExit(f"{clip.name}: starts at {clip.start_s:g} s, but {clip.motion} is {duration:.1f} s long")
        start = min(clip.start_s, max(0.0, duration - clip.seconds))
        seconds = min(clip.seconds, duration - start)
        synthesize(bvh, out, rig=make_rig(rig, size=size), fps=30.0, seconds=seconds, start_s=start,
                   seed=render_seed, motion_name=name)
    return out


if __name__ == "__main__":   # render the whole suite ahead of the benches
    import sys

    for c in suite_clips(sys.argv[1] if len(sys.argv) > 1 else "default"):
        print(c.name, ensure_recording(c), flush=True)
