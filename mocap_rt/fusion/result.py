"""What fusion gives per frame (``FusionResult``) and which joints of it are measured."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_rt.body.silhouette import SilhouetteTargets
from mocap_rt.body.skeleton import N_JOINTS, J
from mocap_rt.names import CUE_INDEX, N_CUES


@dataclass
class FusionResult:
    """One fused frame.

    cues_3d : (6, 3) metres, world; the cues measured this frame (filtered if
        ``use_filtered``), NaN where not reconstructed. cue_valid : (6,) bool.
    joints : (20, 3) metres, world, JOINT_NAMES order (NaN before the first full pose).
    bvh_frame : (n_channels,) motion row for ``BodyTracker.bvh_skeleton``.
    cameras_used : names of the cameras that contributed a cue.
    root_pos (3,), angles (20, 3) radians: the body model pose; pan_rad: the heading.
    pair : the frontal pair's camera names in "pair" mode, else ().
    cues_ik : (6, 3) the cues the IK used (measured, or predicted where missing);
    axes : (3, 3) body frame (right, forward, up) or None. swivel : (4,) the limb swivels
    the pose was solved with; targets : the frame's silhouettes (kept by ``fusion.offline``
    until the bone lengths are estimated, to solve the early frames again, and for the last
    ``RELABEL_BACK_FRAMES``, which a switch of the labels may refit).
    joint_valid : (20,) bool, False for joints of a limb whose end cue was missing (that
        limb is held where it was last estimated, or at the rest pose, ``identity.hold_limbs``)
        and for all joints when there was no pose.
    """

    frame: int
    cues_3d: np.ndarray
    cue_valid: np.ndarray
    joints: np.ndarray
    bvh_frame: np.ndarray
    cameras_used: tuple[str, ...]
    timings_ms: dict
    root_pos: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    angles: np.ndarray = field(default_factory=lambda: np.zeros((N_JOINTS, 3)))
    pan_rad: float = float("nan")
    pair: tuple[str, ...] = ()
    cues_ik: np.ndarray = field(default_factory=lambda: np.full((N_CUES, 3), np.nan))
    axes: np.ndarray | None = None
    joint_valid: np.ndarray = field(default_factory=lambda: np.zeros(N_JOINTS, dtype=bool))
    swivel: np.ndarray | None = None
    targets: SilhouetteTargets | None = None


# joints that depend on each hand/foot cue (the limb beyond the shoulder/hip)
LIMB_OF_CUE = {CUE_INDEX[f"{k}_{s}"]: [J[f"{n}_{s}"] for n in names]
                for s in ("l", "r") for k, names in (("hand", ("elbow", "wrist", "hand")),
                                                     ("foot", ("knee", "ankle", "foot")))}


def joint_validity(have: np.ndarray) -> np.ndarray:
    """(20,) bool: the joints measured when the cues ``have`` (6,) bool are present (a
    limb whose hand/foot cue is missing is held or at rest, ``identity.hold_limbs``)."""
    valid = np.ones(N_JOINTS, dtype=bool)
    for c, joints in LIMB_OF_CUE.items():
        if not have[c]:
            valid[joints] = False
    return valid
