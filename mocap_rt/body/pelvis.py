"""The pelvis turned about the spine to where the knees' hinges point.

The paper's 14 parts put the pelvis and the torso in one rigid trunk, so the hips' line turns
with the shoulders'. A person's does not: in a walk the pelvis turns +-10-20 deg against the
shoulders with every step, in a kick 25 deg, in the CMU modern dance up to 74 deg (the suite's
skeletons, hip line against shoulder line, both projected on the floor). The fitted body then
puts the hips on the shoulders' heading, and the heading measured on the hips (the suite's) is
off by that turn (CMU walk median 15 deg).

What measures the pelvis's turn is the knee: a hinge whose axis is the thigh's X, which the hip
rotates little about the bone (the pelvis faces where the knees bend). The limbs' swivels are
fitted to the silhouettes already, so each bent knee's hinge axis, (hip -> knee) x (knee ->
ankle), is measured; its direction in the pelvis's transverse plane, folded to within 90 deg of
the pelvis's right, is how far that leg's hinge is turned from the pelvis's. The pelvis is turned
about its own long axis (the spine; the torso joint lies on it, so it does not move) by the
weighted mean of the two legs' angles, each weighted by how much of the hinge the knee's bend
defines (|hinge| = sin of the knee's flexion, its part in the transverse plane) against a
``prior`` weight for no turn (a straight leg says nothing), at most ``max_deg``. The torso and
everything above it keep their world frames; each leg is bent again by two-link IK from its
moved hip to its ankle, in the plane of its knee; ankles and feet keep their frames.

Measured on the motion suite (docs/body.md, "The pelvis turned to the knees"): the heading's
error, median over a clip, 9.7 -> 6.9 deg (the Bandai kick 37 -> 10), p95 31.1 -> 26.7; on
fresh windows of the real recordings 18.5 -> 12.0 and 47.5 -> 38.5. Where the silhouettes put a
knee wrong (the modern dance's, 10-30 cm off) the pelvis follows it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from mocap_rt.body.kinematics import euler_xyz_from_matrix, fk_kernel, other_xyz_name
from mocap_rt.body.limb_geometry import _cross, _two_link
from mocap_rt.body.skeleton import N_JOINTS, BodyModel, J

# (hip, knee, ankle) of each leg, and the torso (the pelvis's child on its long axis)
_LEGS = np.array([[J["hip_l"], J["knee_l"], J["ankle_l"]], [J["hip_r"], J["knee_r"], J["ankle_r"]]], np.int64)
_TORSO = J["torso"]


@njit(cache=True, nogil=True)
def _least_rotation(u, v):
    """The least rotation (3, 3) taking direction u to direction v (Rodrigues)."""
    u = u / max(np.sqrt(u @ u), 1e-12)
    v = v / max(np.sqrt(v @ v), 1e-12)
    axis = _cross(u, v)
    s = np.sqrt(axis @ axis)
    c = u @ v
    R = np.eye(3)
    if s < 1e-12:
        return R
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return R + s * K + (1.0 - c) * (K @ K)


@njit(cache=True, nogil=True)
def _local_angles(parent_world, rest_local, world, reference):
    """X-Y-Z angles of ``world`` (3, 3) under ``parent_world @ rest_local``, under the name of the
    rotation (|Y| <= 90 deg, or (x + pi, pi - y, z + pi)) nearer to ``reference`` (3,)."""
    M = np.ascontiguousarray((parent_world @ rest_local).T @ world)
    a = euler_xyz_from_matrix(M)
    x, y, z = other_xyz_name(a[0], a[1], a[2])
    b = np.array([x, y, z])
    da = 0.0
    db = 0.0
    for i in range(3):
        da += abs(np.angle(np.exp(1j * (a[i] - reference[i]))))
        db += abs(np.angle(np.exp(1j * (b[i] - reference[i]))))
    return b if db < da else a


@njit(cache=True, nogil=True)
def _twist(parents, offsets, rest_local, legs, torso, root, angles, prior, max_rad, out):
    """``out`` (J, 3) = ``angles`` with the pelvis turned (module doc); returns the turn (rad)."""
    nj = parents.shape[0]
    pos = np.empty((nj, 3))
    rot = np.empty((nj, 3, 3))
    fk_kernel(parents, offsets, rest_local, root, angles, pos, rot)
    out[:] = angles
    Rp = rot[0]
    num = 0.0
    den = prior
    for leg in range(2):
        h, k, a = legs[leg, 0], legs[leg, 1], legs[leg, 2]
        u = pos[k] - pos[h]
        v = pos[a] - pos[k]
        n = Rp.T @ _cross(u, v) / max(np.sqrt(u @ u) * np.sqrt(v @ v), 1e-12)
        w = np.sqrt(n[0] * n[0] + n[1] * n[1])
        if w < 1e-9:
            continue
        th = np.arctan2(n[1], n[0])          # the hinge's angle from the pelvis's right, folded
        if th > np.pi / 2:
            th -= np.pi
        elif th < -np.pi / 2:
            th += np.pi
        num += w * th
        den += w
    if den <= 0.0:
        return 0.0
    th = min(max(num / den, -max_rad), max_rad)
    if abs(th) < 1e-6:
        return 0.0
    c, s = np.cos(th), np.sin(th)
    Rp2 = Rp @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out[0] = _local_angles(np.eye(3), rest_local[0], Rp2, angles[0])
    out[torso] = _local_angles(Rp2, rest_local[torso], rot[torso], angles[torso])
    for leg in range(2):
        h, k, a = legs[leg, 0], legs[leg, 1], legs[leg, 2]
        hip = root + Rp2 @ offsets[h]
        pole = pos[k] - hip             # the knee stays in its plane
        knee = _two_link(hip, pos[a], np.sqrt(offsets[k] @ offsets[k]), np.sqrt(offsets[a] @ offsets[a]),
                         pole / max(np.sqrt(pole @ pole), 1e-12))[0]
        W_hip = _least_rotation(pos[k] - pos[h], knee - hip) @ rot[h]
        W_knee = _least_rotation(pos[a] - pos[k], pos[a] - knee) @ rot[k]
        out[h] = _local_angles(Rp2, rest_local[h], W_hip, angles[h])
        out[k] = _local_angles(W_hip, rest_local[k], W_knee, angles[k])
        out[a] = _local_angles(W_knee, rest_local[a], rot[a], angles[a])
    return th


def twist_pelvis(model: BodyModel, root: np.ndarray, angles: np.ndarray, prior: float,
                 max_deg: float) -> tuple[np.ndarray, float]:
    """The pose's angles (J, 3) with the pelvis turned to the knees' hinges (module doc), and the
    turn (degrees). ``root`` (3,) metres; ``angles`` (J, 3) radians (``body.kinematics``);
    ``prior``: the weight of no turn against each leg's sin(knee flexion); ``max_deg``: the
    largest turn. The root's position is unchanged."""
    out = np.empty((N_JOINTS, 3))
    th = _twist(model.parents, model.offsets, model.rest_local, _LEGS, _TORSO,
                np.ascontiguousarray(root, np.float64), np.ascontiguousarray(angles, np.float64), float(prior),
                float(np.radians(max_deg)), out)
    return out, float(np.degrees(th))
