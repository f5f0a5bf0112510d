"""Joint trajectories as marker files for biomechanics tools: ``poses.c3d`` and ``poses.trc``.

Every body joint (``JOINT_NAMES``) becomes one point/marker labelled with its name, in
**millimetres**, at the pose rate. Rows are placed on a regular time grid from the first
frame id to the last, so that a frame the service dropped is an empty row (missing
marker) and the time column stays true: row ``i`` is frame ``frames[0] + i``.

* ``.trc`` — OpenSim / Pose2Sim conventions: **Y up**, right-handed, tab-separated,
  5 header lines, ``Frame#`` from 1, ``Time`` from 0 s. ``p_trc = WORLD_TO_Y_UP @ p_world``
  maps the world's (X, Y, Z) to (X, Z, -Y): a -90 degree rotation about X, the
  ``trc_Zup_to_Yup`` conversion of Pose2Sim and the axes of ``poses.bvh``.
* ``.c3d`` — the world frame as it is (**Z up**, the convention of C3D labs), written
  with ezc3d; ``POINT:UNITS`` = ``mm``, ``POINT:RATE`` = fps, ``POINT:LABELS`` = joint
  names; a missing sample has residual -1 (the C3D convention) and zero coordinates.

Both files are written to a temporary name and renamed over the target, so a reader
(or a crash) never sees a half-written file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from mocap_rt.body.bvh_export import WORLD_TO_BVH as WORLD_TO_Y_UP   # world Z up -> Y up (X, Z, -Y)
from mocap_rt.markers.io import MarkerData, write_trc
from mocap_rt.names import JOINT_NAMES
TRC_FIRST_FRAME = 1          # OpenSim numbers TRC frames from 1


def regular_rows(frames: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(F', J, 3) ``joints`` on the regular grid ``frames[0] .. frames[-1]``, NaN in gaps.

    frames : (F,) int, strictly increasing frame ids.  joints : (F, J, 3) float, any unit.
    """
    frames = np.asarray(frames, np.int64).reshape(-1)
    joints = np.asarray(joints, np.float64)
    if joints.ndim != 3 or joints.shape[0] != frames.shape[0] or joints.shape[2] != 3:
        raise ValueError(f"joints must be (F, J, 3) with F = {frames.shape[0]} frames, got {joints.shape}")
    if frames.size == 0:
        return joints.copy()
    if np.any(np.diff(frames) <= 0):
        raise ValueError("frame ids must be strictly increasing")
    out = np.full((int(frames[-1] - frames[0]) + 1, joints.shape[1], 3), np.nan)
    out[frames - frames[0]] = joints
    return out


def _check(joints: np.ndarray, names, fps: float) -> tuple[np.ndarray, tuple[str, ...]]:
    joints = np.asarray(joints, np.float64)
    names = tuple(names)
    if joints.ndim != 3 or joints.shape[1:] != (len(names), 3):
        raise ValueError(f"joints must be (F, {len(names)}, 3), got {joints.shape}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be > 0, got {fps}")
    return joints, names


def write_joints_trc(path: str | Path, joints: np.ndarray, fps: float,
                     names=JOINT_NAMES) -> None:
    """Write ``joints`` (F, J, 3) metres, world Z up, as an OpenSim TRC (Y up, mm).

    Row ``i`` is frame ``TRC_FIRST_FRAME + i`` at ``i / fps`` s; NaN samples are empty fields.
    """
    joints, names = _check(joints, names, fps)
    data = MarkerData(names, joints @ WORLD_TO_Y_UP.T, float(fps), TRC_FIRST_FRAME, str(path))
    write_trc(path, data, units="mm")


def write_joints_c3d(path: str | Path, joints: np.ndarray, fps: float,
                     names=JOINT_NAMES) -> None:
    """Write ``joints`` (F, J, 3) metres, world Z up, as C3D points (Z up, mm) with ezc3d.

    NaN samples get residual -1 and coordinates 0 (missing, by the C3D convention).
    """
    import ezc3d

    joints, names = _check(joints, names, fps)
    path = Path(path)
    n_frames, n_points, _ = joints.shape
    missing = ~np.isfinite(joints).all(axis=2)                       # (F, J)
    pts = np.ones((4, n_points, n_frames))
    pts[:3] = np.transpose(np.where(missing[..., None], 0.0, joints * 1e3), (2, 1, 0))
    residuals = np.where(missing.T, -1.0, 0.0)[None]                 # (1, J, F)
    c3d = ezc3d.c3d()
    point = c3d["parameters"]["POINT"]
    point["RATE"]["value"] = [float(fps)]
    point["LABELS"]["value"] = names
    point["UNITS"]["value"] = ["mm"]
    c3d["data"]["points"] = pts
    c3d["data"]["meta_points"] = {"residuals": residuals,
                                  "camera_masks": np.zeros((7, n_points, n_frames), bool)}
    c3d.add_parameter("POINT", "DESCRIPTIONS", tuple("" for _ in names))
    # ezc3d decides the format by the suffix: the temporary name keeps ".c3d"
    tmp = path.with_name(path.stem + ".tmp.c3d")
    c3d.write(str(tmp))
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    tmp.replace(path)


def write_pose_exports(stem: str | Path, frames: np.ndarray, joints: np.ndarray, fps: float,
                       names=JOINT_NAMES) -> tuple[Path, Path]:
    """``STEM.c3d`` and ``STEM.trc`` of poses ``joints`` (F, J, 3) metres, world, at frame ids
    ``frames`` (F,) (gaps become missing rows). Returns the two paths."""
    stem = Path(stem)
    grid = regular_rows(frames, joints)
    c3d_path, trc_path = stem.with_name(stem.name + ".c3d"), stem.with_name(stem.name + ".trc")
    write_joints_c3d(c3d_path, grid, fps, names)
    write_joints_trc(trc_path, grid, fps, names)
    return c3d_path, trc_path
