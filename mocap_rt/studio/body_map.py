"""BVH clip -> body points in the world frame (Z up, metres), driven by a data table.

The table (``mocap_rt/data/bvh_maps.toml``) says, per skeleton family, which BVH joints
or end sites make each body point of ``mocap_rt.names.JOINT_NAMES`` (plus the helper
points the studio's body shape needs), as affine combinations. This module evaluates it,
converts units and axes, resamples the clip to the output rate (slerp, so bone lengths
stay exact) and places the subject: the first frame's pelvis above the origin, the feet
on the floor.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from mocap_rt.config import FileFormatError, loads_toml
from mocap_rt.io.bvh import BvhClip, forward_kinematics, resample_motion
from mocap_rt.names import JOINT_NAMES, N_JOINTS, J

log = logging.getLogger(__name__)

# Helper points (beyond JOINT_NAMES) that every map must define, for the body shape.
AUX_NAMES: tuple[str, ...] = ("toe_l", "toe_r", "heel_l", "heel_r", "fingers_l", "fingers_r")
POINT_NAMES: tuple[str, ...] = JOINT_NAMES + AUX_NAMES
# Height (m) the lowest of the toe/heel points reaches over the clip: the shoe capsule
# radius (mocap_rt.studio.body_shape.SHOE_RADIUS_M), so the sole touches the floor.
FOOT_POINT_FLOOR_HEIGHT_M = 0.045
# Percentile of the per-frame lowest foot point that is put at that height (robust to
# single-frame glitches; jumps lift it, standing sets it).
FLOOR_PERCENTILE = 5.0
# Bones whose lengths the truth reports, as (from, to) in JOINT_NAMES.
BONES: tuple[tuple[str, str], ...] = (
    ("pelvis", "torso"), ("torso", "neck"), ("neck", "head"),
    ("neck", "shoulder_l"), ("shoulder_l", "elbow_l"), ("elbow_l", "wrist_l"), ("wrist_l", "hand_l"),
    ("neck", "shoulder_r"), ("shoulder_r", "elbow_r"), ("elbow_r", "wrist_r"), ("wrist_r", "hand_r"),
    ("pelvis", "hip_l"), ("hip_l", "knee_l"), ("knee_l", "ankle_l"), ("ankle_l", "foot_l"),
    ("pelvis", "hip_r"), ("hip_r", "knee_r"), ("knee_r", "ankle_r"), ("ankle_r", "foot_r"),
)
_TERM = re.compile(r"\s*([+-]?)\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s+([^\s+]+)\s*")
_META_KEYS = ("detect", "unit_m", "up")


class SkeletonMapError(FileFormatError):
    """The map table is malformed or no family matches a clip."""


@dataclass(frozen=True)
class SkeletonMap:
    """One family's map: ``points`` maps a point name to [(weight, source name), ...]."""

    family: str
    detect: tuple[str, ...]
    unit_m: float
    up: str
    points: dict[str, list[tuple[float, str]]]


def parse_combination(expr: str, where: str) -> list[tuple[float, str]]:
    """Parse "1.5 A - 0.5 B" into [(1.5, "A"), (-0.5, "B")]; weights must sum to 1."""
    terms, pos = [], 0
    expr = expr.strip()
    while pos < len(expr):
        m = _TERM.match(expr, pos)
        if m is None or (terms and not m.group(1)):
            raise SkeletonMapError(f"{where}: cannot parse {expr!r} at {expr[pos:]!r}")
        w = float(m.group(2)) * (-1.0 if m.group(1) == "-" else 1.0)
        terms.append((w, m.group(3)))
        pos = m.end()
    if not terms:
        raise SkeletonMapError(f"{where}: empty combination")
    total = sum(w for w, _ in terms)
    if abs(total - 1.0) > 1e-9:
        raise SkeletonMapError(f"{where}: weights of {expr!r} sum to {total}, not 1")
    return terms


def load_skeleton_maps(path: str | Path | None = None) -> list[SkeletonMap]:
    """Read the map table (default: the packaged ``bvh_maps.toml``), families in file order."""
    if path is None:
        text = resources.files("mocap_rt.data").joinpath("bvh_maps.toml").read_text()
        where = "mocap_rt/data/bvh_maps.toml"
    else:
        text, where = Path(path).read_text(), str(path)
    doc = loads_toml(text, where, SkeletonMapError)
    common = doc.pop("common", {})
    maps = []
    for family, table in doc.items():
        for key in _META_KEYS:
            if key not in table:
                raise SkeletonMapError(f"{where} [{family}]: missing {key!r}")
        if table["up"] not in ("Y", "Z"):
            raise SkeletonMapError(f"{where} [{family}]: up must be 'Y' or 'Z'")
        points = {}
        for name, expr in list(table.items()) + list(common.items()):
            if name in _META_KEYS:
                continue
            if name not in POINT_NAMES:
                raise SkeletonMapError(f"{where} [{family}]: unknown point {name!r}")
            points[name] = parse_combination(expr, f"{where} [{family}] {name}")
        missing = [n for n in POINT_NAMES if n not in points]
        if missing:
            raise SkeletonMapError(f"{where} [{family}]: points not defined: {missing}")
        maps.append(SkeletonMap(family, tuple(table["detect"]), float(table["unit_m"]),
                                table["up"], points))
    return maps


def find_map(names: list[str], maps: list[SkeletonMap] | None = None) -> SkeletonMap:
    """The first family whose ``detect`` joints are all among ``names``."""
    maps = load_skeleton_maps() if maps is None else maps
    have = set(names)
    for m in maps:
        if all(d in have for d in m.detect):
            return m
    raise SkeletonMapError(f"no skeleton map fits this BVH (joints {names[:8]}...); "
                           f"known families: {[m.family for m in maps]}")


def _axes_to_world(points: np.ndarray, up: str) -> np.ndarray:
    """(..., 3) file axes -> world (Z up). Y up: (x, y, z) -> (x, -z, y), a rotation."""
    if up == "Z":
        return points
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def map_points(clip_skeleton, positions_with_ends: np.ndarray, smap: SkeletonMap) -> np.ndarray:
    """Evaluate the map on FK output.

    positions_with_ends : (F, J + E, 3) from ``forward_kinematics(..., include_end_sites=True)``.
    Returns (F, len(POINT_NAMES), 3) in file units and axes.
    """
    src = {n: i for i, n in enumerate(clip_skeleton.names + clip_skeleton.end_site_names)}
    F = positions_with_ends.shape[0]
    done: dict[str, np.ndarray] = {}
    for name, terms in smap.points.items():
        acc = np.zeros((F, 3))
        for w, ref in terms:
            if ref in done:
                acc += w * done[ref]
            elif ref in src:
                acc += w * positions_with_ends[:, src[ref]]
            else:
                raise SkeletonMapError(f"[{smap.family}] {name}: {ref!r} is neither a BVH joint/end "
                                       "site of this file nor a point defined above")
        done[name] = acc
    return np.stack([done[n] for n in POINT_NAMES], axis=1)


@dataclass(frozen=True)
class BodyMotion:
    """Body points over time, world frame (right-handed, Z up, metres).

    points : (F, P, 3) float64 in ``POINT_NAMES`` order (the first 20 are JOINT_NAMES).
    times_s : (F,) float64 seconds from the clip's start.
    family : the skeleton map used.
    """

    points: np.ndarray
    times_s: np.ndarray
    family: str

    @property
    def joints(self) -> np.ndarray:
        """(F, 20, 3) in JOINT_NAMES order."""
        return self.points[:, :N_JOINTS]

    def point(self, name: str) -> np.ndarray:
        """(F, 3) one point's trajectory."""
        return self.points[:, POINT_NAMES.index(name)]

    def bone_lengths(self) -> np.ndarray:
        """(len(BONES),) median length of each bone over the clip, metres."""
        a = np.array([J[b[0]] for b in BONES])
        b = np.array([J[b[1]] for b in BONES])
        return np.median(np.linalg.norm(self.points[:, a] - self.points[:, b], axis=-1), axis=0)


def bone_names() -> list[str]:
    """Names of ``BONES``, "from-to"."""
    return [f"{a}-{b}" for a, b in BONES]


def body_motion(clip: BvhClip, fps: float | None = None, n_frames: int | None = None,
                start_s: float = 0.0, maps: list[SkeletonMap] | None = None,
                placement: str = "first") -> BodyMotion:
    """World body points of a clip, resampled to ``fps`` (default: the clip's own rate).

    n_frames : number of output frames (default: as many as the clip covers from start_s);
    past the clip's end the last pose is held. ``placement``: "first" puts the first
    frame's pelvis above the origin, "centre" the middle of the pelvis's horizontal range
    over the output frames (keeps a walk inside a camera ring), "none" keeps the file's
    position. Unless "none", the lowest foot points (FLOOR_PERCENTILE over the output
    frames) are put at FOOT_POINT_FLOOR_HEIGHT_M.
    """
    if placement not in ("first", "centre", "none"):
        raise ValueError(f"placement must be 'first', 'centre' or 'none', got {placement!r}")
    smap = find_map(clip.skeleton.names, maps)
    fps = clip.fps if fps is None else float(fps)
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    duration = (clip.n_frames - 1) * clip.frame_time_s
    if n_frames is None:
        n_frames = max(1, int(np.floor((duration - start_s) * fps + 1e-9)) + 1)
    times = start_s + np.arange(n_frames) / fps
    if np.allclose(fps, clip.fps, rtol=1e-6) and start_s == 0.0 and n_frames <= clip.n_frames:
        motion = clip.motion[:n_frames]
    else:
        motion = resample_motion(clip.skeleton, clip.motion, clip.frame_time_s, times)
    pos = forward_kinematics(clip.skeleton, motion, include_end_sites=True)
    pts = _axes_to_world(map_points(clip.skeleton, pos, smap), smap.up) * smap.unit_m
    if placement != "none":
        pelvis = pts[:, J["pelvis"], :2]
        origin = pelvis[0] if placement == "first" else 0.5 * (pelvis.min(axis=0) + pelvis.max(axis=0))
        feet = [POINT_NAMES.index(n) for n in ("toe_l", "toe_r", "heel_l", "heel_r")]
        low = np.percentile(pts[:, feet, 2].min(axis=1), FLOOR_PERCENTILE)
        pts = pts - np.array([origin[0], origin[1], low - FOOT_POINT_FLOOR_HEIGHT_M])
    return BodyMotion(pts, times - start_s, smap.family)
