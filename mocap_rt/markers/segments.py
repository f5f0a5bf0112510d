"""Segment definitions: which markers ride on which body segment, which joints link them.

TOML format (file order is kept)::

    [segments.thigh_r]
    markers = ["RTHI", "RKNE", "RTH2", "RTH3"]

    [joints.knee_r]
    parent = "thigh_r"
    child = "shank_r"

Every segment needs at least 3 markers (a rigid frame needs 3 non-collinear points).
Unknown keys, segments a joint names but nobody defines, and (with
:meth:`SegmentSet.check_markers`) markers a trial does not contain are errors naming them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mocap_rt.config import FileFormatError, read_toml

MIN_MARKERS_PER_SEGMENT = 3  # a rigid frame needs three non-collinear points


class SegmentError(FileFormatError):
    """A segment definition that is malformed or does not match the marker data."""


@dataclass(frozen=True)
class Joint:
    name: str
    parent: str
    child: str


@dataclass(frozen=True)
class SegmentSet:
    """segments: name -> marker names (file order); joints: in file order."""

    segments: dict[str, tuple[str, ...]]
    joints: tuple[Joint, ...]
    source: str = ""

    def __post_init__(self) -> None:
        where = self.source or "segment definitions"
        for name, markers in self.segments.items():
            if len(markers) < MIN_MARKERS_PER_SEGMENT:
                raise SegmentError(f"{where}: segment {name!r} has {len(markers)} markers, "
                                   f"needs >= {MIN_MARKERS_PER_SEGMENT}")
            if len(set(markers)) != len(markers):
                raise SegmentError(f"{where}: segment {name!r} lists a marker twice: {list(markers)}")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise SegmentError(f"{where}: duplicate joint names {names}")
        for j in self.joints:
            unknown = [s for s in (j.parent, j.child) if s not in self.segments]
            if unknown:
                raise SegmentError(f"{where}: joint {j.name!r} refers to unknown segment(s) {unknown} "
                                   f"(defined: {list(self.segments)})")
            if j.parent == j.child:
                raise SegmentError(f"{where}: joint {j.name!r} has parent == child == {j.parent!r}")

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def joint(self, name: str) -> Joint:
        for j in self.joints:
            if j.name == name:
                return j
        raise SegmentError(f"{self.source or 'segment definitions'}: unknown joint {name!r} "
                           f"(defined: {list(self.joint_names)})")

    def neighbours(self, joint_name: str) -> tuple[str, ...]:
        """Joints sharing a segment with ``joint_name`` (their distances are bone lengths)."""
        j = self.joint(joint_name)
        mine = {j.parent, j.child}
        return tuple(o.name for o in self.joints if o.name != j.name and {o.parent, o.child} & mine)

    def check_markers(self, labels) -> None:
        """Raise SegmentError naming every segment marker missing from ``labels``."""
        have = set(labels)
        missing = {s: [m for m in ms if m not in have] for s, ms in self.segments.items()}
        missing = {s: ms for s, ms in missing.items() if ms}
        if missing:
            detail = "; ".join(f"{s}: {ms}" for s, ms in missing.items())
            raise SegmentError(f"{self.source or 'segment definitions'}: unknown marker name(s) "
                               f"not in the trial — {detail}")

    def used_segments(self) -> tuple[str, ...]:
        """Segments that some joint uses, in definition order."""
        used = {s for j in self.joints for s in (j.parent, j.child)}
        return tuple(s for s in self.segments if s in used)


def segments_from_dict(table: dict, source: str = "") -> SegmentSet:
    """Build a SegmentSet from the parsed TOML table (see module docstring)."""
    where = source or "segment definitions"
    extra = set(table) - {"segments", "joints"}
    if extra:
        raise SegmentError(f"{where}: unknown top-level table(s) {sorted(extra)} "
                           "(expected [segments.*] and [joints.*])")
    segs = table.get("segments", {})
    if not isinstance(segs, dict) or not segs:
        raise SegmentError(f"{where}: no [segments.<name>] tables")
    segments: dict[str, tuple[str, ...]] = {}
    for name, body in segs.items():
        if not isinstance(body, dict) or set(body) != {"markers"}:
            raise SegmentError(f"{where}: [segments.{name}] must have exactly one key 'markers', "
                               f"got {sorted(body) if isinstance(body, dict) else body!r}")
        markers = body["markers"]
        if not isinstance(markers, list) or not all(isinstance(m, str) for m in markers):
            raise SegmentError(f"{where}: segments.{name}.markers must be a list of strings")
        segments[name] = tuple(markers)
    joints = []
    for name, body in table.get("joints", {}).items():
        if not isinstance(body, dict) or set(body) != {"parent", "child"}:
            raise SegmentError(f"{where}: [joints.{name}] needs exactly 'parent' and 'child', "
                               f"got {sorted(body) if isinstance(body, dict) else body!r}")
        joints.append(Joint(name, str(body["parent"]), str(body["child"])))
    if not joints:
        raise SegmentError(f"{where}: no [joints.<name>] tables")
    return SegmentSet(segments, tuple(joints), source)


def load_segments(path: str | Path) -> SegmentSet:
    """Read a segment-definition TOML file."""
    return segments_from_dict(read_toml(path, "segment definition file", SegmentError), str(path))


def dumps_segments(segset: SegmentSet) -> str:
    """TOML text for ``segset`` (inverse of :func:`segments_from_dict`)."""
    out = []
    for name, markers in segset.segments.items():
        out += [f"[segments.{name}]", "markers = [" + ", ".join(f'"{m}"' for m in markers) + "]", ""]
    for j in segset.joints:
        out += [f"[joints.{j.name}]", f'parent = "{j.parent}"', f'child = "{j.child}"', ""]
    return "\n".join(out)


def shipped_segments_path(name: str) -> Path:
    """Path of an example segment set shipped as package data (``mocap_rt/data/segments_*.toml``).

    name : e.g. "biobuddy_qualisys", "biobuddy_vicon", "opensim_gait".
    """
    path = Path(__file__).resolve().parents[1] / "data" / f"segments_{name}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no shipped segment set {name!r} ({path})")
    return path
