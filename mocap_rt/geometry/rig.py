"""A rig: the cameras of one capture set-up, read from and written to one TOML file.

The file layout is the one Pose2Sim and aniposelib use::

    [cam_1]
    name = "cam_1"
    size = [640.0, 480.0]                  # width, height in pixels
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2]          # OpenCV order, 0/4/5/8 values
    rotation = [rx, ry, rz]                 # Rodrigues vector, world -> camera
    translation = [tx, ty, tz]              # metres, world -> camera
    fisheye = false

    [metadata]
    adjusted = false
    error = 0.0

Cameras keep file order (never sorted by name). Floats are written with ``repr`` so
that reading back gives the same bits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mocap_rt.config import FileFormatError, dumps_toml, read_toml
from mocap_rt.geometry.camera import Camera, look_at, rotation_from_rodrigues
from mocap_rt.io.files import atomic_write_text

# Camera.extra key holding the TOML table name when it differs from the camera name.
TABLE_KEY = "__table__"
_CAMERA_KEYS = {"name", "size", "matrix", "distortions", "rotation", "translation", "fisheye"}


class RigFileError(FileFormatError):
    """A rig file that cannot be read; the message names the file and the field."""


@dataclass(frozen=True)
class Rig:
    cameras: tuple[Camera, ...]
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "cameras", tuple(self.cameras))
        names = [c.name for c in self.cameras]
        if len(set(names)) != len(names):
            raise ValueError(f"rig has duplicate camera names: {names}")

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self):
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            for cam in self.cameras:
                if cam.name == key:
                    return cam
            raise KeyError(f"no camera named {key!r} in rig (cameras: {self.names})")
        return self.cameras[key]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def with_camera(self, camera: Camera) -> "Rig":
        """A new rig with ``camera`` replacing the one of the same name, or appended."""
        cams = list(self.cameras)
        for i, c in enumerate(cams):
            if c.name == camera.name:
                cams[i] = camera
                break
        else:
            cams.append(camera)
        return Rig(tuple(cams), dict(self.metadata))

    def subset(self, names: list[str]) -> "Rig":
        return Rig(tuple(self[n] for n in names), dict(self.metadata))


# ----------------------------------------------------------------------------- TOML
def _camera_table(cam: Camera) -> dict:
    table = {
        "name": cam.name,
        "size": [float(cam.width), float(cam.height)],
        "matrix": cam.K,
        "distortions": cam.dist,
        "rotation": cam.rvec,
        "translation": cam.t,
        "fisheye": False,
    }
    table.update({k: v for k, v in cam.extra.items() if k != TABLE_KEY})
    return table


def rig_to_toml(rig: Rig) -> str:
    tables = {}
    for cam in rig.cameras:
        key = str(cam.extra.get(TABLE_KEY, cam.name))
        if key in tables or key == "metadata":
            raise ValueError(f"rig: two cameras would be written to the same table [{key}]")
        tables[key] = _camera_table(cam)
    tables["metadata"] = {"adjusted": False, "error": 0.0, **rig.metadata}
    return dumps_toml(tables)


def write_rig(rig: Rig, path: str | Path) -> None:
    """Write atomically (temp file + rename), so a crash never leaves half a rig."""
    atomic_write_text(path, rig_to_toml(rig))


def _camera_from_table(key: str, table: dict, where: str) -> Camera:
    missing = [k for k in ("size", "matrix", "distortions", "rotation", "translation") if k not in table]
    if missing:
        raise RigFileError(f"{where}: [{key}] is missing {', '.join(missing)}")
    try:
        size = np.asarray(table["size"], dtype=np.float64).ravel()
        if size.size != 2:
            raise ValueError("size must be [width, height]")
        rot = np.asarray(table["rotation"], dtype=np.float64)
        rvec_source = None
        if rot.shape == (3,):
            R = rotation_from_rodrigues(rot)
            rvec_source = rot
        elif rot.shape == (3, 3):
            R = rot
        else:
            raise ValueError(f"rotation must be a Rodrigues vector or 3x3 matrix, got shape {rot.shape}")
        matrix = np.asarray(table["matrix"], dtype=np.float64)
        if matrix.shape != (3, 3):
            raise ValueError(f"matrix must be 3x3, got shape {matrix.shape}")
        if not np.all(np.isfinite(rot)):
            raise ValueError("rotation has NaN or inf")
        _check_intrinsics(matrix, size)
        if table.get("fisheye", False) not in (False, 0):
            raise ValueError("fisheye cameras are not supported (the camera model is pinhole + OpenCV distortion)")
        extra = {k: v for k, v in table.items() if k not in _CAMERA_KEYS}
        name = str(table.get("name", key))
        if key != name:  # aniposelib writes [cam_0] name = "A": keep the table name for writing
            extra[TABLE_KEY] = key
        return Camera(
            name=name,
            size=(int(round(size[0])), int(round(size[1]))),
            K=matrix,
            dist=table["distortions"],
            R=R,
            t=table["translation"],
            extra=extra,
            rvec_source=rvec_source,
        )
    except (ValueError, TypeError) as exc:
        raise RigFileError(f"{where}: [{key}]: {exc}") from exc


# focal lengths a real camera can have, in image widths: 0.01 w is a ~178 deg field of view,
# 100 w a 0.6 deg one; anything outside is a unit or typing error (fx = 1e-300 put a person 2.8 m tall)
FOCAL_RANGE_WIDTHS = (0.01, 100.0)


def _check_intrinsics(matrix: np.ndarray, size: np.ndarray) -> None:
    """ValueError naming the field for sizes and focal lengths no camera has."""
    if not (np.all(np.isfinite(size)) and np.all(size >= 1)):
        raise ValueError(f"size must be two positive numbers [width, height], got {size.tolist()}")
    lo, hi = (f * float(size[0]) for f in FOCAL_RANGE_WIDTHS)
    for label, v in (("fx", matrix[0, 0]), ("fy", matrix[1, 1])):
        if not (math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"matrix {label} = {v:g} px is not a plausible focal length for an image "
                             f"{size[0]:g} px wide (expected {lo:g}..{hi:g} px)")


def read_rig(path: str | Path) -> Rig:
    """Read a Pose2Sim/aniposelib rig TOML; errors name the file and the table."""
    path = Path(path)
    try:
        data = read_toml(path, "rig file", RigFileError)
    except FileNotFoundError as exc:
        raise RigFileError(str(exc)) from None
    metadata = data.pop("metadata", {})
    cameras = [_camera_from_table(k, v, str(path)) for k, v in data.items() if isinstance(v, dict)]
    if not cameras:
        raise RigFileError(f"{path}: no camera tables")
    try:
        return Rig(tuple(cameras), dict(metadata))
    except ValueError as exc:
        raise RigFileError(f"{path}: {exc}") from exc


def read_opencv_yaml(path: str | Path, name: str | None = None) -> Camera:
    """One camera from an OpenCV FileStorage YAML/XML file.

    Accepted node names (first found wins): camera_matrix|K|cameraMatrix,
    distortion_coefficients|D|dist_coeffs|distCoeffs, rvec|rotation|R, tvec|translation|T,
    image_width + image_height or size.
    """
    path = Path(path)
    if not path.exists():
        raise RigFileError(f"{path}: no such file")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise RigFileError(f"{path}: OpenCV cannot open it as FileStorage")

    def node(*names):
        for n in names:
            nd = fs.getNode(n)
            if not nd.empty():
                return nd
        return None

    try:
        K = node("camera_matrix", "K", "cameraMatrix")
        if K is None:
            raise RigFileError(f"{path}: no camera_matrix")
        D = node("distortion_coefficients", "D", "dist_coeffs", "distCoeffs")
        R = node("rvec", "rotation", "R")
        T = node("tvec", "translation", "T")
        if node("image_width") is not None:
            size = (int(node("image_width").real()), int(node("image_height").real()))
        elif node("size") is not None:
            s = node("size").mat()
            size = (int(s.ravel()[0]), int(s.ravel()[1]))
        else:
            raise RigFileError(f"{path}: no image_width/image_height or size")
        rot = np.eye(3) if R is None else R.mat()
        rot = rotation_from_rodrigues(rot.ravel()) if rot.size == 3 else rot
        t = np.zeros(3) if T is None else T.mat().ravel()
        dist = np.zeros(0) if D is None else D.mat().ravel()
        return Camera(name or path.stem, size, K.mat(), dist, rot, t)
    except ValueError as exc:
        raise RigFileError(f"{path}: {exc}") from exc
    finally:
        fs.release()


# --------------------------------------------------------------------- rig layouts
def intrinsics_for_fov(size: tuple[int, int], hfov_deg: float) -> np.ndarray:
    """(3, 3) K of an ideal camera with the given horizontal field of view."""
    w, h = size
    f = (w / 2) / math.tan(math.radians(hfov_deg) / 2)
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])


def ring_rig(
    n_cameras: int = 6,
    radius_m: float = 3.0,
    height_m: float = 1.6,
    size: tuple[int, int] = (640, 480),
    hfov_deg: float = 60.0,
    target_m: tuple[float, float, float] = (0.0, 0.0, 0.9),
    first_azimuth_deg: float = -90.0,
    dist: tuple[float, ...] = (),
) -> Rig:
    """N cameras evenly spaced on a circle around the origin, aimed at ``target_m``.

    Camera i sits at azimuth ``first_azimuth_deg + i * 360 / n`` (degrees from +X towards
    +Y); the default puts cam_1 on -Y looking towards +Y.
    """
    if n_cameras < 1:
        raise ValueError("n_cameras must be >= 1")
    K = intrinsics_for_fov(size, hfov_deg)
    cams = []
    for i in range(n_cameras):
        az = math.radians(first_azimuth_deg + 360.0 * i / n_cameras)
        eye = np.array([radius_m * math.cos(az), radius_m * math.sin(az), height_m])
        R, t = look_at(eye, np.asarray(target_m, dtype=np.float64))
        cams.append(Camera(f"cam_{i + 1}", size, K, np.asarray(dist, dtype=np.float64), R, t))
    return Rig(tuple(cams), {"layout": f"ring{n_cameras}"})


def desktop_rig(size: tuple[int, int] = (640, 480), hfov_deg: float = 55.0) -> Rig:
    """Two cameras 1.2 m apart, 1.8 m in front of a seated/standing user's upper body."""
    K = intrinsics_for_fov(size, hfov_deg)
    target = np.array([0.0, 0.0, 1.3])
    cams = []
    for i, x in enumerate((-0.6, 0.6)):
        R, t = look_at(np.array([x, -1.8, 1.5]), target)
        cams.append(Camera(f"cam_{i + 1}", size, K, np.zeros(0), R, t))
    return Rig(tuple(cams), {"layout": "desktop2"})
