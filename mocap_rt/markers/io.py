"""Marker trajectories: read C3D (via ezc3d) and TRC (OpenSim text), write TRC.

Everything is returned in **metres**, in the file's own axes (the shared files differ:
Qualisys/Vicon +Z up, OpenSim +Y up, the biobuddy "lightweight" Vicon set -Z up).
Axes are kept as they are because joint centres are invariant to a global rotation;
convert with :func:`MarkerData.transformed` if a consumer needs Z up.

Missing samples are NaN.  In C3D a sample is missing when its residual is negative
(the C3D convention), when ezc3d already gives NaN, or when all three coordinates are
exactly zero (what several exporters write for gaps).  In TRC empty fields are missing.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap_rt.config import FileFormatError
from mocap_rt.io.files import atomic_write_text

log = logging.getLogger(__name__)

# length unit name (lower case) -> metres per unit
UNIT_TO_M = {"mm": 1e-3, "cm": 1e-2, "dm": 1e-1, "m": 1.0, "in": 0.0254, "inch": 0.0254}


class MarkerFileError(FileFormatError):
    """A marker file that cannot be read; the message names the file and the field."""


@dataclass(frozen=True)
class MarkerData:
    """Marker trajectories of one trial.

    labels : tuple[str, ...], M marker names in file order.
    positions : (F, M, 3) float64, metres, the file's axes; NaN where missing.
    rate_hz : sampling rate in Hz.
    first_frame : frame number of row 0 (as stored in the file, usually 0 or 1).
    source : the file read, or "" for data made in memory.
    """

    labels: tuple[str, ...]
    positions: np.ndarray
    rate_hz: float
    first_frame: int = 0
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[2] != 3 or pos.shape[1] != len(self.labels):
            raise ValueError(f"positions must be (F, {len(self.labels)}, 3), got {pos.shape}")
        if len(set(self.labels)) != len(self.labels):
            dup = sorted({x for x in self.labels if self.labels.count(x) > 1})
            raise ValueError(f"duplicate marker labels {dup} in {self.source or 'marker data'}")
        object.__setattr__(self, "positions", pos)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def times_s(self) -> np.ndarray:
        """(F,) float64 seconds from row 0."""
        return np.arange(self.n_frames) / float(self.rate_hz)

    def index(self, name: str) -> int:
        try:
            return self.labels.index(name)
        except ValueError:
            raise KeyError(f"marker {name!r} not in {self.source or 'marker data'}") from None

    def select(self, names) -> np.ndarray:
        """(F, len(names), 3) positions of the named markers, in the order given."""
        return self.positions[:, [self.index(n) for n in names], :]

    def transformed(self, rotation: np.ndarray) -> "MarkerData":
        """Copy with every position rotated: p' = rotation @ p (rotation (3, 3))."""
        pos = self.positions @ np.asarray(rotation, dtype=np.float64).T
        return MarkerData(self.labels, pos, self.rate_hz, self.first_frame, self.source, dict(self.meta))


def read_markers(path: str | Path) -> MarkerData:
    """Read a ``.c3d`` or ``.trc`` file by its suffix."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".c3d":
        return read_c3d(path)
    if suffix == ".trc":
        return read_trc(path)
    raise MarkerFileError(f"{path}: unknown marker file type {suffix!r} (expected .c3d or .trc)")


def _unit_scale(unit: str, where: str) -> float:
    key = unit.strip().lower()
    if key not in UNIT_TO_M:
        raise MarkerFileError(f"{where}: unknown length unit {unit!r} (known: {sorted(UNIT_TO_M)})")
    return UNIT_TO_M[key]


def read_c3d(path: str | Path) -> MarkerData:
    """Read the 3D points of a C3D file with ezc3d; metres, NaN for missing samples."""
    import ezc3d

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such marker file")
    declared = _c3d_declared_frames(path)     # before ezc3d: junk can make it abort the process
    try:
        c3d = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises RuntimeError/IOError for corrupt files
        raise MarkerFileError(f"{path}: not a readable C3D file ({exc})") from exc
    try:
        point = c3d["parameters"]["POINT"]
        labels = [str(x).strip() for x in point["LABELS"]["value"]]
        # long label lists continue in LABELS2, LABELS3, ...
        k = 2
        while f"LABELS{k}" in point:
            labels += [str(x).strip() for x in point[f"LABELS{k}"]["value"]]
            k += 1
        units = point["UNITS"]["value"][0] if point.get("UNITS", {}).get("value") else "mm"
        rate = float(np.asarray(point["RATE"]["value"]).ravel()[0])
        data = np.asarray(c3d["data"]["points"], dtype=np.float64)  # (4, M, F)
        residuals = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=np.float64)  # (1, M, F)
        first = int(c3d["header"]["points"]["first_frame"])
    except (KeyError, IndexError, TypeError) as exc:
        raise MarkerFileError(f"{path}: C3D POINT section incomplete ({exc!r})") from exc
    if declared is not None and data.shape[2] < declared:
        raise MarkerFileError(f"{path}: the header declares {declared} frames but {data.shape[2]} could be "
                              f"read (file cut?)")
    n_points = data.shape[1]
    labels = labels[:n_points] + [f"*{i}" for i in range(len(labels), n_points)]
    if not (math.isfinite(rate) and rate > 0):
        raise MarkerFileError(f"{path}: POINT:RATE must be positive, got {rate}")
    scale = _unit_scale(str(units), f"{path}: POINT:UNITS")
    pos = np.transpose(data[:3], (2, 1, 0)) * scale  # (F, M, 3)
    missing = (residuals[0].T < 0) | np.all(pos == 0.0, axis=2) | np.any(~np.isfinite(pos), axis=2)
    pos[missing] = np.nan
    labels = _dedupe(labels, path)
    log.debug("%s: %d frames, %d markers, %.1f Hz, %.1f%% missing", path, pos.shape[0],
              pos.shape[1], rate, 100.0 * missing.mean() if missing.size else 0.0)
    return MarkerData(tuple(labels), pos, rate, first, str(path), {"units_in_file": str(units)})


def _c3d_declared_frames(path: Path) -> int | None:
    """The frame count a C3D file's own header declares (words 4-5: first and last frame,
    1-based), read from the raw bytes: ezc3d shortens its copy of the header to the frames it
    could read, so a cut file would look whole. None when the header cannot tell (16-bit last
    frame saturated). ``MarkerFileError`` when the file has no C3D signature (byte 2 = 0x50, a
    parameter block with a processor type): ezc3d aborts the whole process on some such files."""
    with open(path, "rb") as fh:
        head = fh.read(512)
        if len(head) < 512 or head[1] != 0x50 or head[0] < 2:
            raise MarkerFileError(f"{path}: not a C3D file (no C3D header signature)")
        fh.seek((head[0] - 1) * 512)
        param = fh.read(4)
    if len(param) < 4 or param[3] not in (84, 85, 86):
        raise MarkerFileError(f"{path}: not a C3D file (parameter section missing or cut)")
    order = ">" if param[3] == 86 else "<"              # 84 Intel, 85 DEC: little-endian; 86 MIPS
    first, last = struct.unpack(order + "HH", head[6:10])
    if last == 0xFFFF or last < first:
        return None
    return last - first + 1


def _dedupe(labels: list[str], path: Path) -> list[str]:
    """Empty or repeated labels get a suffix so that every marker stays addressable."""
    seen: dict[str, int] = {}
    out = []
    for i, name in enumerate(labels):
        name = name or f"*{i}"
        if name in seen:
            seen[name] += 1
            new = f"{name}#{seen[name]}"
            log.warning("%s: repeated marker label %r renamed %r", path, name, new)
            name = new
        else:
            seen[name] = 0
        out.append(name)
    return out


def read_trc(path: str | Path) -> MarkerData:
    """Read an OpenSim TRC file (tab separated, 5 header lines); metres, NaN where empty."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such marker file")
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise MarkerFileError(f"{path}: line 1: not a TRC file (expected 'PathFileType' header)")
    keys = lines[1].split("\t")
    values = lines[2].split("\t")
    header = {k.strip(): v.strip() for k, v in zip(keys, values)}
    for required in ("DataRate", "NumMarkers", "Units"):
        if required not in header:
            raise MarkerFileError(f"{path}: line 2-3: header field {required!r} missing")
    try:
        rate = float(header["DataRate"])
        n_markers = int(header["NumMarkers"])
    except ValueError as exc:
        raise MarkerFileError(f"{path}: line 3: bad DataRate/NumMarkers ({exc})") from exc
    if not (math.isfinite(rate) and rate > 0):
        raise MarkerFileError(f"{path}: line 3: DataRate must be a positive number, got {header['DataRate']!r}")
    scale = _unit_scale(header["Units"], f"{path}: line 3: Units")
    names_row = lines[3].split("\t")
    if len(names_row) < 2 or names_row[0].strip() != "Frame#":
        raise MarkerFileError(f"{path}: line 4: expected 'Frame#\\tTime\\t<marker names>'")
    labels = [n.strip() for n in names_row[2:] if n.strip()]
    if len(labels) != n_markers:
        raise MarkerFileError(f"{path}: line 4: {len(labels)} marker names but NumMarkers={n_markers}")
    width = 2 + 3 * n_markers
    rows = []
    frames = []
    for lineno, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        fields = line.rstrip("\r\n").split("\t")
        if len(fields) > width and all(not f.strip() for f in fields[width:]):
            fields = fields[:width]
        if len(fields) < width:  # trailing empty markers may be cut off entirely
            fields = fields + [""] * (width - len(fields))
        if len(fields) != width:
            raise MarkerFileError(f"{path}: line {lineno}: {len(fields)} fields, expected {width}")
        try:
            frames.append(int(float(fields[0])))
            rows.append([float(f) if f.strip() else np.nan for f in fields[2:]])
        except ValueError as exc:
            raise MarkerFileError(f"{path}: line {lineno}: not a number ({exc})") from exc
    if not rows:
        raise MarkerFileError(f"{path}: no data rows")
    declared = header.get("NumFrames", "").strip()
    if declared and declared != str(len(rows)):
        raise MarkerFileError(f"{path}: line 3: NumFrames={declared} but the file has {len(rows)} data rows "
                              f"(cut or edited?)")
    pos = np.asarray(rows, dtype=np.float64).reshape(len(rows), n_markers, 3) * scale
    pos[np.any(~np.isfinite(pos), axis=2)] = np.nan
    return MarkerData(tuple(_dedupe(labels, path)), pos, rate, frames[0], str(path),
                      {"units_in_file": header["Units"]})


def write_trc(path: str | Path, data: MarkerData, units: str = "mm") -> None:
    """Write ``data`` as an OpenSim TRC file in ``units`` (missing samples as empty fields).

    The file is written to a temporary name and renamed, so an existing file is never left
    half-written.
    """
    path = Path(path)
    scale = _unit_scale(units, f"{path}: units")
    n_frames, n_markers, _ = data.positions.shape
    out = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{data.rate_hz:.6g}\t{data.rate_hz:.6g}\t{n_frames}\t{n_markers}\t{units}\t{data.rate_hz:.6g}\t"
        f"{data.first_frame}\t{n_frames}",
        "Frame#\tTime\t" + "\t".join(f"{name}\t\t" for name in data.labels).rstrip("\t"),
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, n_markers + 1)),
        "",
    ]
    values = data.positions / scale
    values = np.where(np.isfinite(values), values, np.nan).reshape(n_frames, -1)
    times = data.times_s
    # one %-format per row (fast for long recordings); "nan" (the only letters in the rows)
    # becomes the empty field of a missing sample
    row = "%d\t%.6f\t" + "\t".join(["%.6f"] * (3 * n_markers))
    rows = "\n".join(row % (data.first_frame + f, times[f], *values[f]) for f in range(n_frames))
    out.append(rows.replace("nan", ""))
    atomic_write_text(path, "\n".join(out) + "\n")
