"""Forward kinematics and joint-angle conversions for ``BodyModel`` (seed digest B.5).

A pose is ``root_pos (3,)`` (pelvis, metres, world frame) plus ``angles (J, 3)``
radians: ``angles[0]`` rotates the body frame into the world, every other row is a
joint's X-Y-Z (intrinsic) angles relative to its rest frame. Joint frame ``j`` in the
world is ``R[j] = R[parent] @ rest_local[j] @ Rx Ry Rz``; its position is
``p[j] = p[parent] + R[parent] @ offsets[j]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from mocap_rt.body.skeleton import N_JOINTS, BodyModel


@njit(cache=True, nogil=True)
def euler_xyz_matrix(ax: float, ay: float, az: float) -> np.ndarray:
    """(3, 3) ``Rx(ax) @ Ry(ay) @ Rz(az)``, radians."""
    ca, sa = np.cos(ax), np.sin(ax)
    cb, sb = np.cos(ay), np.sin(ay)
    cc, sc = np.cos(az), np.sin(az)
    R = np.empty((3, 3))
    R[0, 0] = cb * cc
    R[0, 1] = -cb * sc
    R[0, 2] = sb
    R[1, 0] = ca * sc + sa * sb * cc
    R[1, 1] = ca * cc - sa * sb * sc
    R[1, 2] = -sa * cb
    R[2, 0] = sa * sc - ca * sb * cc
    R[2, 1] = sa * cc + ca * sb * sc
    R[2, 2] = ca * cb
    return R


@njit(cache=True, nogil=True)
def euler_xyz_from_matrix(R: np.ndarray) -> np.ndarray:
    """(3,) X-Y-Z angles of ``R = Rx Ry Rz``, radians, Y in [-pi/2, pi/2]."""
    out = np.empty(3)
    sb = min(1.0, max(-1.0, R[0, 2]))
    out[1] = np.arcsin(sb)
    if abs(sb) < 1.0 - 1e-12:
        out[0] = np.arctan2(-R[1, 2], R[2, 2])
        out[2] = np.arctan2(-R[0, 1], R[0, 0])
    else:  # gimbal lock: put everything into X
        out[0] = np.arctan2(R[2, 1], R[1, 1])
        out[2] = 0.0
    return out


@njit(cache=True, nogil=True)
def mul3(A, B, out):
    """out = A @ B for 3x3 (written out: numba's ``@`` on 3x3 goes through BLAS, slower)."""
    for a in range(3):
        for b in range(3):
            out[a, b] = A[a, 0] * B[0, b] + A[a, 1] * B[1, b] + A[a, 2] * B[2, b]


@njit(cache=True, nogil=True)
def fk_kernel(parents, offsets, rest_local, root_pos, angles, pos, rot):
    """FK into pos (J, 3) / rot (J, 3, 3) of the body arrays (``BodyModel`` fields); see module doc."""
    M = np.empty((3, 3))
    for j in range(parents.shape[0]):
        if parents[j] < 0:
            mul3(rest_local[j], euler_xyz_matrix(angles[j, 0], angles[j, 1], angles[j, 2]), rot[j])
            pos[j] = root_pos
        else:
            fk_joint(parents, offsets, rest_local, angles, pos, rot, j, M)


@njit(cache=True, nogil=True)
def fk_joint(parents, offsets, rest_local, angles, pos, rot, j, M):
    """``fk_kernel``'s step for joint j (not the root), its parent's pos and rot in place; M (3, 3) scratch."""
    p = parents[j]
    mul3(rest_local[j], euler_xyz_matrix(angles[j, 0], angles[j, 1], angles[j, 2]), M)
    mul3(rot[p], M, rot[j])
    for a in range(3):
        pos[j, a] = pos[p, a] + rot[p, a, 0] * offsets[j, 0] + rot[p, a, 1] * offsets[j, 1] \
            + rot[p, a, 2] * offsets[j, 2]


def forward_kinematics(model: BodyModel, root_pos: np.ndarray, angles: np.ndarray,
                       out: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (J, 3) metres and frames (J, 3, 3) in the world.

    root_pos : (3,) pelvis position, metres, world. angles : (J, 3) radians (see module doc).
    ``out`` may pass preallocated (positions, rotations) arrays.
    """
    angles = np.ascontiguousarray(angles, dtype=np.float64)
    if angles.shape != (N_JOINTS, 3):
        raise ValueError(f"angles must have shape ({N_JOINTS}, 3), got {angles.shape}")
    root_pos = np.ascontiguousarray(root_pos, dtype=np.float64).reshape(3)
    pos, rot = out if out is not None else (np.empty((N_JOINTS, 3)), np.empty((N_JOINTS, 3, 3)))
    fk_kernel(model.parents, model.offsets, model.rest_local, root_pos, angles, pos, rot)
    return pos, rot


def angles_from_frames(model: BodyModel, rotations: np.ndarray) -> np.ndarray:
    """Inverse of the rotation part of FK: world frames (J, 3, 3) -> angles (J, 3) radians.

    Each joint's angle is the rotation between its parent's frame and its own
    (B.5: ``M = F_parent^-1 F_child``, less the rest rotation) split as Rx Ry Rz.
    """
    rotations = np.asarray(rotations, dtype=np.float64)
    out = np.zeros((N_JOINTS, 3))
    for j in range(N_JOINTS):
        p = model.parents[j]
        parent = np.eye(3) if p < 0 else rotations[p]
        M = (parent @ model.rest_local[j]).T @ rotations[j]
        out[j] = euler_xyz_from_matrix(np.ascontiguousarray(M))
    return out


@njit(cache=True, nogil=True)
def other_xyz_name(x: float, y: float, z: float) -> tuple[float, float, float]:
    """The other X-Y-Z name (x + pi, pi - y, z + pi) of the rotation named (x, y, z), each
    angle kept within [-pi, pi]: ``euler_xyz_from_matrix`` gives |Y| <= pi/2; an arm raised
    sideways above the shoulder has its angles within the limits only under the other."""
    return (x + np.pi if x <= 0.0 else x - np.pi, np.pi - y if y >= 0.0 else -np.pi - y,
            z + np.pi if z <= 0.0 else z - np.pi)


def quaternions_from_angles(angles: np.ndarray) -> np.ndarray:
    """(J, 3) X-Y-Z angles (radians) -> (J, 4) unit quaternions (x, y, z, w), scipy order."""
    return Rotation.from_euler("XYZ", np.asarray(angles, dtype=np.float64)).as_quat()


def angles_from_quaternions(quats: np.ndarray) -> np.ndarray:
    """(J, 4) quaternions (x, y, z, w) -> (J, 3) X-Y-Z angles, radians."""
    return Rotation.from_quat(np.asarray(quats, dtype=np.float64)).as_euler("XYZ")

