"""Joint centres for a whole trial: every joint of a segment definition, one method.

Each segment is preprocessed once (rigid fit, step A; marker order, step D) and shared
by the joints that use it.  Output joint centres are virtual markers named after the
joints, in the trial's frame and units (metres).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.markers.io import MarkerData
from mocap_rt.markers.joint_centres import METHODS, JointCentreFit, PreparedSegment, prepare_segment
from mocap_rt.markers.segments import SegmentSet

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BoneStats:
    """Distance between two joint centres over the trial (metres); NaN frames ignored."""

    joint_a: str
    joint_b: str
    mean_m: float
    std_m: float
    n_frames: int


@dataclass(frozen=True)
class TrialJointCentres:
    """names : J joint names (definition order); centres : (F, J, 3) metres, trial frame, NaN
    where not placed; fits : joint -> JointCentreFit; segments : segment -> PreparedSegment."""

    names: tuple[str, ...]
    centres: np.ndarray
    fits: dict[str, JointCentreFit]
    segments: dict[str, PreparedSegment]
    method: str
    rigid: bool
    rom_deg: dict[str, float]

    def as_marker_data(self, like: MarkerData) -> MarkerData:
        """The joint centres as virtual markers with ``like``'s rate and first frame."""
        return MarkerData(self.names, self.centres, like.rate_hz, like.first_frame, "", {"method": self.method})

    def bone_lengths(self, segset: SegmentSet) -> list[BoneStats]:
        """Mean/std distance for every pair of joints sharing a segment (each pair once)."""
        out = []
        idx = {n: i for i, n in enumerate(self.names)}
        for a in self.names:
            for b in segset.neighbours(a):
                if idx[b] <= idx[a]:
                    continue
                d = np.linalg.norm(self.centres[:, idx[a]] - self.centres[:, idx[b]], axis=1)
                d = d[np.isfinite(d)]
                out.append(BoneStats(a, b, float(d.mean()) if d.size else np.nan,
                                     float(d.std()) if d.size else np.nan, int(d.size)))
        return out


LOW_ROM_DEG = 20.0  # below this relative rotation the centre is poorly determined


def relative_rotation_range_deg(rot_parent: np.ndarray, rot_child: np.ndarray) -> float:
    """95th percentile angle (deg) of the child's rotation relative to the parent, about its mean.

    rot_parent, rot_child : (F, 3, 3) segment rotations (NaN where no pose).  A joint that
    hardly moves (say < 20 deg) has no well-defined functional centre: every method's
    answer is then dominated by noise.
    """
    ok = np.isfinite(rot_parent[:, 0, 0]) & np.isfinite(rot_child[:, 0, 0])
    if ok.sum() < 2:
        return 0.0
    rel = Rotation.from_matrix(np.matmul(rot_parent[ok].transpose(0, 2, 1), rot_child[ok]))
    return float(np.degrees(np.percentile((rel * rel.mean().inv()).magnitude(), 95)))


def joint_centres_for_trial(data: MarkerData, segset: SegmentSet, method: str = "patent", rigid: bool = True,
                            similarity: bool = False) -> TrialJointCentres:
    """Estimate every joint of ``segset`` from ``data``.

    Raises SegmentError naming unknown markers, ValueError for an unknown method or a
    segment whose markers are never seen together.
    """
    if method not in METHODS:
        raise ValueError(f"unknown joint-centre method {method!r} (choose from {sorted(METHODS)})")
    segset.check_markers(data.labels)
    prepared: dict[str, PreparedSegment] = {}
    for seg in segset.used_segments():
        names = segset.segments[seg]
        pts = data.select(names)
        seen = np.all(np.isfinite(pts), axis=2)  # (F, k)
        never = [n for n, s in zip(names, seen.any(axis=0)) if not s]
        if never:  # a marker with no data at all is dropped, not fatal, while 3 remain
            log.warning("segment %s: marker(s) %s have no data in %s; using the others", seg, never, data.source)
            keep = [k for k, n in enumerate(names) if n not in never]
            pts, seen = pts[:, keep], seen[:, keep]
        if pts.shape[1] < 3 or not np.any(seen.sum(axis=1) >= 3):
            raise ValueError(f"segment {seg!r}: fewer than 3 of its markers {list(names)} are seen together in any "
                             f"frame of {data.source or 'the trial'}" + (f" (never seen: {never})" if never else ""))
        try:
            prepared[seg] = prepare_segment(pts, rigid, similarity)
        except ValueError as exc:
            raise ValueError(f"segment {seg!r} ({data.source}): {exc}") from exc
    fits: dict[str, JointCentreFit] = {}
    rom: dict[str, float] = {}
    centres = np.full((data.n_frames, len(segset.joints), 3), np.nan)
    for k, joint in enumerate(segset.joints):
        try:
            fit = METHODS[method](prepared[joint.parent].points, prepared[joint.child].points)
        except (ValueError, np.linalg.LinAlgError) as exc:
            log.warning("joint %s: %s failed (%s); left empty", joint.name, method, exc)
            continue
        fits[joint.name] = fit
        centres[:, k] = fit.centre
        rom[joint.name] = relative_rotation_range_deg(prepared[joint.parent].rotation, prepared[joint.child].rotation)
        if rom[joint.name] < LOW_ROM_DEG:
            log.warning("joint %s moves only %.0f deg in this trial: its centre is poorly determined",
                        joint.name, rom[joint.name])
    return TrialJointCentres(segset.joint_names, centres, fits, prepared, method, rigid, rom)
