"""Zero-lag smoothing of a processed clip's poses (offline: ``mocap-rt process``).

The live service publishes each pose when its frame ends, so it can only look back. Offline
the whole clip is known, and the tools of the field low-pass it both ways with no lag
(Pose2Sim and FreeMoCap run a Butterworth filter forwards and backwards over the 3D points;
Pose2Sim's default is order 4 at 6 Hz, and OpenSim then fits the skeleton to them). Here:

1. every joint's position is filtered by ``scipy.signal.filtfilt`` with a Butterworth low-pass
   of ``cutoff_hz`` (order ``ORDER``, run both ways);
2. the body is put back on them with its own bone lengths (``retarget``), from the root outwards:
   each joint's frame turned by the least rotation that points its bone at the filtered child from
   where the joint itself has come to lie (Kabsch over several children), the twist about the bone
   kept; each arm and leg bent as the per-frame analytic IK bends it (``_two_link``), to reach its
   wrist's (ankle's) filtered position from where its shoulder (hip) came to lie, in the plane of
   its filtered elbow (knee); a joint without children keeps its angles;
3. the angles read from those frames, each under the name of its rotation nearer to the
   solver's (``_closest_name``), and the joints recomputed by forward kinematics.

Filtering the angles instead (the root's rotation and every joint's) is worse: the per-frame
solve makes the limbs reach their cues from wherever the trunk is, and a filtered trunk with
filtered limbs no longer reaches them (the CMU modern dance, 62.2 -> 64.0 mm, where filtering
the points gives 61.6; docs/body.md, "Offline smoothing"). The filtered pose turns the joints
that the per-frame model holds fixed (the rigid trunk, the elbow's side swing) by a few
degrees (median 7, p95 17 on the modern dance); putting them back to zero costs 4 mm.

Runs are filtered apart: a run ends where the pose is missing, where the joint's limb was at
rest (its cue missing), and where a joint moves more than ``JUMP_M`` in one frame (a change of
the labels that was not carried back, a body that restarted): filtering across it would blend
two different bodies. Runs shorter than the filter's padding are left as they are.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, filtfilt
from scipy.spatial.transform import Rotation

from mocap_rt.body.kinematics import angles_from_frames, forward_kinematics, other_xyz_name
from mocap_rt.body.skeleton import BodyModel, J

# the limbs bent by two-link IK: root -> (middle, end)
_LIMBS = {J[f"{root}_{s}"]: (J[f"{mid}_{s}"], J[f"{end}_{s}"])
          for s in ("l", "r") for root, mid, end in (("shoulder", "elbow", "wrist"), ("hip", "knee", "ankle"))}
ORDER = 2            # the Butterworth's order; run both ways, 4 (Pose2Sim's default)
JUMP_M = 0.5         # a joint moving more than this in one frame starts a new run


def _labels(keep: np.ndarray, jump: np.ndarray) -> np.ndarray:
    """Run labels (F,) int: frames of one run share a label; -1 where not ``keep``. A run
    also ends before frame t where ``jump[t - 1]`` (jump: (F - 1,) bool)."""
    start = np.concatenate([[True], jump | ~keep[:-1]]) & keep
    lab = np.cumsum(start) - 1
    return np.where(keep, lab, -1)


def _filter_labelled(x: np.ndarray, lab: np.ndarray, b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """x (F, D) filtered within each run of equal label (>= 0); elsewhere unchanged."""
    out = x.copy()
    pad = 3 * max(len(a), len(b))
    for r in np.unique(lab[lab >= 0]):
        idx = np.flatnonzero(lab == r)
        if idx.size > pad:
            out[idx] = filtfilt(b, a, x[idx], axis=0)
    return out


def _closest_name(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """X-Y-Z angles (F, 3), each row the one of its rotation's two names (|Y| <= 90 deg, or
    (x + pi, pi - y, z + pi) wrapped) nearer to ``reference`` (F, 3): the solver's names, so
    that a BVH channel does not jump where an arm is raised over the shoulder."""
    other = np.array([other_xyz_name(*row) for row in angles.tolist()])

    def dist(u):
        return np.abs(np.angle(np.exp(1j * (u - reference)))).sum(axis=1)
    return np.where((dist(other) < dist(angles))[:, None], other, angles)


def _least_rotations(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) the least rotations taking directions u (N, 3) to v (N, 3)."""
    axis = np.cross(u, v)
    s = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(s, np.einsum("ij,ij->i", u, v))
    rotvec = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-300)[:, None] * angle[:, None], 0.0)
    return Rotation.from_rotvec(rotvec).as_matrix()


def _kabsch(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(N, 3, 3) the rotations R minimising sum_k |R A[n, k] - B[n, k]|^2, A and B (N, K, 3)."""
    U, _, Vt = np.linalg.svd(np.einsum("nki,nkj->nij", A, B))
    V = np.swapaxes(Vt, 1, 2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    D = np.zeros((len(A), 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    return V @ D @ np.swapaxes(U, 1, 2)


def _two_link(root: np.ndarray, goal: np.ndarray, pole: np.ndarray, a: float, b: float) -> np.ndarray:
    """(N, 3) the middle joints of two-link chains from ``root`` (N, 3) reaching for ``goal``
    (N, 3), bones ``a`` then ``b`` long, bent in the plane of root, goal and ``pole`` (N, 3)."""
    reach = goal - root
    d = np.linalg.norm(reach, axis=1)
    u = reach / np.maximum(d, 1e-12)[:, None]
    side = pole - root
    side -= u * np.einsum("ij,ij->i", side, u)[:, None]
    v = side / np.maximum(np.linalg.norm(side, axis=1), 1e-12)[:, None]
    d = np.clip(d, abs(a - b) + 1e-9, a + b - 1e-9)
    cos = np.clip((a * a + d * d - b * b) / (2 * a * d), -1.0, 1.0)
    return root + a * (cos[:, None] * u + np.sqrt(1 - cos * cos)[:, None] * v)


def retarget(model: BodyModel, rotations: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """World frames (N, J, 3, 3) of ``model`` moved from ``rotations`` (N, J, 3, 3) so that its
    bones point at the joint positions ``targets`` (N, J, 3) (module doc, step 2), from the root
    (at its target) outwards: each joint's bones aimed from where the joint has come to lie, so
    that what its parents missed is not passed on; each limb (shoulder or hip ->
    elbow or knee -> wrist or ankle) bent as the analytic IK bends it, to reach its end's target
    from where its root came to lie, in the plane of its middle joint's target."""
    out = np.empty_like(rotations)
    targets = targets.copy()
    at = np.empty_like(targets)                    # where the joints come to lie
    at[:, 0] = targets[:, 0]
    for j, p in enumerate(model.parents):
        kids = np.flatnonzero(model.parents == j)
        R = rotations[:, j]
        if j in _LIMBS:
            mid, end = _LIMBS[j]
            targets[:, mid] = _two_link(at[:, j], targets[:, end], targets[:, mid],
                                        float(np.linalg.norm(model.offsets[mid])), float(np.linalg.norm(model.offsets[end])))
        aim = kids[np.linalg.norm(model.offsets[kids], axis=1) > 1e-9]
        if aim.size == 0:
            out[:, j] = out[:, p] @ np.swapaxes(rotations[:, p], 1, 2) @ R
        else:
            bones = np.einsum("nij,kj->nki", R, model.offsets[aim])      # the bones as solved
            aimed = targets[:, aim] - at[:, j][:, None]                   # ... and as they should point
            turn = _least_rotations(bones[:, 0], aimed[:, 0]) if aim.size == 1 else _kabsch(bones, aimed)
            out[:, j] = turn @ R
        for c in kids:
            at[:, c] = at[:, j] + out[:, j] @ model.offsets[c]
    return out


def smooth_poses(model: BodyModel, root: np.ndarray, angles: np.ndarray, posed: np.ndarray,
                 limb_valid: np.ndarray, fps: float, cutoff_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The low-passed poses of a clip (module doc): (root (F, 3), angles (F, J, 3), joints (F, J, 3)).

    ``model``: the body the poses are of; root (F, 3) metres; angles (F, J, 3) radians, X-Y-Z
    (``body.kinematics``); posed (F,) bool: frames with a pose (the others are returned as
    given); limb_valid (F, J) bool: joints measured (False where the limb's cue was missing and
    the limb held or put at rest: not filtered). ``cutoff_hz`` in (0, fps / 2)."""
    if not 0.0 < cutoff_hz < fps / 2:
        raise ValueError(f"smoothing cutoff must be in (0, {fps / 2:g}) Hz (half the frame rate), got {cutoff_hz}")
    root, angles = root.copy(), angles.copy()
    idx = np.flatnonzero(posed)
    joints = np.full(angles.shape, np.nan)
    if idx.size == 0:
        return root, angles, joints
    fk = [forward_kinematics(model, root[i], angles[i]) for i in idx]
    P = np.array([f[0] for f in fk])
    R = np.array([f[1] for f in fk])
    b, a = butter(ORDER, cutoff_hz / (fps / 2))
    aims = P.copy()
    gap = np.diff(idx) > 1
    for j in range(P.shape[1]):
        keep = limb_valid[idx, j]
        step = np.linalg.norm(np.diff(P[:, j], axis=0), axis=1)
        aims[:, j] = _filter_labelled(P[:, j], _labels(keep, gap | ~(step <= JUMP_M)), b, a)
    frames = retarget(model, R, aims)
    for n, i in enumerate(idx):
        angles[i] = _closest_name(angles_from_frames(model, frames[n]), angles[i])
        root[i] = aims[n, 0]
        joints[i] = forward_kinematics(model, root[i], angles[i])[0]
    return root, angles, joints
