"""Per-subject bone lengths: measured from joint positions, or estimated from the cues.

The paper needed the subject's segment lengths beforehand; here they are estimated
from the first seconds of a capture. Six cues do not see elbows or knees, so the
estimate scales a default adult (``BoneLengths()``) by one factor, the median of
three ratios between observed and model distances:

* head - torso (rigid in the model: ``trunk/2 + neck_head``), median over frames;
* torso - foot with the legs near straight: the 90th percentile over frames of each
  foot's distance, against the rest pose's;
* the shoulders-to-hands span is not used (arms are rarely straight).
"""

from __future__ import annotations

import numpy as np

from mocap_rt.body.skeleton import J, BoneLengths, body_model

C_HEAD, C_HAND_L, C_HAND_R, C_FOOT_L, C_FOOT_R, C_TORSO = range(6)
MIN_FRAMES = 10  # fewer valid frames than this: no estimate
LEG_PERCENTILE = 90.0


def _mean_dist(joints: np.ndarray, a: str, b: str) -> float:
    d = np.linalg.norm(joints[:, J[a]] - joints[:, J[b]], axis=-1)
    d = d[np.isfinite(d)]
    if d.size == 0:
        raise ValueError(f"no frame has both {a} and {b}")
    return float(np.median(d))


def bone_lengths_from_joints(joints: np.ndarray, foot_pitch_deg: float | None = None) -> BoneLengths:
    """Median segment lengths from joint positions (F, J, 3) metres in JOINT_NAMES order
    (e.g. a studio ``truth.npz``). The foot pitch is measured in frames where the shank
    is near vertical unless given."""
    joints = np.asarray(joints, dtype=np.float64).reshape(-1, len(J), 3)
    d = lambda a, b: _mean_dist(joints, a, b)  # noqa: E731
    sides = ("l", "r")
    avg = lambda a, b: float(np.mean([d(f"{a}_{s}", f"{b}_{s}") for s in sides]))  # noqa: E731
    if foot_pitch_deg is None:
        pitches = []
        for s in sides:
            shank = joints[:, J[f"ankle_{s}"]] - joints[:, J[f"knee_{s}"]]
            foot = joints[:, J[f"foot_{s}"]] - joints[:, J[f"ankle_{s}"]]
            cosang = np.einsum("fi,fi->f", shank, foot) / (np.linalg.norm(shank, axis=1) * np.linalg.norm(foot, axis=1))
            ang = np.degrees(np.arccos(np.clip(cosang[np.isfinite(cosang)], -1, 1)))
            pitches.extend(90.0 - ang)  # angle below the horizontal when the shank is vertical
        foot_pitch_deg = float(np.median(pitches)) if pitches else BoneLengths().foot_pitch_deg
    return BoneLengths(
        trunk_m=d("pelvis", "torso") + d("torso", "neck"), neck_head_m=d("neck", "head"),
        shoulder_half_width_m=d("shoulder_l", "shoulder_r") / 2,
        upper_arm_m=avg("shoulder", "elbow"), forearm_m=avg("elbow", "wrist"), hand_m=avg("wrist", "hand"),
        hip_half_width_m=d("hip_l", "hip_r") / 2, thigh_m=avg("hip", "knee"), shank_m=avg("knee", "ankle"),
        foot_m=avg("ankle", "foot"), foot_pitch_deg=foot_pitch_deg)


def estimate_bone_lengths(cues: np.ndarray, base: BoneLengths | None = None) -> BoneLengths | None:
    """Scale ``base`` to the subject from 3D cues (F, 6, 3) metres (NaN = missing).

    Returns None when fewer than ``MIN_FRAMES`` frames have the needed cues.
    """
    base = base or BoneLengths()
    cues = np.asarray(cues, dtype=np.float64).reshape(-1, 6, 3)
    rest = body_model(base).rest_positions()
    ratios = []
    ht = np.linalg.norm(cues[:, C_HEAD] - cues[:, C_TORSO], axis=1)
    ht = ht[np.isfinite(ht)]
    if ht.size >= MIN_FRAMES:
        ratios.append(np.median(ht) / np.linalg.norm(rest[J["head"]] - rest[J["torso"]]))
    for c, jn in ((C_FOOT_L, "foot_l"), (C_FOOT_R, "foot_r")):
        tf = np.linalg.norm(cues[:, c] - cues[:, C_TORSO], axis=1)
        tf = tf[np.isfinite(tf)]
        if tf.size >= MIN_FRAMES:
            ratios.append(np.percentile(tf, LEG_PERCENTILE) / np.linalg.norm(rest[J[jn]] - rest[J["torso"]]))
    if not ratios:
        return None
    return base.scaled(float(np.median(ratios)))
