"""The body model as a BVH hierarchy, and a pose as one BVH motion row.

The file is **Y up, metres** (what Blender's BVH importer expects with scale 1):
``p_bvh = C @ p_world`` with ``C`` mapping world (X, Y, Z) to BVH (X, Z, -Y). Joints are
``JOINT_NAMES`` (parents first); the pelvis has 6 channels, every other joint
``Xrotation Yrotation Zrotation`` (intrinsic, ``R = Rx Ry Rz``), degrees. BVH joint frames
are parallel to the BVH world at rest (zero rotations = the model's rest pose); the
head, hands and feet carry a short End Site along their bone.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import euler_xyz_from_matrix, forward_kinematics
from mocap_rt.body.skeleton import N_JOINTS, BodyModel, BoneLengths, body_model
from mocap_rt.io.bvh import BvhJoint, BvhSkeleton
from mocap_rt.names import JOINT_NAMES

WORLD_TO_BVH = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
JOINT_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
END_SITE_M = 0.05  # length of the End Site stubs


def bvh_skeleton(model: BodyModel) -> BvhSkeleton:
    """The model's hierarchy (offsets from the rest pose, metres, BVH axes)."""
    C = WORLD_TO_BVH
    joints = []
    children = {j: model.children(j) for j in range(N_JOINTS)}
    for j, name in enumerate(JOINT_NAMES):
        p = int(model.parents[j])
        off = np.zeros(3) if p < 0 else C @ (model.rest_world[p] @ model.offsets[j])
        end = None
        if not children[j]:
            end = C @ (model.rest_world[j] @ np.array([0.0, 0, END_SITE_M]))
        joints.append(BvhJoint(name, p, off, ROOT_CHANNELS if p < 0 else JOINT_CHANNELS, end))
    return BvhSkeleton(tuple(joints))


def bvh_skeleton_of(lengths: BoneLengths) -> BvhSkeleton:
    """The hierarchy of a subject with these bone lengths (the paper and full presets share
    it): what a ``BodyTracker`` with these lengths writes motion rows for."""
    return bvh_skeleton(body_model(lengths, "paper"))


@njit(cache=True, nogil=True)
def _bvh_row(parents, rest_world, rot, root_pos, C, out):
    J = parents.shape[0]
    B = np.empty((J, 3, 3))
    for j in range(J):
        B[j] = C @ rot[j] @ rest_world[j].T @ C.T      # BVH-world rotation of joint j
    p = C @ root_pos
    out[0], out[1], out[2] = p[0], p[1], p[2]
    for j in range(J):
        local = B[j] if parents[j] < 0 else B[parents[j]].T @ B[j]
        a = euler_xyz_from_matrix(local)
        for k in range(3):
            out[3 + 3 * j + k] = np.degrees(a[k])


def bvh_frame(model: BodyModel, root_pos: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(n_channels,) float64 motion row for the pose (root metres, rotations degrees)."""
    _, rot = forward_kinematics(model, root_pos, angles)
    out = np.empty(3 + 3 * N_JOINTS)
    _bvh_row(model.parents, np.ascontiguousarray(model.rest_world), rot,
             np.ascontiguousarray(root_pos, dtype=np.float64).reshape(3), WORLD_TO_BVH, out)
    return out


def bvh_frames(model: BodyModel, root_pos: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(F, n_channels) rows for poses ``root_pos (F, 3)``, ``angles (F, J, 3)``."""
    return np.array([bvh_frame(model, r, a) for r, a in zip(root_pos, angles)])
