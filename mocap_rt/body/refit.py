"""Bone-length refit of measured joints (seed digest B.4) and the pose it leads to.

Input: the triangulated end effectors (head, hands, feet) and the measured 3D
direction of every limb segment (B.2), plus the subject's ``BoneLengths``.

1. From each end effector walk *along the measured directions* with the known bone
   lengths: foot -> ankle -> knee -> hip, hand -> wrist -> elbow -> shoulder,
   head -> neck.
2. Join the blocks: the hip-to-hip and shoulder-to-shoulder vectors get their known
   lengths (both ends moved symmetrically along the measured vector); the pelvis is
   the hips' midpoint P1; P2 is the foot of the perpendicular from P1 to the shoulder
   line L1 (the spine is perpendicular to the shoulders); the two shoulder blocks slide
   along L1 so that P2 is their midpoint (symmetry); the neck is P2 and the head is
   put at its known distance from P2 along the measured neck->head direction. The
   torso joint is the midpoint of pelvis and neck.
3. Refitting moves the end effectors off their measurements; ``pose_from_refit``
   builds the body-model angles from the refit joints (bone frames, B.5) and the
   improved CCD brings the end effectors back to the measurements.
"""

from __future__ import annotations

import numpy as np

from mocap_rt.body.ccd import CcdConfig, solve_ccd
from mocap_rt.body.ik_problem import IkResult
from mocap_rt.body.kinematics import angles_from_frames, other_xyz_name
from mocap_rt.body.skeleton import END_EFFECTORS, J, N_JOINTS, BodyModel, BoneLengths

# Chains walked from each end effector: (joint reached, segment length attribute).
CHAINS: dict[str, tuple[tuple[str, str], ...]] = {
    "foot_l": (("ankle_l", "foot_m"), ("knee_l", "shank_m"), ("hip_l", "thigh_m")),
    "foot_r": (("ankle_r", "foot_m"), ("knee_r", "shank_m"), ("hip_r", "thigh_m")),
    "hand_l": (("wrist_l", "hand_m"), ("elbow_l", "forearm_m"), ("shoulder_l", "upper_arm_m")),
    "hand_r": (("wrist_r", "hand_m"), ("elbow_r", "forearm_m"), ("shoulder_r", "upper_arm_m")),
    "head": (("neck", "neck_head_m"),),
}
# The segments whose measured directions the refit needs, as (from, to) joint names,
# oriented from the end effector towards the root.
SEGMENTS: tuple[tuple[str, str], ...] = tuple(
    (prev, joint) for eff, chain in CHAINS.items()
    for prev, (joint, _) in zip((eff,) + tuple(j for j, _ in chain), chain))


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"degenerate direction {v}")
    return v / n


def refit_skeleton(effectors: dict[str, np.ndarray], directions: dict[tuple[str, str], np.ndarray],
                   lengths: BoneLengths) -> np.ndarray:
    """Joint positions (J, 3) metres in JOINT_NAMES order (B.4).

    effectors : {"head", "hand_l", "hand_r", "foot_l", "foot_r"} -> (3,) measured positions.
    directions : {(from, to)} -> (3,) unit direction of each segment of ``SEGMENTS``
        (from the end effector towards the root; the sign is fixed here if reversed).
    """
    P = np.full((N_JOINTS, 3), np.nan)
    for eff, chain in CHAINS.items():
        if eff not in effectors:
            raise ValueError(f"refit: missing end effector {eff!r}")
        cur = np.asarray(effectors[eff], dtype=np.float64)
        P[J[eff]] = cur
        prev = eff
        for joint, attr in chain:
            key = (prev, joint)
            if key not in directions:
                raise ValueError(f"refit: missing segment direction {prev}-{joint}")
            cur = cur + getattr(lengths, attr) * _unit(np.asarray(directions[key], dtype=np.float64))
            P[J[joint]] = cur
            prev = joint
    # hips: known distance, both ends moved symmetrically along the measured hip vector
    for a, b, half in (("hip_l", "hip_r", lengths.hip_half_width_m),
                       ("shoulder_l", "shoulder_r", lengths.shoulder_half_width_m)):
        mid = 0.5 * (P[J[a]] + P[J[b]])
        u = _unit(P[J[b]] - P[J[a]])
        shift_a = (mid - half * u) - P[J[a]]
        shift_b = (mid + half * u) - P[J[b]]
        _move_block(P, a, shift_a)
        _move_block(P, b, shift_b)
    pelvis = 0.5 * (P[J["hip_l"]] + P[J["hip_r"]])                       # P1
    sl, sr = P[J["shoulder_l"]], P[J["shoulder_r"]]
    u = _unit(sr - sl)                                                    # L1
    p2 = sl + u * ((pelvis - sl) @ u)                                    # foot of the perpendicular
    mid = 0.5 * (sl + sr)
    _move_block(P, "shoulder_l", p2 - mid)                                # symmetric about P2
    _move_block(P, "shoulder_r", p2 - mid)
    P[J["pelvis"]] = pelvis
    P[J["neck"]] = p2
    P[J["head"]] = p2 - lengths.neck_head_m * _unit(np.asarray(directions[("head", "neck")], dtype=np.float64))
    P[J["torso"]] = 0.5 * (pelvis + p2)
    return P


_BLOCKS = {"hip_l": ("hip_l", "knee_l", "ankle_l", "foot_l"), "hip_r": ("hip_r", "knee_r", "ankle_r", "foot_r"),
           "shoulder_l": ("shoulder_l", "elbow_l", "wrist_l", "hand_l"),
           "shoulder_r": ("shoulder_r", "elbow_r", "wrist_r", "hand_r")}


def _move_block(P: np.ndarray, root: str, shift: np.ndarray) -> None:
    for name in _BLOCKS[root]:
        P[J[name]] += shift


def _frame(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    z = _unit(z)
    x = x_hint - z * (x_hint @ z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross([0.0, 1.0, 0.0], z)
    x = x / np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def frames_from_joints(model: BodyModel, P: np.ndarray) -> np.ndarray:
    """(J, 3, 3) bone frames (B.5: Z along the bone) from joint positions (J, 3).

    Body frame: up = neck - pelvis, right = hip_r - hip_l. Limb frames take their X
    axis (flexion) normal to the limb's plane (upper and lower segment), falling back
    to the body's right for a straight limb.
    """
    up = _unit(P[J["neck"]] - P[J["pelvis"]])
    body = _frame(up, P[J["hip_r"]] - P[J["hip_l"]])
    right = body[:, 0]
    R = np.empty((N_JOINTS, 3, 3))
    R[J["pelvis"]] = body
    R[J["torso"]] = _frame(P[J["neck"]] - P[J["torso"]], right)
    R[J["neck"]] = R[J["head"]] = _frame(P[J["head"]] - P[J["neck"]], right)
    for s in ("l", "r"):
        for a, b, c, d, sign in (("shoulder", "elbow", "wrist", "hand", 1.0), ("hip", "knee", "ankle", "foot", -1.0)):
            pa, pb, pc, pd = (P[J[f"{n}_{s}"]] for n in (a, b, c, d))
            n = sign * np.cross(pb - pa, pc - pb)
            x = n if np.linalg.norm(n) > 1e-6 * np.linalg.norm(pb - pa) * np.linalg.norm(pc - pb) else right
            R[J[f"{a}_{s}"]] = _frame(pb - pa, x)
            R[J[f"{b}_{s}"]] = _frame(pc - pb, x)
            R[J[f"{c}_{s}"]] = R[J[f"{d}_{s}"]] = _frame(pd - pc, x)
    return R


def _limit_excess(a: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """How far (radians, summed) the angles ``a`` lie outside [lo, hi]."""
    return float(np.abs(a - np.clip(a, lo, hi)).sum())


def pose_from_refit(model: BodyModel, P: np.ndarray, effectors: dict[str, np.ndarray],
                    config: CcdConfig = CcdConfig(angle_tolerance_deg=30.0)) -> tuple[np.ndarray, IkResult]:
    """Model pose from refit joints, then CCD back to the measured end effectors.

    Returns (root_pos (3,), IkResult with angles (J, 3)).
    """
    R = frames_from_joints(model, P)
    raw = angles_from_frames(model, R)
    lo, hi = model.limits[..., 0], model.limits[..., 1]
    for j in np.flatnonzero(model.dof.all(axis=1)):   # a rotation's two names: the one nearer the limits
        alt = np.array(other_xyz_name(*raw[j]))
        if _limit_excess(alt, lo[j], hi[j]) < _limit_excess(raw[j], lo[j], hi[j]):
            raw[j] = alt
    angles = model.clamp(raw)
    angles[0] = raw[0]                      # the root's rotation is free
    root = P[J["pelvis"]]
    eff = np.array([J[n] for n in END_EFFECTORS])
    goals = np.array([effectors[n] for n in END_EFFECTORS], dtype=np.float64)
    res = solve_ccd(model, root, angles, eff, goals, reference=angles, solve_root=True, config=config)
    return root, res
