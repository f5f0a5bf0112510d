"""The studio subject's shape: capsules on the body points, each with a material.

A capsule is the set of points within ``radius`` of the segment ``a``-``b`` (a sphere
when a == b). Skin covers the head and hands, shoes the feet, a long-sleeved shirt the
trunk and arms, trousers the hips and legs. The neck is shirt (a collar), so that the
head's skin blob is the head alone.

Each cue (``mocap_rt.names.CUE_NAMES``) is one capsule whose centre is the cue's truth
point: head centre, hand centre, shoe centre, torso (pelvis-neck midpoint).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_rt.names import CUE_NAMES
from mocap_rt.studio.body_map import POINT_NAMES

# Materials, index order used by the renderer.
MATERIALS: tuple[str, ...] = ("skin", "shirt", "trousers", "shoe")
SKIN, SHIRT, TROUSERS, SHOE = range(4)
# Default albedos, BGR in [0, 1]. Skin: the median B, G, R of the skin class of the UCI
# Skin Segmentation data (real face pixels; ../shared/data/skin), 117, 152, 218 / 255;
# tests recompute it. Shirt: a mid blue; trousers: dark grey-brown; shoes: green. All
# far from skin chromaticity and from each other.
SKIN_BGR_UCI_MEDIAN = (117.0, 152.0, 218.0)
DEFAULT_ALBEDO_BGR: dict[str, tuple[float, float, float]] = {
    "skin": tuple(v / 255.0 for v in SKIN_BGR_UCI_MEDIAN),
    "shirt": (0.62, 0.30, 0.12),
    "trousers": (0.22, 0.24, 0.28),
    "shoe": (0.15, 0.62, 0.18),
}

# Capsules that make up the trunk (one visibility group).
TRUNK_CAPSULES = ("torso", "chest", "hips", "neck")

# Radii in metres (an adult of ~1.7 m).
HEAD_RADIUS_M = 0.095
HEAD_HALF_AXIS_M = 0.035   # head capsule half-length along the neck->head axis
NECK_RADIUS_M = 0.05
CHEST_RADIUS_M = 0.10
WAIST_RADIUS_M = 0.13
HIPS_RADIUS_M = 0.11
UPPER_ARM_RADIUS_M = 0.05
FOREARM_RADIUS_M = 0.04
HAND_RADIUS_M = 0.04
THIGH_RADIUS_M = 0.075
SHIN_RADIUS_M = 0.055
SHOE_RADIUS_M = 0.045


@dataclass(frozen=True)
class BodyPrimitives:
    """Capsules of one frame, world frame, metres.

    a, b : (P, 3) float64 segment ends; radius : (P,) float64; material : (P,) int64
    index into MATERIALS; names : (P,) capsule names; cue_index : (6,) int64, the
    capsule of each cue in CUE_NAMES order; group : (P,) int64, capsules of one rigid
    part share a group (the trunk: torso, chest, hips, neck), so that a cue hidden only
    behind its own part still counts as visible.
    """

    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    material: np.ndarray
    names: tuple[str, ...]
    cue_index: np.ndarray
    group: np.ndarray

    @property
    def centres(self) -> np.ndarray:
        """(P, 3) capsule centres."""
        return 0.5 * (self.a + self.b)


def body_primitives(points: np.ndarray) -> BodyPrimitives:
    """Capsules for one frame of body points: (len(POINT_NAMES), 3) world metres."""
    p = {n: points[i] for i, n in enumerate(POINT_NAMES)}
    caps: list[tuple[str, np.ndarray, np.ndarray, float, int]] = []

    up = p["head"] - p["neck"]
    up = up / max(np.linalg.norm(up), 1e-9)
    caps.append(("head", p["head"] - HEAD_HALF_AXIS_M * up, p["head"] + HEAD_HALF_AXIS_M * up,
                 HEAD_RADIUS_M, SKIN))
    neck_top = p["head"] - (HEAD_RADIUS_M + HEAD_HALF_AXIS_M) * up
    caps.append(("neck", p["neck"], neck_top, NECK_RADIUS_M, SHIRT))
    spine = p["neck"] - p["pelvis"]
    caps.append(("torso", p["pelvis"] + 0.15 * spine, p["neck"] - 0.15 * spine, WAIST_RADIUS_M, SHIRT))
    sl, sr = p["shoulder_l"], p["shoulder_r"]
    caps.append(("chest", sl + 0.3 * (sr - sl), sr + 0.3 * (sl - sr), CHEST_RADIUS_M, SHIRT))
    caps.append(("hips", p["hip_l"], p["hip_r"], HIPS_RADIUS_M, TROUSERS))
    for s in ("l", "r"):
        caps.append((f"upper_arm_{s}", p[f"shoulder_{s}"], p[f"elbow_{s}"], UPPER_ARM_RADIUS_M, SHIRT))
        caps.append((f"forearm_{s}", p[f"elbow_{s}"], p[f"wrist_{s}"], FOREARM_RADIUS_M, SHIRT))
        h, w = p[f"hand_{s}"], p[f"wrist_{s}"]
        caps.append((f"hand_{s}", h - 0.6 * (h - w), h + 0.6 * (h - w), HAND_RADIUS_M, SKIN))
        caps.append((f"thigh_{s}", p[f"hip_{s}"], p[f"knee_{s}"], THIGH_RADIUS_M, TROUSERS))
        caps.append((f"shin_{s}", p[f"knee_{s}"], p[f"ankle_{s}"], SHIN_RADIUS_M, TROUSERS))
        caps.append((f"foot_{s}", p[f"heel_{s}"], p[f"toe_{s}"], SHOE_RADIUS_M, SHOE))
    names = tuple(c[0] for c in caps)
    cue_index = np.array([names.index(c) for c in CUE_NAMES], dtype=np.int64)
    trunk = names.index("torso")
    group = np.array([trunk if n in TRUNK_CAPSULES else i for i, n in enumerate(names)], dtype=np.int64)
    return BodyPrimitives(
        a=np.array([c[1] for c in caps], dtype=np.float64),
        b=np.array([c[2] for c in caps], dtype=np.float64),
        radius=np.array([c[3] for c in caps], dtype=np.float64),
        material=np.array([c[4] for c in caps], dtype=np.int64),
        names=names,
        cue_index=cue_index,
        group=group,
    )
