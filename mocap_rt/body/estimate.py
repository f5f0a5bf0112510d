"""Per-subject bone lengths: measured from joint positions, or estimated from the cues.

The paper needed the subject's segment lengths beforehand; here they are estimated
from the first seconds of a capture (``estimate_bone_lengths``). Six cues do not see
elbows or knees, so the estimate scales a default adult (``BoneLengths()``) by three
group factors (trunk, legs, arms), see the function.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocap_rt.body.skeleton import BoneLengths, body_model
from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HAND_L, C_HAND_R, C_HEAD, C_TORSO, N_CUES, J

MIN_FRAMES = 10  # fewer valid frames than this: no estimate
LEG_PERCENTILE = 90.0
ARM_PERCENTILE = 97.0
MAX_TILT_DEG = 45.0  # a fitted trunk farther than this from the torso -> head line is not the person's


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


def _percentile(x: np.ndarray, q: float) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if x.size >= MIN_FRAMES else None


def estimate_bone_lengths(cues: np.ndarray, base: BoneLengths | None = None,
                          axes: np.ndarray | None = None) -> BoneLengths | None:
    """Scale ``base`` to the subject from 3D cues (F, 6, 3) metres (NaN = missing).

    Three group scales, each from a distance the cues measure (the proportions inside a
    group stay those of ``base``):

    * trunk, neck-head, shoulder and hip widths: the median head - torso distance
      (rigid in the model: trunk/2 + neck_head);
    * thigh, shank, foot: the ``LEG_PERCENTILE`` hip - foot distance (legs near
      straight) against thigh + |shank + foot|;
    * upper arm, forearm, hand: the ``ARM_PERCENTILE`` shoulder - hand distance (arms
      near straight) against their sum.

    Hips and shoulders are placed with the body frames ``axes`` (F, 3, 3) (columns
    right, forward, up, as ``analytic.body_axes``); without them, at the pelvis/neck on
    the torso -> head line (then the widths are ignored). A frame whose fitted up axis is
    more than ``MAX_TILT_DEG`` from its torso -> head line is left out of the limbs: there
    the fit is not the person (the first frames of jumping jacks, tilted 60 deg, made the arms
    47 % too long). Missing groups keep the trunk scale. Returns None when the head - torso
    distance has fewer than ``MIN_FRAMES`` frames.
    """
    base = base or BoneLengths()
    cues = np.asarray(cues, dtype=np.float64).reshape(-1, N_CUES, 3)
    up = cues[:, C_HEAD] - cues[:, C_TORSO]
    ht = _percentile(np.linalg.norm(up, axis=1), 50.0)
    if ht is None:
        return None
    s_trunk = ht / (base.trunk_m / 2 + base.neck_head_m)
    tr = base.scaled(s_trunk)
    if axes is None:
        unit_up = up / np.linalg.norm(up, axis=1, keepdims=True)
        right = np.zeros_like(up)
    else:
        axes = np.asarray(axes, dtype=np.float64).reshape(-1, 3, 3)
        unit_up, right = axes[:, :, 2], axes[:, :, 0]
        cos_tilt = np.einsum("fi,fi->f", unit_up, up) / np.linalg.norm(up, axis=1)
        cues = np.where((cos_tilt >= np.cos(np.radians(MAX_TILT_DEG)))[:, None, None], cues, np.nan)
    pelvis = cues[:, C_TORSO] - unit_up * (tr.trunk_m / 2)
    neck = cues[:, C_TORSO] + unit_up * (tr.trunk_m / 2)
    scales = {}
    rest = body_model(base).rest_positions()
    knee_foot = float(np.linalg.norm(rest[J["foot_r"]] - rest[J["knee_r"]]))
    groups = (("leg", pelvis, tr.hip_half_width_m, (C_FOOT_L, C_FOOT_R), LEG_PERCENTILE, base.thigh_m + knee_foot),
              ("arm", neck, tr.shoulder_half_width_m, (C_HAND_L, C_HAND_R), ARM_PERCENTILE,
               base.upper_arm_m + base.forearm_m + base.hand_m))
    for name, centre, half, (cl, cr), q, model_len in groups:
        d = np.concatenate([np.linalg.norm(cues[:, cl] - (centre - right * half), axis=1),
                            np.linalg.norm(cues[:, cr] - (centre + right * half), axis=1)])
        obs = _percentile(d, q)
        scales[name] = s_trunk if obs is None else max(0.5, obs / model_len)
    s_leg, s_arm = scales["leg"], scales["arm"]
    return replace(tr, thigh_m=base.thigh_m * s_leg, shank_m=base.shank_m * s_leg, foot_m=base.foot_m * s_leg,
                   upper_arm_m=base.upper_arm_m * s_arm, forearm_m=base.forearm_m * s_arm,
                   hand_m=base.hand_m * s_arm)
