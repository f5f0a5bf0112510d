"""Procedural motions on the CMU skeleton: a pose script -> BVH motion (pure numpy).

A motion is a ``Script``: per frame, in the world frame (right-handed, Z up, metres),
the pelvis (the BVH ``Hips`` joint) position, the body's heading, trunk and neck bend,
the ankle positions and foot headings, the hand centres (``mocap_rt.names`` semantics:
wrist -> fingertips midpoint) and the directions the elbows and knees point to.
``solve_script`` turns it into BVH channel values on a CMU MotionBuilder skeleton
(the hierarchy of ``cmu_02_01_walk.bvh``): the trunk chain by rotations, each limb by a
two-link IK (``mocap_rt.body.analytic._two_link``) whose bone frames are built from
the limb plane, so the elbow and knee are pure hinges and bone lengths are exact.

The motions themselves (``procedural_motions.py``) are smooth keyframe scripts; each
takes a seed that varies amplitudes, tempo, heading and side, so held-out seeds give
clips that differ from the tuning ones. ``procedural_motions.generate(name, seed)`` returns a
``BvhClip``.

Frames: the CMU file has Y up, the subject facing +Z with its left on +X at rest;
world = ``AXES @ file`` = (x, -z, y), so at rest the subject faces world -Y.
"""

from __future__ import annotations

import zlib
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.body.analytic import _two_link
from mocap_rt.io.bvh import BvhClip, BvhSkeleton, joint_transforms, read_bvh
from mocap_rt.shared_data import data_root
from mocap_rt.studio.body_map import POINT_NAMES, find_map, map_points

# The skeleton every procedural clip uses (relative to the shared data root).
SKELETON_CLIP = Path("bvh") / "cmu" / "cmu_02_01_walk.bvh"
AXES = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])   # file -> world
DEFAULT_FPS = 60.0
DEFAULT_SECONDS = 6.0
# Fraction of the full leg length between hip and ankle when standing.
STAND_LEG_FRAC = 0.99
SIDES = ("Left", "Right")
# Toe-tip above the heel point of a standing foot, degrees (the shared clips: -9.5 to -11.5).
FOOT_PITCH_DEG = -10.0
# Bumped when the generator changes what a (name, seed) produces (cached renders key on it).
GENERATOR_VERSION = 2
PELVIS_TILT_FRAC = 0.4    # share of the trunk's forward bend taken by the pelvis (the rest: 3 x 0.2)


@lru_cache(maxsize=4)
def cmu_skeleton(path: str | None = None) -> BvhSkeleton:
    """The CMU hierarchy the procedural motions are built on (default: ``SKELETON_CLIP``)."""
    p = Path(path) if path else data_root() / SKELETON_CLIP
    if not p.is_file():
        raise FileNotFoundError(f"procedural skeleton: no BVH at {p} (set MOCAP_RT_DATA)")
    return read_bvh(p).skeleton


@dataclass
class Script:
    """A motion, F frames, world frame (Z up), metres and radians; side 0 = left, 1 = right.

    pelvis (F, 3) position of the Hips joint; heading (F,) direction the body faces,
    angle of the forward axis from +X towards +Y; trunk (F, 3) forward bend, bend to the
    left, twist to the left (split over the three spine joints); neck (F,) forward nod;
    ankles (F, 2, 3); foot_heading (F, 2); hands (F, 2, 3) hand centres; elbow_pole and
    knee_pole (F, 2, 3) directions the elbow / knee is bent towards.
    """

    pelvis: np.ndarray
    heading: np.ndarray
    trunk: np.ndarray
    neck: np.ndarray
    ankles: np.ndarray
    foot_heading: np.ndarray
    hands: np.ndarray
    elbow_pole: np.ndarray
    knee_pole: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """(..., 3, 3) frames with columns (x, y, z): z along ``z``, x nearest ``x_hint``."""
    z = _unit(z)
    x = _unit(x_hint - z * np.sum(x_hint * z, axis=-1, keepdims=True))
    return np.stack([x, np.cross(z, x), z], axis=-1)


def _rot(axis: str, angle: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations about a world/body axis letter by ``angle`` (F,) radians."""
    return Rotation.from_euler(axis, np.asarray(angle, dtype=np.float64).reshape(-1, 1)).as_matrix()


@dataclass(frozen=True)
class SkeletonGeometry:
    """What the solver needs of the CMU hierarchy, world axes, metres."""

    skeleton: BvhSkeleton
    unit_m: float
    offsets: np.ndarray            # (J, 3) offsets in world axes, metres
    ankle_height_m: float          # ankle height when the foot stands flat on the floor
    landmarks: dict                # standing pose, heading 0 (facing +X), pelvis over origin
    foot_tilt_rad: float = 0.0     # toe-down rotation of the foot that gives FOOT_PITCH_DEG

    def index(self, name: str) -> int:
        return self.skeleton.index(name)

    def length(self, name: str) -> float:
        return float(np.linalg.norm(self.offsets[self.index(name)]))

    @property
    def arm_m(self) -> float:
        """Shoulder -> hand centre, straight arm."""
        return self.length("LeftForeArm") + 1.45 * self.length("LeftHand")


def _motion_from_globals(skel: BvhSkeleton, unit_m: float, root_m: np.ndarray, glob: dict) -> np.ndarray:
    """BVH motion (F, n_channels) from world-axes global rotations (joints not in ``glob``
    keep their parent's frame) and the root position (F, 3) metres, world."""
    F = root_m.shape[0]
    motion = np.zeros((F, skel.n_channels))
    starts = skel.channel_starts
    g_file = []
    root_file = (root_m @ AXES) / unit_m          # world rows -> file rows, file units
    for j, joint in enumerate(skel.joints):
        if joint.name in glob:
            g = AXES.T @ glob[joint.name] @ AXES
        else:
            g = g_file[joint.parent] if joint.parent >= 0 else np.broadcast_to(np.eye(3), (F, 3, 3))
        g_file.append(g)
        local = g if joint.parent < 0 else np.swapaxes(g_file[joint.parent], -1, -2) @ g
        rot_axes = "".join(c[0] for c in joint.channels if c.endswith("rotation")).upper()
        rot_cols = [int(starts[j]) + k for k, c in enumerate(joint.channels) if c.endswith("rotation")]
        pos_cols = {c[0]: int(starts[j]) + k for k, c in enumerate(joint.channels) if c.endswith("position")}
        if rot_axes:
            with warnings.catch_warnings():   # gimbal lock: scipy still returns the exact rotation
                warnings.simplefilter("ignore", UserWarning)
                ang = Rotation.from_matrix(local).as_euler(rot_axes, degrees=True)
            motion[:, rot_cols] = np.unwrap(ang, period=360.0, axis=0)
        for axis, col in pos_cols.items():
            i = "XYZ".index(axis)
            motion[:, col] = root_file[:, i] if joint.parent < 0 else joint.offset[i]
    return motion


def _positions_m(skel: BvhSkeleton, unit_m: float, motion: np.ndarray) -> np.ndarray:
    """(F, J, 3) joint positions, world axes, metres (the I/O module's FK)."""
    return joint_transforms(skel, motion)[1] @ AXES.T * unit_m


def _trunk_globals(g: SkeletonGeometry, s: Script) -> dict:
    yaw = _rot("z", s.heading + np.pi / 2)                 # rest faces -Y: turn to the heading
    # forward bend: 40 % pelvis tilt, 20 % per spine joint; side bend and twist over the spine
    third = _rot("x", 0.2 * s.trunk[:, 0]) @ _rot("y", s.trunk[:, 1] / 3) @ _rot("z", s.trunk[:, 2] / 3)
    prev = yaw @ _rot("x", PELVIS_TILT_FRAC * s.trunk[:, 0])
    glob = {"Hips": prev}
    for name in ("LowerBack", "Spine", "Spine1"):
        prev = prev @ third
        glob[name] = prev
    glob["Neck1"] = prev @ _rot("x", s.neck / 2)
    glob["Head"] = glob["Neck1"] @ _rot("x", s.neck / 2)
    return glob


def _limb(root: np.ndarray, goal: np.ndarray, l1: float, l2: float, pole: np.ndarray):
    """Two-link IK per frame: (mid (F, 3), end (F, 3), hinge axis (F, 3) = unit(w x u))."""
    F = root.shape[0]
    mid, end, hinge = np.empty((F, 3)), np.empty((F, 3)), np.empty((F, 3))
    pole = _unit(pole)
    for f in range(F):
        m, e, u, w = _two_link(root[f], goal[f], l1, l2, pole[f])
        mid[f], end[f], hinge[f] = m, e, np.cross(w, u)
    return mid, end, _unit(hinge)


def _bone_rotation(g: SkeletonGeometry, child: str, direction: np.ndarray, hinge: np.ndarray,
                   rest_hinge: np.ndarray) -> np.ndarray:
    """(F, 3, 3) global rotation taking the rest bone towards ``child`` onto ``direction``
    with the rest hinge axis onto ``hinge``."""
    rest = _frame(g.offsets[g.index(child)], rest_hinge)
    return _frame(direction, hinge) @ rest.T


def solve_script(g: SkeletonGeometry, s: Script) -> np.ndarray:
    """BVH motion (F, n_channels) of ``g.skeleton`` performing the script."""
    skel = g.skeleton
    glob = _trunk_globals(g, s)
    motion0 = _motion_from_globals(skel, g.unit_m, s.pelvis, glob)
    pos0 = _positions_m(skel, g.unit_m, motion0)
    F = s.pelvis.shape[0]
    for k, side in enumerate(SIDES):
        # arm: shoulder -> elbow -> hand centre (the forearm extended by 45 % to the hand centre)
        sh = pos0[:, skel.index(f"{side}Arm")]
        l_up, l_fo = g.length(f"{side}ForeArm"), g.length(f"{side}Hand")
        elbow, hand, hinge = _limb(sh, s.hands[:, k], l_up, 1.45 * l_fo, s.elbow_pole[:, k])
        wrist = elbow + (hand - elbow) / 1.45
        rest_h = np.array([0.0, 1.0, 0.0])
        glob[f"{side}Arm"] = _bone_rotation(g, f"{side}ForeArm", elbow - sh, hinge, rest_h)
        glob[f"{side}ForeArm"] = _bone_rotation(g, f"{side}Hand", wrist - elbow, hinge, rest_h)
        # leg: hip -> knee -> ankle; the foot flat, turned to its heading
        hip = pos0[:, skel.index(f"{side}UpLeg")]
        knee, ankle, hinge = _limb(hip, s.ankles[:, k], g.length(f"{side}Leg"), g.length(f"{side}Foot"),
                                   s.knee_pole[:, k])
        lat = np.array([1.0, 0.0, 0.0])
        glob[f"{side}UpLeg"] = _bone_rotation(g, f"{side}Leg", knee - hip, hinge, lat)
        glob[f"{side}Leg"] = _bone_rotation(g, f"{side}Foot", ankle - knee, hinge, lat)
        down = np.broadcast_to([0.0, 0.0, -1.0], (F, 3))
        level = _bone_rotation(g, f"{side}Foot", down, np.broadcast_to(lat, (F, 3)), lat)
        tilt = _rot("x", np.full(F, g.foot_tilt_rad))
        glob[f"{side}Foot"] = _rot("z", s.foot_heading[:, k] + np.pi / 2) @ tilt @ level
    return _motion_from_globals(skel, g.unit_m, s.pelvis, glob)


def body_points(g: SkeletonGeometry, motion: np.ndarray) -> dict[str, np.ndarray]:
    """Body points of ``mocap_rt.studio.body_map.POINT_NAMES`` (F, 3) world, metres."""
    from mocap_rt.io.bvh import forward_kinematics

    smap = find_map(g.skeleton.names)
    pos = forward_kinematics(g.skeleton, motion, include_end_sites=True)
    pts = map_points(g.skeleton, pos, smap) @ AXES.T * smap.unit_m
    return {n: pts[:, i] for i, n in enumerate(POINT_NAMES)}


def _standing_script(g_partial, pelvis_z: float, ankle_z: float, land: dict | None = None) -> Script:
    """One frame standing, facing +X, pelvis above the origin, arms hanging."""
    hip = (land or {}).get("hip_offsets", np.array([[0.047, 0.077, -0.10], [0.047, -0.077, -0.10]]))
    ankles = np.array([[hip[0, 0], hip[0, 1], ankle_z], [hip[1, 0], hip[1, 1], ankle_z]])[None]
    hands = np.array([[0.0, 0.25, pelvis_z - 0.1], [0.0, -0.25, pelvis_z - 0.1]])[None]
    return Script(np.array([[0.0, 0.0, pelvis_z]]), np.zeros(1), np.zeros((1, 3)), np.zeros(1), ankles,
                  np.zeros((1, 2)), hands, np.array([[[-1.0, 0.3, 0], [-1.0, -0.3, 0]]]),
                  np.array([[[1.0, 0, 0], [1.0, 0, 0]]]))


@lru_cache(maxsize=4)
def skeleton_geometry(skeleton_path: str | None = None) -> SkeletonGeometry:
    """Geometry of the CMU skeleton: offsets, the standing ankle height and landmarks of
    the standing pose (``landmarks[name]`` (3,) for every body point, plus
    ``hip_offsets`` (2, 3) hip joints relative to the pelvis), facing +X."""
    skel = cmu_skeleton(skeleton_path)
    unit = find_map(skel.names).unit_m
    offsets = skel.offsets @ AXES.T * unit
    g = SkeletonGeometry(skel, unit, offsets, 0.0, {})
    # hip joints relative to the pelvis from the trunk alone
    probe = _standing_script(g, 1.0, 0.0)
    pos = _positions_m(skel, unit, _motion_from_globals(skel, unit, probe.pelvis, _trunk_globals(g, probe)))
    hips = np.stack([pos[0, skel.index(f"{s}UpLeg")] for s in SIDES]) - probe.pelvis[0]
    land = {"hip_offsets": hips}
    leg = STAND_LEG_FRAC * min(g.length(f"{s}Leg") + g.length(f"{s}Foot") for s in SIDES)
    pelvis_z = 1.0 - hips[0, 2] + leg
    tilt = 0.0
    for _ in range(4):          # the foot's tilt: toe-tip to heel at FOOT_PITCH_DEG (the heel point moves too)
        g = SkeletonGeometry(skel, unit, offsets, 0.0, land, tilt)
        pts = body_points(g, solve_script(g, _standing_script(g, pelvis_z, 1.0, land)))
        d = pts["toe_l"][0] - pts["heel_l"][0]
        tilt += np.arctan2(d[2], np.hypot(d[0], d[1])) - np.radians(FOOT_PITCH_DEG)
    # ankle height: the lowest toe/heel point on the floor
    low = min(float(pts[n][0, 2]) for n in ("toe_l", "toe_r", "heel_l", "heel_r"))
    ankle_h = 1.0 - low
    pelvis_z = ankle_h - hips[0, 2] + leg
    g = SkeletonGeometry(skel, unit, offsets, ankle_h, land, tilt)
    pts = body_points(g, solve_script(g, _standing_script(g, pelvis_z, ankle_h, land)))
    land.update({n: v[0] for n, v in pts.items()})
    land["pelvis_z"] = pelvis_z
    return g


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk blend 0 -> 1 for ``s`` in [0, 1] (clipped)."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10 - 15 * s + 6 * s * s)


@dataclass
class Timeline:
    """Frame times and the seed's draws. t (F,) seconds; amp, tempo factors; heading0 rad;
    side 0/1 (the leading or active side); rng for motion-specific draws."""

    t: np.ndarray
    seconds: float
    amp: float
    tempo: float
    heading0: float
    side: int
    rng: np.random.Generator

    @classmethod
    def make(cls, name: str, seed: int, seconds: float, fps: float) -> "Timeline":
        rng = np.random.default_rng([zlib.crc32(name.encode()), int(seed) & 0xFFFFFFFF])
        n = int(round(seconds * fps)) + 1
        return cls(np.arange(n) / fps, seconds, float(rng.uniform(0.85, 1.15)), float(rng.uniform(0.85, 1.15)),
                   float(rng.uniform(-np.pi, np.pi)), int(rng.integers(2)), rng)

    @property
    def n(self) -> int:
        return self.t.size

    def keys(self, times, values) -> np.ndarray:
        """Min-jerk interpolation through keyframes: times (K,) s, values (K, ...) -> (F, ...)."""
        times = np.asarray(times, dtype=np.float64)
        values = np.asarray(values, dtype=np.float64)
        i = np.clip(np.searchsorted(times, self.t, side="right") - 1, 0, len(times) - 2)
        s = (self.t - times[i]) / np.maximum(times[i + 1] - times[i], 1e-9)
        w = min_jerk(s).reshape((-1,) + (1,) * (values.ndim - 1))
        return values[i] + w * (values[i + 1] - values[i])

    def cycle_keys(self, period: float, times, values) -> np.ndarray:
        """``keys`` of one cycle (times within [0, period], first value = last) repeated."""
        reps = int(np.ceil(self.seconds / period)) + 1
        tt = np.concatenate([np.asarray(times, float)[:-1] + r * period for r in range(reps)] + [[reps * period]])
        vv = np.concatenate([np.asarray(values, float)[:-1]] * reps + [np.asarray(values, float)[-1:]])
        return self.keys(tt, vv)

    def frame(self, time_s: float) -> int:
        return int(np.clip(np.searchsorted(self.t, time_s), 0, self.n - 1))
