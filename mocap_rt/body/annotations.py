"""The thesis' two-view offline pipeline (seed digest B.2-B.4, B.7) from an annotations file.

Annotations JSON (paths relative to the file)::

    {
      "rig": "rig.toml",                  # Pose2Sim/aniposelib TOML; two cameras are used
      "cameras": ["cam_1", "cam_2"],      # optional: which two (default: the first two)
      "bones": "bones.toml",              # optional [bones] table (default: an adult)
      "points": {                         # end effectors, distorted pixels per camera
        "head":   {"cam_1": [u, v], "cam_2": [u, v]},
        "hand_l": {...}, "hand_r": {...}, "foot_l": {...}, "foot_r": {...}
      },
      "segments": {                       # limb segments: two pixels on the segment per camera,
        "hand_l-wrist_l": {"cam_1": [[u, v], [u, v]], "cam_2": [[u, v], [u, v]]},
        ...                               # the first pixel nearer the first joint named
      }
    }

The needed segments are ``refit.SEGMENTS`` (e.g. ``foot_l-ankle_l``, ``ankle_l-knee_l``,
``knee_l-hip_l``, ``hand_l-wrist_l``, ``wrist_l-elbow_l``, ``elbow_l-shoulder_l``,
``head-neck``). The two pixels of a segment need not be the joints themselves nor
correspond between the views: only the image line matters (B.2).

Pipeline: end effectors by two-view linear triangulation (B.3), segment directions by
``line_direction_two_views`` (B.2), the bone-length refit (B.4), then the improved CCD
(B.7) back onto the measured end effectors.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap_rt.body.ik_problem import IkResult
from mocap_rt.body.refit import SEGMENTS, pose_from_refit, refit_skeleton
from mocap_rt.body.skeleton import END_EFFECTORS, BodyModel, BoneLengths, body_model, read_bone_lengths
from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.rig import read_rig
from mocap_rt.geometry.triangulate import line_direction_two_views, triangulate_dlt


@dataclass(frozen=True)
class Annotations:
    """Parsed annotations: two cameras, pixels (distorted) and the bone lengths."""

    cameras: tuple[Camera, Camera]
    points: dict[str, np.ndarray]                   # name -> (2, 2) pixels, one row per camera
    segments: dict[tuple[str, str], np.ndarray]     # (from, to) -> (2, 2, 2) [camera, endpoint, uv]
    lengths: BoneLengths
    path: Path


def _pix(value, shape, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: not numbers: {value!r}") from None
    if a.shape != shape or not np.isfinite(a).all():
        raise ValueError(f"{where}: expected finite pixels of shape {shape}, got {value!r}")
    return a


def read_annotations(path: str | Path) -> Annotations:
    """Parse and validate an annotations JSON file (errors name the file and field)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: top level must be an object")
    for key in ("rig", "points", "segments"):
        if key not in doc:
            raise ValueError(f"{path}: missing field {key!r}")
    rig = read_rig(path.parent / doc["rig"])
    names = doc.get("cameras") or list(rig.names)[:2]
    if len(names) != 2:
        raise ValueError(f"{path}: 'cameras' must name exactly two cameras, got {names}")
    try:
        cams = (rig[names[0]], rig[names[1]])
    except (KeyError, IndexError) as exc:
        raise ValueError(f"{path}: 'cameras': {exc}") from None
    lengths = read_bone_lengths(path.parent / doc["bones"]) if doc.get("bones") else BoneLengths()
    points = {}
    for eff in END_EFFECTORS:
        entry = doc["points"].get(eff)
        if not isinstance(entry, dict):
            raise ValueError(f"{path}: points.{eff} missing (needs one pixel per camera)")
        points[eff] = np.stack([_pix(entry.get(c.name), (2,), f"{path}: points.{eff}.{c.name}") for c in cams])
    segments = {}
    for a, b in SEGMENTS:
        key = f"{a}-{b}"
        entry = doc["segments"].get(key)
        if not isinstance(entry, dict):
            raise ValueError(f"{path}: segments.{key} missing (needs two pixels per camera)")
        segments[(a, b)] = np.stack([_pix(entry.get(c.name), (2, 2), f"{path}: segments.{key}.{c.name}")
                                     for c in cams])
    return Annotations(cams, points, segments, lengths, path)


def _undistorted_px(cam: Camera, uv: np.ndarray) -> np.ndarray:
    xy = cam.undistort_pixels(np.atleast_2d(uv))
    return xy @ cam.K[:2, :2].T + cam.K[:2, 2]


@dataclass(frozen=True)
class TwoViewPose:
    """Result of the pipeline: measured points, refit joints, solved pose."""

    effectors: dict[str, np.ndarray]                 # triangulated end effectors (3,)
    directions: dict[tuple[str, str], np.ndarray]    # measured unit segment directions (3,)
    refit_joints: np.ndarray                         # (J, 3) after the B.4 refit
    root_pos: np.ndarray                             # (3,) pelvis
    ik: IkResult                                     # angles (J, 3) and end-effector errors
    joints: np.ndarray                               # (J, 3) final joints
    model: BodyModel


def pose_from_annotations(ann: Annotations) -> TwoViewPose:
    """Run the two-view pipeline on parsed annotations."""
    from mocap_rt.body.kinematics import forward_kinematics

    c1, c2 = ann.cameras
    P = np.stack([c1.P, c2.P])
    effectors = {}
    for name, uv in ann.points.items():
        und = np.stack([_undistorted_px(c1, uv[0]), _undistorted_px(c2, uv[1])])   # (2, 1, 2)
        X = triangulate_dlt(P, und)[0]
        if not np.isfinite(X).all():
            raise ValueError(f"{ann.path}: points.{name}: the two views do not triangulate")
        effectors[name] = X
    directions = {}
    for (a, b), seg in ann.segments.items():
        a1, b1 = _undistorted_px(c1, seg[0])
        a2, b2 = _undistorted_px(c2, seg[1])
        d = line_direction_two_views(c1.P, a1, b1, c2.P, a2, b2)
        if not np.isfinite(d).all():
            raise ValueError(f"{ann.path}: segments.{a}-{b}: no 3D direction (line in an epipolar plane?)")
        directions[(a, b)] = d
    model = body_model(ann.lengths, "full")
    refit = refit_skeleton(effectors, directions, ann.lengths)
    root, res = pose_from_refit(model, refit, effectors)
    joints = forward_kinematics(model, root, res.angles)[0]
    return TwoViewPose(effectors, directions, refit, root, res, joints, model)
