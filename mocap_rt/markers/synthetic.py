"""Synthetic marker trials with known joint centres (tests, bench, CLI demos).

* :func:`simulate_joint` - the patent's experiment (digest C, evaluation): child markers
  rotate about a joint centre J, then parent and child move rigidly together, then
  Gaussian noise.  Continuous motion follows smooth sinusoids, discrete motion draws
  every frame at random.  Range I: rotations in [-5, 5]^3 deg, translations in [-1, 1];
  range II: rotations [-180, 180] x [-90, 90] x [-90, 90] deg, translations [-100, 100].
  The patent gives no unit or marker layout; we use segment length L = 1 (markers 0.3-1 L
  from J) and noise sigma = level x L per coordinate, so "5 %" is 0.05 L.
* :func:`simulate_body` - a 13-segment, 12-joint body (hips, knees, ankles, shoulders,
  elbows, wrists) doing a range-of-motion trial, with 4 markers per segment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.markers.io import MarkerData
from mocap_rt.markers.segments import Joint, SegmentSet

RANGES = {
    "I": (np.array([5.0, 5.0, 5.0]), 1.0),
    "II": (np.array([180.0, 90.0, 90.0]), 100.0),
}
MARKER_DIST_L = (0.3, 1.0)  # marker distance from the joint, in segment lengths


@dataclass(frozen=True)
class JointTrial:
    """parent (F, kp, 3), child (F, kc, 3) noisy markers; centre (F, 3) true joint centre."""

    parent: np.ndarray
    child: np.ndarray
    centre: np.ndarray


def _angles(rng: np.random.Generator, n: int, half_range_deg: np.ndarray, continuous: bool) -> np.ndarray:
    """(n, 3) Euler angles in degrees within +-half_range_deg."""
    if continuous:
        t = np.linspace(0.0, 1.0, n)[:, None]
        freq = rng.uniform(0.5, 2.0, size=(1, 3))
        phase = rng.uniform(0.0, 2 * np.pi, size=(1, 3))
        return half_range_deg * np.sin(2 * np.pi * freq * t + phase)
    return rng.uniform(-1.0, 1.0, size=(n, 3)) * half_range_deg


def _offsets(rng: np.random.Generator, k: int, side: float) -> np.ndarray:
    """k marker positions relative to J, on one side (z sign) of the joint."""
    d = rng.normal(size=(k, 3))
    d[:, 2] = np.abs(d[:, 2]) * side + 0.5 * side
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(*MARKER_DIST_L, size=(k, 1))


def simulate_joint(rng: np.random.Generator, n_frames: int = 100, continuous: bool = True,
                   range_name: str = "II", noise: float = 0.0, n_parent: int = 4,
                   n_child: int = 4) -> JointTrial:
    """One trial of the patent's synthetic experiment (units: segment lengths)."""
    half_rot, half_trans = RANGES[range_name]
    joint = rng.uniform(-1.0, 1.0, size=3)
    parent_local = _offsets(rng, n_parent, +1.0)
    child_local = _offsets(rng, n_child, -1.0)
    rel = Rotation.from_euler("xyz", _angles(rng, n_frames, half_rot, continuous), degrees=True)
    glob = Rotation.from_euler("xyz", _angles(rng, n_frames, half_rot, continuous), degrees=True)
    if continuous:
        t = np.linspace(0.0, 1.0, n_frames)[:, None]
        trans = half_trans * np.sin(2 * np.pi * rng.uniform(0.5, 2.0, (1, 3)) * t + rng.uniform(0, 6.3, (1, 3)))
    else:
        trans = rng.uniform(-half_trans, half_trans, size=(n_frames, 3))
    gm = glob.as_matrix()  # (F, 3, 3)
    child_rel = np.einsum("fab,kb->fka", rel.as_matrix(), child_local)  # child rotated about J
    parent = np.einsum("fab,fkb->fka", gm, np.broadcast_to(parent_local, (n_frames,) + parent_local.shape))
    child = np.einsum("fab,fkb->fka", gm, child_rel)
    centre = joint + trans  # J moves with the global motion only
    parent = parent + centre[:, None]
    child = child + centre[:, None]
    parent = parent + rng.normal(scale=noise, size=parent.shape)
    child = child + rng.normal(scale=noise, size=child.shape)
    return JointTrial(parent, child, centre)


# ---- a 12-joint body ---------------------------------------------------------------------------
# segment: (parent segment, joint name, joint position in parent frame (m), segment "bone" vector (m),
#           rotation amplitude (deg) about x, y, z)
_BODY = {
    "pelvis": (None, None, (0, 0, 0), (0, 0, 0.2), (0, 0, 0)),
    "thorax": ("pelvis", None, (0, 0, 0.25), (0, 0, 0.3), (15, 10, 20)),
    "thigh_r": ("pelvis", "hip_r", (-0.09, 0.0, -0.05), (0, 0, -0.42), (50, 30, 25)),
    "shank_r": ("thigh_r", "knee_r", (0, 0, -0.42), (0, 0, -0.40), (60, 5, 8)),
    "foot_r": ("shank_r", "ankle_r", (0, 0, -0.40), (0, 0.15, -0.05), (25, 15, 15)),
    "thigh_l": ("pelvis", "hip_l", (0.09, 0.0, -0.05), (0, 0, -0.42), (50, 30, 25)),
    "shank_l": ("thigh_l", "knee_l", (0, 0, -0.42), (0, 0, -0.40), (60, 5, 8)),
    "foot_l": ("shank_l", "ankle_l", (0, 0, -0.40), (0, 0.15, -0.05), (25, 15, 15)),
    "upperarm_r": ("thorax", "shoulder_r", (-0.18, 0, 0.25), (0, 0, -0.30), (60, 45, 40)),
    "forearm_r": ("upperarm_r", "elbow_r", (0, 0, -0.30), (0, 0, -0.26), (60, 8, 40)),
    "hand_r": ("forearm_r", "wrist_r", (0, 0, -0.26), (0, 0, -0.08), (40, 25, 10)),
    "upperarm_l": ("thorax", "shoulder_l", (0.18, 0, 0.25), (0, 0, -0.30), (60, 45, 40)),
    "forearm_l": ("upperarm_l", "elbow_l", (0, 0, -0.30), (0, 0, -0.26), (60, 8, 40)),
    "hand_l": ("forearm_l", "wrist_l", (0, 0, -0.26), (0, 0, -0.08), (40, 25, 10)),
}
MARKER_STANDOFF_M = 0.06  # markers sit this far from the bone axis (skin + cluster base)


def simulate_body(n_frames: int = 1085, rate_hz: float = 30.0, noise_m: float = 0.0, gap_frac: float = 0.0,
                  seed: int = 0, markers_per_segment: int = 4) -> tuple[MarkerData, SegmentSet, dict]:
    """A range-of-motion trial of a 12-joint body, Z up, metres.

    Returns (markers, segment definitions, truth) where truth maps joint name -> (F, 3)
    true centre.  ``gap_frac`` of the marker samples are removed as short gaps (NaN).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / rate_hz
    pose_r: dict[str, np.ndarray] = {}
    pose_t: dict[str, np.ndarray] = {}
    truth: dict[str, np.ndarray] = {}
    labels: list[str] = []
    columns: list[np.ndarray] = []
    segments: dict[str, tuple[str, ...]] = {}
    joints: list[Joint] = []
    for name, (parent, joint, at, bone, amp) in _BODY.items():
        freq = rng.uniform(0.05, 0.3, size=3)
        phase = rng.uniform(0, 2 * np.pi, size=3)
        ang = np.asarray(amp) * np.sin(2 * np.pi * freq * t[:, None] + phase)  # (F, 3) deg
        rel = Rotation.from_euler("xyz", ang, degrees=True).as_matrix()
        if parent is None:  # the root wanders and turns about the vertical
            yaw = Rotation.from_euler("z", 90 * np.sin(2 * np.pi * 0.03 * t)[:, None], degrees=True).as_matrix()
            tilt = Rotation.from_euler("xy", 10 * np.sin(2 * np.pi * np.outer(t, [0.07, 0.11])), degrees=True)
            pose_r[name] = yaw @ tilt.as_matrix()
            pose_t[name] = np.stack([0.5 * np.sin(2 * np.pi * 0.02 * t), 0.3 * np.cos(2 * np.pi * 0.03 * t),
                                     1.0 + 0.03 * np.sin(2 * np.pi * 0.5 * t)], axis=1)
        else:
            origin = np.einsum("fab,b->fa", pose_r[parent], np.asarray(at, float)) + pose_t[parent]
            pose_r[name] = pose_r[parent] @ rel
            pose_t[name] = origin
            if joint is not None:
                truth[joint] = origin
                joints.append(Joint(joint, parent, name))
        # markers around the bone from the segment origin towards its end
        bone_v = np.asarray(bone, float)
        along = rng.uniform(0.3, 0.9, size=markers_per_segment)[:, None] * bone_v
        radial = rng.normal(size=(markers_per_segment, 3))
        radial -= np.outer(radial @ bone_v, bone_v) / max(bone_v @ bone_v, 1e-12)
        radial *= MARKER_STANDOFF_M / np.linalg.norm(radial, axis=1, keepdims=True)
        local = along + radial
        names = tuple(f"{name.upper()}{k + 1}" for k in range(markers_per_segment))
        segments[name] = names
        labels += names
        columns.append(np.einsum("fab,kb->fka", pose_r[name], local) + pose_t[name][:, None])
    pos = np.concatenate(columns, axis=1)
    pos = pos + rng.normal(scale=noise_m, size=pos.shape) if noise_m > 0 else pos
    if gap_frac > 0:
        n_gaps = int(gap_frac * pos.shape[0] * pos.shape[1] / 5)
        for _ in range(n_gaps):  # gaps of 1..9 frames
            m = rng.integers(pos.shape[1])
            f = rng.integers(pos.shape[0])
            pos[f:f + rng.integers(1, 10), m] = np.nan
    data = MarkerData(tuple(labels), pos, rate_hz, 1, "synthetic")
    return data, SegmentSet(segments, tuple(joints), "synthetic"), truth
