"""The body pose as a Unity humanoid: bone-local rotations relative to the T-pose, Unity axes.

What the VMC protocol (``/VMC/Ext/Bone/Pos``) and VRM avatars expect: a *normalised*
humanoid, whose every bone has the identity local rotation in the T-pose (VRM 0.x
normalisation), so a bone's ``localRotation`` is its rotation relative to the T-pose,
expressed in its parent's T-pose axes, and its ``localPosition`` the offset from its
parent's joint in those axes.

**Axes.** Unity is left-handed, +X right, +Y up, +Z forward, metres; a humanoid faces +Z.
The world here is right-handed, Z up. ``p_unity = UNITY_FROM_WORLD @ p_world`` maps world
(X, Y, Z) to (X, Z, Y): up stays up, world +X is Unity +X, world +Y is Unity forward (+Z).
The map is a reflection (det -1), which is what turns a right-handed description into the
left-handed one of the *same* physical space: a subject facing world +Y with their right
hand towards +X (the body frame of ``skeleton.py``) is a Unity humanoid facing +Z with its
right hand towards +X. A rotation ``R`` (world) is ``UNITY_FROM_WORLD @ R @ UNITY_FROM_WORLD.T``
in Unity axes (det +1 again), and Unity's quaternion of a matrix is the usual one (Unity's
``Quaternion * Vector3`` is the standard rotation formula), in (x, y, z, w) order.

**T-pose vs the model's rest pose.** The body model rests in the anatomical pose (arms
hanging, palms in). The T-pose lifts each whole arm by 90 degrees about the body's forward
axis (abduction in the coronal plane: palms then face down, as a Unity T-pose has them);
spine, legs and feet are the same in both. With ``G_j`` the world rotation of joint frame
``j`` from its rest orientation (``rot_j @ rest_world_j.T``) and ``A_j`` the arm lift, the
bone's rotation from the T-pose is ``D_j = G_j @ A_j.T``; the VMC local rotation is
``D_parent.T @ D_j`` in Unity axes (the humanoid parent; bones between, e.g. Chest and
the shoulders, are sent as identity with zero offset).

**Root.** ``/VMC/Ext/Root/Pos`` carries the pelvis position (Unity axes) and the identity
rotation; the Hips bone sits at the root (zero local position) and carries the whole
body's orientation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from mocap_rt.body.bvh_export import WORLD_TO_BVH
from mocap_rt.body.skeleton import J, N_JOINTS, BodyModel

UNITY_FROM_WORLD = np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]])   # world (X, Y, Z) -> Unity (X, Z, Y)

# (Unity HumanBodyBones name, body joint whose frame drives it or None, humanoid parent), parents first.
# Bones without a joint (Chest, UpperChest, shoulders) keep the identity and a zero offset, so
# that a receiver which applies bone positions rebuilds exactly this skeleton.
HUMANOID_BONES: tuple[tuple[str, str | None, str | None], ...] = (
    ("Hips", "pelvis", None),
    ("Spine", "torso", "Hips"),
    ("Chest", None, "Spine"),
    ("UpperChest", None, "Chest"),
    ("Neck", "neck", "UpperChest"),
    ("Head", "head", "Neck"),
    ("LeftShoulder", None, "UpperChest"),
    ("LeftUpperArm", "shoulder_l", "LeftShoulder"),
    ("LeftLowerArm", "elbow_l", "LeftUpperArm"),
    ("LeftHand", "wrist_l", "LeftLowerArm"),
    ("RightShoulder", None, "UpperChest"),
    ("RightUpperArm", "shoulder_r", "RightShoulder"),
    ("RightLowerArm", "elbow_r", "RightUpperArm"),
    ("RightHand", "wrist_r", "RightLowerArm"),
    ("LeftUpperLeg", "hip_l", "Hips"),
    ("LeftLowerLeg", "knee_l", "LeftUpperLeg"),
    ("LeftFoot", "ankle_l", "LeftLowerLeg"),
    ("RightUpperLeg", "hip_r", "Hips"),
    ("RightLowerLeg", "knee_r", "RightUpperLeg"),
    ("RightFoot", "ankle_r", "RightLowerLeg"),
)
BONE_NAMES: tuple[str, ...] = tuple(b[0] for b in HUMANOID_BONES)
_ARM_JOINTS = {"l": ("shoulder_l", "elbow_l", "wrist_l", "hand_l"),
               "r": ("shoulder_r", "elbow_r", "wrist_r", "hand_r")}


def _joint_of(bone: str) -> int | None:
    """Index of the body joint that drives ``bone``, following bones without one upwards."""
    by_name = {b[0]: b for b in HUMANOID_BONES}
    while bone is not None:
        _, joint, parent = by_name[bone]
        if joint is not None:
            return J[joint]
        bone = parent
    return None


def arm_lift() -> np.ndarray:
    """(J, 3, 3) rotation taking each joint frame from the rest pose to the T-pose, body frame:
    about +Y (forward) by -90 degrees for the right arm (down -> +X), +90 for the left."""
    lift = np.tile(np.eye(3), (N_JOINTS, 1, 1))
    for side, deg in (("r", -90.0), ("l", 90.0)):
        R = Rotation.from_euler("y", deg, degrees=True).as_matrix()
        for name in _ARM_JOINTS[side]:
            lift[J[name]] = R
    return lift


def tpose_positions(model: BodyModel) -> np.ndarray:
    """(J, 3) joint positions in the T-pose, body frame (pelvis at the origin), metres."""
    frames = arm_lift() @ model.rest_world                 # (J, 3, 3) T-pose joint frames
    pos = np.zeros((N_JOINTS, 3))
    for j in range(1, N_JOINTS):
        p = model.parents[j]
        pos[j] = pos[p] + frames[p] @ model.offsets[j]
    return pos


@dataclass(frozen=True)
class HumanoidRig:
    """What does not change between poses of one subject: the bones' T-pose local positions.

    local_positions : (B, 3) float64 metres, Unity axes, ``BONE_NAMES`` order (Hips: zeros).
    """

    local_positions: np.ndarray
    bone_joint: np.ndarray          # (B,) int, driving joint per bone (-1: none)
    bone_parent: np.ndarray         # (B,) int, parent bone index (-1: the root)
    lift: np.ndarray                # (J, 3, 3) arm_lift()
    driven: np.ndarray              # (D,) bone indices with a joint
    driven_joints: np.ndarray       # (D,) their joints
    left_q: np.ndarray              # (D, 4) quaternion of A_parent @ WORLD_TO_BVH.T (see below)
    right_q: np.ndarray             # (D, 4) quaternion of WORLD_TO_BVH @ A_joint.T

    @classmethod
    def of(cls, model: BodyModel) -> "HumanoidRig":
        tpos = tpose_positions(model)
        index = {name: i for i, name in enumerate(BONE_NAMES)}
        joint = np.array([-1 if j is None else J[j] for _, j, _ in HUMANOID_BONES])
        parent = np.array([-1 if p is None else index[p] for _, _, p in HUMANOID_BONES])
        local = np.zeros((len(BONE_NAMES), 3))
        for b, (name, jname, pname) in enumerate(HUMANOID_BONES):
            if jname is None or pname is None:
                continue                                   # no joint, or Hips at the root
            local[b] = UNITY_FROM_WORLD @ (tpos[J[jname]] - tpos[_joint_of(pname)])
        lift, T = arm_lift(), WORLD_TO_BVH
        driven = np.flatnonzero(joint >= 0)
        for b in driven:      # the fast path needs the humanoid parent's joint = the tree parent
            if parent[b] >= 0 and _joint_of(BONE_NAMES[parent[b]]) != model.parents[joint[b]]:
                raise ValueError(f"humanoid bone {BONE_NAMES[b]}: parent joint is not the body's")
        left = [(np.eye(3) if parent[b] < 0 else lift[model.parents[joint[b]]]) @ T.T for b in driven]
        right = [T @ lift[joint[b]].T for b in driven]
        return cls(local, joint, parent, lift, driven, joint[driven].astype(np.int64),
                   Rotation.from_matrix(np.array(left)).as_quat(), Rotation.from_matrix(np.array(right)).as_quat())


@dataclass(frozen=True)
class HumanoidPose:
    """One pose as VMC sends it (Unity axes, metres).

    root_position : (3,) the pelvis.  root_rotation : (4,) x, y, z, w (the identity).
    local_positions : (B, 3), local_rotations : (B, 4) unit quaternions x, y, z, w, in
    ``BONE_NAMES`` order.
    """

    root_position: np.ndarray
    root_rotation: np.ndarray
    local_positions: np.ndarray
    local_rotations: np.ndarray


def humanoid_pose(rig: HumanoidRig, root_pos: np.ndarray, rest_rotations: np.ndarray) -> HumanoidPose:
    """The humanoid pose of a body pose.

    root_pos : (3,) pelvis, metres, world.  rest_rotations : (J, 3, 3) ``G_j``, each joint
    frame's world rotation from its rest orientation (``rot_j @ rest_world_j.T`` of
    ``forward_kinematics``, or ``rest_rotations_from_bvh_row``).
    """
    C = UNITY_FROM_WORLD
    D = np.asarray(rest_rotations, np.float64) @ np.transpose(rig.lift, (0, 2, 1))    # (J, 3, 3)
    U = C @ D @ C.T                                                               # Unity axes
    n = len(BONE_NAMES)
    world = np.tile(np.eye(3), (n, 1, 1))
    has = rig.bone_joint >= 0
    world[has] = U[rig.bone_joint[has]]
    # a bone without a joint follows its parent: identity local rotation
    for b in range(n):
        if not has[b] and rig.bone_parent[b] >= 0:
            world[b] = world[rig.bone_parent[b]]
    parent_world = np.where((rig.bone_parent >= 0)[:, None, None], world[rig.bone_parent], np.eye(3))
    local = np.transpose(parent_world, (0, 2, 1)) @ world                         # (B, 3, 3)
    quats = Rotation.from_matrix(local).as_quat()
    return HumanoidPose(C @ np.asarray(root_pos, np.float64).reshape(3), np.array([0.0, 0, 0, 1]),
                        rig.local_positions, quats)


def rest_rotations_from_bvh_row(row: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root position (3,) metres world and ``G`` (J, 3, 3) from a BVH motion row of
    ``bvh_export.bvh_frame`` (root position in BVH axes, then X-Y-Z local angles in degrees
    of each joint's BVH-world rotation from rest, relative to its parent's)."""
    row = np.asarray(row, np.float64).reshape(-1)
    n = parents.shape[0]
    if row.shape[0] != 3 + 3 * n:
        raise ValueError(f"BVH row has {row.shape[0]} values, expected {3 + 3 * n}")
    E = Rotation.from_euler("XYZ", row[3:].reshape(n, 3), degrees=True).as_matrix()   # Rx Ry Rz
    B = np.empty((n, 3, 3))
    for j in range(n):
        B[j] = E[j] if parents[j] < 0 else B[parents[j]] @ E[j]
    T = WORLD_TO_BVH
    return T.T @ row[:3], T.T @ B @ T


@njit(cache=True, nogil=True)
def _qmul(a, b, out):
    """``out = a * b`` (Hamilton) for quaternions (x, y, z, w) of shape (4,)."""
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    out[0] = aw * bx + ax * bw + ay * bz - az * by
    out[1] = aw * by - ax * bz + ay * bw + az * bx
    out[2] = aw * bz + ax * by - ay * bx + az * bw
    out[3] = aw * bw - ax * bx - ay * by - az * bz


@njit(cache=True, nogil=True)
def _bone_quats(row, bones, joints, left_q, right_q, out):
    """out[bones[d]] = Unity-axes quaternion of left_q[d] * q(Rx Ry Rz of the row's angles of
    joints[d]) * right_q[d]; ``row`` is the whole BVH row (root position, then 3 angles, degrees,
    per joint)."""
    e = np.empty(4)
    t = np.empty(4)
    u = np.empty(4)
    for d in range(joints.shape[0]):
        k = 3 + 3 * joints[d]
        hx = np.radians(row[k]) / 2
        hy = np.radians(row[k + 1]) / 2
        hz = np.radians(row[k + 2]) / 2
        cx, sx, cy, sy, cz, sz = np.cos(hx), np.sin(hx), np.cos(hy), np.sin(hy), np.cos(hz), np.sin(hz)
        # qx * qy * qz written out
        e[0] = sx * cy * cz + cx * sy * sz
        e[1] = cx * sy * cz - sx * cy * sz
        e[2] = cx * cy * sz + sx * sy * cz
        e[3] = cx * cy * cz - sx * sy * sz
        _qmul(left_q[d], e, t)
        _qmul(t, right_q[d], u)
        sign = 1.0 if u[3] >= 0 else -1.0                  # w >= 0, as scipy's from_matrix
        b = bones[d]
        out[b, 0], out[b, 1], out[b, 2], out[b, 3] = -u[0] * sign, -u[2] * sign, -u[1] * sign, u[3] * sign


_IDENTITY_QUATS = np.tile([0.0, 0, 0, 1], (len(BONE_NAMES), 1))      # (B, 4) bones without a joint
_UNITY_FROM_BVH = UNITY_FROM_WORLD @ WORLD_TO_BVH.T


def humanoid_pose_from_bvh_row(rig: HumanoidRig, model: BodyModel, row: np.ndarray) -> HumanoidPose:
    """``humanoid_pose`` of a pose given as a ``bvh_frame`` row of ``model``'s skeleton, without
    chaining the tree: every driven bone's humanoid parent is its joint's tree parent, so with
    ``E_j`` the row's local rotation (BVH axes, ``B_j = B_parent E_j``) the bone's local rotation
    in world axes is ``A_parent T.T E_j T A_j.T`` (``T`` = WORLD_TO_BVH; the Hips: ``T.T E T``).
    The reflection to Unity axes turns a quaternion (x, y, z, w) into (-x, -z, -y, w)
    (``C R C.T`` is the rotation about ``C axis`` by minus the angle). About 10x faster than
    ``humanoid_pose`` (the reference it is tested against); ~20 us a pose."""
    row = np.asarray(row, np.float64).reshape(-1)
    if row.shape[0] != 3 + 3 * N_JOINTS:
        raise ValueError(f"BVH row has {row.shape[0]} values, expected {3 + 3 * N_JOINTS}")
    quats = _IDENTITY_QUATS.copy()
    _bone_quats(row, rig.driven, rig.driven_joints, rig.left_q, rig.right_q, quats)
    return HumanoidPose(_UNITY_FROM_BVH @ row[:3], _IDENTITY_QUATS[0].copy(), rig.local_positions, quats)
