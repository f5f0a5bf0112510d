"""The body model: joint tree, bone lengths, local frames, degrees of freedom, limits.

Joints are ``mocap_rt.names.JOINT_NAMES`` (20), the root is the pelvis. Every joint
carries a frame; a child's position is fixed in its parent's frame
(``p_child = p_parent + R_parent @ offset_child``). Every bone frame has its **Z axis
along the bone** (seed digest B.5): the frame of the shoulder has Z from shoulder to
elbow, and so on. At zero angles the body stands in the anatomical pose (arms hanging,
palms in, feet forward) in the *body frame*: +X the subject's right, +Y forward, +Z up.
A joint's rotation relative to its parent is ``R_rest @ Rx(ax) @ Ry(ay) @ Rz(az)``
(intrinsic X-Y-Z, B.5), angles in radians.

Axes of the limb frames at rest: X = the body's right (the flexion axis), Z along the
bone, Y = Z x X. So for the arms and legs (Z down) positive X rotation swings the limb
forward (shoulder/hip flexion, elbow flexion; knee flexion is negative), positive Y
rotation swings it to the subject's right (right-side abduction, left-side adduction),
Z rotation twists about the bone. Spine frames (Z up): positive X is extension.

Degrees of freedom (``dof`` mask, ``model.dof_names``):

* ``full`` (thesis skeleton, 38 DOF): pelvis 3 translations + 3 rotations, torso 3,
  neck 3, shoulders 3, elbows 2 (flexion, pronation), wrists 2 (flexion, deviation),
  hips 3, knees 1, ankles 2 (dorsi/plantar flexion, inversion/eversion).
* ``paper`` (seed digest A.5, 14 parts / 23 DOF): pelvis 3 + 3, shoulders 3, elbows 1,
  hips 3, knees 1, neck 1 (nod). The trunk (pelvis + torso), head, and the hands and
  feet rigid on their forearm/shank are the 14 parts: trunk, head, 2 x (upper arm,
  forearm, hand), 2 x (thigh, shank, foot).

Limits come from the AAOS range-of-motion table (B.7), mirrored for the left side.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from mocap_rt.config import dumps_toml, load_dataclass
from mocap_rt.names import JOINT_NAMES, N_JOINTS, J
PARENTS: tuple[int, ...] = (
    -1, J["pelvis"], J["torso"], J["neck"],
    J["torso"], J["shoulder_l"], J["elbow_l"], J["wrist_l"],
    J["torso"], J["shoulder_r"], J["elbow_r"], J["wrist_r"],
    J["pelvis"], J["hip_l"], J["knee_l"], J["ankle_l"],
    J["pelvis"], J["hip_r"], J["knee_r"], J["ankle_r"],
)
# End effectors of the IK (the cue joints except the torso), leaves of the tree.
END_EFFECTORS: tuple[str, ...] = ("head", "hand_l", "hand_r", "foot_l", "foot_r")


_SIGNED = {"torso_cue_up_m"}     # BoneLengths' offsets that may be <= 0


@dataclass(frozen=True)
class BoneLengths:
    """Per-subject segment lengths, metres (``foot_pitch_deg`` in degrees).

    trunk_m : pelvis -> neck (the torso joint is its midpoint).
    neck_head_m : neck base -> head centre.
    shoulder_half_width_m, hip_half_width_m : neck -> shoulder, pelvis -> hip, lateral.
    upper_arm_m, forearm_m, hand_m : shoulder -> elbow -> wrist -> hand centre.
    thigh_m, shank_m : hip -> knee -> ankle.
    foot_m : ankle -> foot centre; ``foot_pitch_deg`` its angle below the horizontal at rest
        (the default adult's 30 is the foot the tracker's state moves; the subject's foot is
        steeper, ``FusionConfig.subject_foot_pitch_deg``).
    torso_cue_up_m : how far the torso cue (the trunk's visible centre) lies above the torso
        joint along the trunk (signed; ``body.calibrate`` fits it to the silhouettes).
    """

    trunk_m: float = 0.50
    neck_head_m: float = 0.20
    shoulder_half_width_m: float = 0.19
    upper_arm_m: float = 0.29
    forearm_m: float = 0.26
    hand_m: float = 0.08
    hip_half_width_m: float = 0.09
    thigh_m: float = 0.43
    shank_m: float = 0.42
    foot_m: float = 0.09
    foot_pitch_deg: float = 30.0
    torso_cue_up_m: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not np.isfinite(v) or (f.name.endswith("_m") and f.name not in _SIGNED and v <= 0):
                raise ValueError(f"bone length {f.name} must be finite and > 0, got {v}")

    def scaled(self, factor: float) -> "BoneLengths":
        """All lengths times ``factor`` (angles unchanged)."""
        return replace(self, **{f.name: getattr(self, f.name) * factor
                                for f in fields(self) if f.name.endswith("_m")})

    def leg_reach_m(self) -> float:
        """Hip -> foot centre with the leg straight at rest: thigh + |knee -> foot centre|."""
        a = np.radians(self.foot_pitch_deg)
        return self.thigh_m + float(np.hypot(self.foot_m * np.cos(a), self.shank_m + self.foot_m * np.sin(a)))

    def with_foot_pitch(self, pitch_deg: float) -> "BoneLengths":
        """The same body with its foot at ``pitch_deg`` and the thigh, shank and foot scaled by one
        factor so that the leg reaches as far (``leg_reach_m``): what the cues measure of a leg
        (hip and foot centre) is unchanged. ``with_foot_pitch(p).with_foot_pitch(self.foot_pitch_deg)``
        gives ``self`` back (to rounding)."""
        if pitch_deg == self.foot_pitch_deg:
            return self
        pitched = replace(self, foot_pitch_deg=float(pitch_deg))
        k = self.leg_reach_m() / pitched.leg_reach_m()
        return replace(pitched, thigh_m=self.thigh_m * k, shank_m=self.shank_m * k, foot_m=self.foot_m * k)

    def as_array(self) -> np.ndarray:
        """(n_fields,) float64 in field order (for messages; ``from_array`` inverts it)."""
        return np.array([getattr(self, f.name) for f in fields(self)], np.float64)

    @classmethod
    def from_array(cls, values) -> "BoneLengths":
        """The lengths from ``as_array``'s vector; ValueError on a wrong size or value."""
        v = np.asarray(values, np.float64).reshape(-1)
        names = [f.name for f in fields(cls)]
        if v.shape[0] != len(names):
            raise ValueError(f"bone lengths: expected {len(names)} values, got {v.shape[0]}")
        return cls(**{n: float(x) for n, x in zip(names, v)})


def read_bone_lengths(path: str | Path) -> BoneLengths:
    """Read ``[bones]`` from a TOML file; unknown or bad keys raise ``FileFormatError`` naming
    the file and the key."""
    return load_dataclass(BoneLengths, path, "bones", required=True)


def write_bone_lengths(lengths: BoneLengths, path: str | Path) -> None:
    """Write ``[bones]`` TOML (round-trips through ``read_bone_lengths``)."""
    from mocap_rt.io.files import atomic_write_text

    atomic_write_text(path, dumps_toml({"bones": asdict(lengths)}))


N_BONE_VALUES = len(fields(BoneLengths))     # length of ``BoneLengths.as_array()``


# ----------------------------------------------------------------------------- model

_DOWN = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # limb bone frame at rest: Z down, X right
_SPINE = {"pelvis", "torso", "neck", "head"}


def _rest_world(name: str, lengths: BoneLengths) -> np.ndarray:
    """(3, 3) rest orientation of a joint frame in the body frame (columns = axes)."""
    if name in _SPINE:
        return np.eye(3)
    if name.startswith("ankle") or name.startswith("foot"):
        a = np.radians(lengths.foot_pitch_deg)
        z = np.array([0.0, np.cos(a), -np.sin(a)])
        x = np.array([1.0, 0, 0])
        return np.column_stack([x, np.cross(z, x), z])
    return _DOWN.copy()


def _offsets(lengths: BoneLengths) -> np.ndarray:
    """(J, 3) child offsets in the parent's *rest* frame."""
    L = lengths
    off = np.zeros((N_JOINTS, 3))
    half = L.trunk_m / 2
    off[J["torso"]] = (0, 0, half)
    off[J["neck"]] = (0, 0, half)
    off[J["head"]] = (0, 0, L.neck_head_m)
    for side, sx in (("l", -1.0), ("r", 1.0)):
        off[J[f"shoulder_{side}"]] = (sx * L.shoulder_half_width_m, 0, half)
        off[J[f"elbow_{side}"]] = (0, 0, L.upper_arm_m)
        off[J[f"wrist_{side}"]] = (0, 0, L.forearm_m)
        off[J[f"hand_{side}"]] = (0, 0, L.hand_m)
        off[J[f"hip_{side}"]] = (sx * L.hip_half_width_m, 0, 0)
        off[J[f"knee_{side}"]] = (0, 0, L.thigh_m)
        off[J[f"ankle_{side}"]] = (0, 0, L.shank_m)
        off[J[f"foot_{side}"]] = (0, 0, L.foot_m)
    return off


# (lo, hi) degrees for the (X, Y, Z) angles of the right side; left mirrors Y and Z.
# From the AAOS range-of-motion column of the thesis' table 3.1 (seed digest B.7).
_LIMITS_DEG = {
    "torso": ((-80, 25), (-35, 35), (-45, 45)),     # thoracolumbar flex/ext, lateral, rotation
    "neck": ((-45, 45), (-45, 45), (-60, 60)),      # cervical
    "shoulder": ((-60, 180), (0, 180), (-90, 70)),  # ext/flex, abduction, ext/int rotation
    "elbow": ((0, 150), (0, 0), (-80, 80)),         # flexion, -, supination/pronation
    "wrist": ((-70, 80), (-30, 20), (0, 0)),        # ext/flex, ulnar/radial deviation
    "hip": ((-30, 120), (-30, 45), (-45, 45)),      # ext/flex, adduction/abduction, rotation
    "knee": ((-135, 0), (0, 0), (0, 0)),            # flexion
    "ankle": ((-50, 20), (-15, 35), (0, 0)),        # plantar/dorsi flexion, eversion/inversion
}
_FREE = 1e3  # radians, "no limit" for the root

_DOF_FULL = {"torso": "xyz", "neck": "xyz", "shoulder": "xyz", "elbow": "xz", "wrist": "xy",
             "hip": "xyz", "knee": "x", "ankle": "xy"}
_DOF_PAPER = {"neck": "x", "shoulder": "xyz", "elbow": "x", "hip": "xyz", "knee": "x"}
DOF_PRESETS = ("full", "paper")


@dataclass(frozen=True)
class BodyModel:
    """Arrays describing the kinematic tree (all float64 unless said).

    parents : (J,) int64, -1 for the root; parents precede children.
    offsets : (J, 3) metres, each joint's position in its parent's frame.
    rest_local : (J, 3, 3) rotation of each joint frame relative to its parent's at zero angles
        (the root's is the identity: the body frame).
    rest_world : (J, 3, 3) each joint frame in the body frame at zero angles.
    dof : (J, 3) bool, which of the joint's X, Y, Z angles move (root: its rotation).
    limits : (J, 3, 2) radians, (lo, hi) per angle; fixed angles have lo = hi = 0.
    lengths : the BoneLengths it was built from; ``preset`` "full" or "paper".
    """

    parents: np.ndarray
    offsets: np.ndarray
    rest_local: np.ndarray
    rest_world: np.ndarray
    dof: np.ndarray
    limits: np.ndarray
    lengths: BoneLengths
    preset: str

    @property
    def names(self) -> tuple[str, ...]:
        return JOINT_NAMES

    @property
    def n_dof(self) -> int:
        """Degrees of freedom including the root's 3 translations."""
        return int(self.dof.sum()) + 3

    @property
    def dof_names(self) -> list[str]:
        out = ["pelvis_tx", "pelvis_ty", "pelvis_tz"]
        for j, name in enumerate(JOINT_NAMES):
            out += [f"{name}_r{a}" for k, a in enumerate("xyz") if self.dof[j, k]]
        return out

    def children(self, j: int) -> list[int]:
        return [c for c in range(N_JOINTS) if self.parents[c] == j]

    def rest_positions(self) -> np.ndarray:
        """(J, 3) joint positions at zero angles, body frame, pelvis at the origin."""
        pos = np.zeros((N_JOINTS, 3))
        for j in range(1, N_JOINTS):
            p = self.parents[j]
            pos[j] = pos[p] + self.rest_world[p] @ self.offsets[j]
        return pos

    def clamp(self, angles: np.ndarray) -> np.ndarray:
        """(J, 3) angles clamped into the limits (fixed angles set to 0)."""
        a = np.clip(angles, self.limits[..., 0], self.limits[..., 1])
        return np.where(self.dof, a, 0.0)


def body_model(lengths: BoneLengths | None = None, preset: str = "full") -> BodyModel:
    """Build the body model for ``lengths`` (default: a 1.75 m adult) and a DOF preset."""
    if preset not in DOF_PRESETS:
        raise ValueError(f"preset must be one of {DOF_PRESETS}, got {preset!r}")
    lengths = lengths or BoneLengths()
    dof_map = _DOF_FULL if preset == "full" else _DOF_PAPER
    parents = np.array(PARENTS, dtype=np.int64)
    rest_world = np.array([_rest_world(n, lengths) for n in JOINT_NAMES])
    rest_local = np.empty_like(rest_world)
    rest_local[0] = np.eye(3)
    for j in range(1, N_JOINTS):
        rest_local[j] = rest_world[parents[j]].T @ rest_world[j]
    dof = np.zeros((N_JOINTS, 3), dtype=bool)
    limits = np.zeros((N_JOINTS, 3, 2))
    dof[0] = True
    limits[0, :, 0], limits[0, :, 1] = -_FREE, _FREE
    for j, name in enumerate(JOINT_NAMES):
        kind, _, side = name.partition("_")
        if kind not in _LIMITS_DEG or kind not in dof_map:
            continue
        lim = np.radians(np.array(_LIMITS_DEG[kind], dtype=np.float64))
        if side == "l":  # mirror: Y and Z angles change sign on the left
            lim[1:] = -lim[1:, ::-1]
        for k, axis in enumerate("xyz"):
            if axis in dof_map[kind]:
                dof[j, k] = True
                limits[j, k] = lim[k]
    offsets = _offsets(lengths)  # already in the parent's frame (Z along its bone)
    return BodyModel(parents, offsets, rest_local, rest_world, dof, limits, lengths, preset)
