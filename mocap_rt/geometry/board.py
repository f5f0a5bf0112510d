"""Calibration from a planar board (checkerboard or ChArUco) with OpenCV.

Two steps calibrate a real rig end to end:

1. **Intrinsics per camera** (K, distortion) from many views of a board, by
   :func:`calibrate_intrinsics` (``cv2.calibrateCamera``; Zhang's method).
2. **Extrinsics of every camera in one world frame** (right-handed, +Z up, metres):
   * from one view of the board lying at a *known placement* (e.g. flat on the floor at
     the origin, :func:`floor_placement`): :func:`extrinsics_from_board`
     (``cv2.solvePnP``, IPPE for planes, then Levenberg-Marquardt);
   * from known 3D points (a calibration object): :func:`extrinsics_from_points`;
   * around a ring where no single placement is seen by all cameras: a camera already
     placed sees the board at an unknown placement, :func:`placement_from_camera`
     recovers that placement, and the next camera is placed from its own view of it.

Board frame (OpenCV's): origin at the outer top-left corner of the printed board,
x along the columns of squares, y along the rows, z into the board (away from a viewer
who reads it). Corner ``id = row * (squares_x - 1) + col`` lies at
``((col + 1) s, (row + 1) s, 0)`` with ``s`` the square side — for both kinds.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.dlt import CalibrationError

logger = logging.getLogger(__name__)

# Fewer detected corners than this make a view useless (PnP / calibrateCamera).
MIN_CORNERS = 6
# Views needed for intrinsics; OpenCV needs >= 3 non-parallel views to fix K well.
MIN_INTRINSIC_VIEWS = 3
# Sub-pixel refinement window (half-size, pixels) for checkerboard corners.
SUBPIX_HALF_WINDOW_PX = 5
KINDS = ("charuco", "chessboard")

__all__ = [
    "BoardSpec",
    "BoardDetection",
    "IntrinsicsResult",
    "detect_board",
    "calibrate_intrinsics",
    "board_pose",
    "floor_placement",
    "extrinsics_from_board",
    "extrinsics_from_points",
    "placement_from_camera",
]


@dataclass(frozen=True)
class BoardSpec:
    """A printed calibration board.

    kind : "charuco" or "chessboard".
    squares_x, squares_y : number of squares along x (columns) and y (rows).
    square_m : side of one square, metres (measure the print!).
    marker_m : ChArUco marker side, metres (< square_m); unused for a chessboard.
    dictionary : ChArUco ArUco dictionary name, e.g. "DICT_5X5_100".
    inverted : the board is printed white-on-black (detect on the inverted image).
    """

    kind: str = "charuco"
    squares_x: int = 8
    squares_y: int = 6
    square_m: float = 0.1
    marker_m: float = 0.075
    dictionary: str = "DICT_5X5_100"
    inverted: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"board kind must be one of {KINDS}, got {self.kind!r}")
        if self.squares_x < 3 or self.squares_y < 3:
            raise ValueError(f"board needs >= 3 x 3 squares, got {self.squares_x} x {self.squares_y}")
        if not self.square_m > 0:
            raise ValueError(f"square_m must be > 0, got {self.square_m}")
        if self.kind == "charuco":
            if not 0 < self.marker_m < self.square_m:
                raise ValueError(f"marker_m must be in (0, square_m), got {self.marker_m}")
            if not hasattr(cv2.aruco, self.dictionary):
                raise ValueError(f"unknown ArUco dictionary {self.dictionary!r}")

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    @cached_property
    def corner_points(self) -> np.ndarray:
        """(n_corners, 3) float64 inner corners in the board frame, metres, by id."""
        cols, rows = np.meshgrid(np.arange(1, self.squares_x), np.arange(1, self.squares_y))
        pts = np.stack([cols.ravel(), rows.ravel(), np.zeros(cols.size)], axis=1)
        return pts * self.square_m

    def cv_board(self) -> "cv2.aruco.CharucoBoard":
        """The OpenCV ChArUco board (charuco kind only)."""
        if self.kind != "charuco":
            raise ValueError("cv_board() is for ChArUco boards")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)

    def image(self, px_per_square: int = 40, margin_px: int = 20) -> np.ndarray:
        """(H, W) uint8 printable board, W = squares_x * px + 2 margin; white margin.

        Pixel (i, j) (row, col) covers board coordinates
        ``((j - margin + [0, 1]) s / px, (i - margin + [0, 1]) s / px)``.
        """
        w = self.squares_x * px_per_square + 2 * margin_px
        h = self.squares_y * px_per_square + 2 * margin_px
        if self.kind == "charuco":
            img = self.cv_board().generateImage((w, h), marginSize=margin_px, borderBits=1)
        else:
            img = np.full((h, w), 255, np.uint8)
            for r in range(self.squares_y):
                for c in range(self.squares_x):
                    if (r + c) % 2 == 0:
                        y0, x0 = margin_px + r * px_per_square, margin_px + c * px_per_square
                        img[y0:y0 + px_per_square, x0:x0 + px_per_square] = 0
        return 255 - img if self.inverted else img


@dataclass(frozen=True)
class BoardDetection:
    """Board corners found in one image.

    ids : (M,) int, corner ids (rows of :attr:`BoardSpec.corner_points`).
    uv : (M, 2) float64 pixels (distorted, as seen).
    """

    ids: np.ndarray
    uv: np.ndarray

    def object_points(self, spec: BoardSpec) -> np.ndarray:
        """(M, 3) float64 board-frame corners, metres, matching ``uv``."""
        return spec.corner_points[self.ids]

    def __len__(self) -> int:
        return len(self.ids)


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got {img.dtype}")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got shape {img.shape}")
    return img


def detect_board(image: np.ndarray, spec: BoardSpec, min_corners: int = MIN_CORNERS) -> BoardDetection | None:
    """Find the board's inner corners in a uint8 gray or BGR image; None if < min_corners."""
    gray = _gray(image)
    if spec.inverted:
        gray = 255 - gray
    if spec.kind == "charuco":
        detector = cv2.aruco.CharucoDetector(spec.cv_board())
        corners, ids, _, _ = detector.detectBoard(gray)
        if ids is None or len(ids) < min_corners:
            return None
        return BoardDetection(ids.ravel().astype(np.int64), corners.reshape(-1, 2).astype(np.float64))
    pattern = (spec.squares_x - 1, spec.squares_y - 1)
    found, corners = cv2.findChessboardCorners(
        gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    win = (SUBPIX_HALF_WINDOW_PX, SUBPIX_HALF_WINDOW_PX)
    corners = cv2.cornerSubPix(gray, corners.astype(np.float32), win, (-1, -1), crit)
    return BoardDetection(np.arange(spec.n_corners), corners.reshape(-1, 2).astype(np.float64))


@dataclass(frozen=True)
class IntrinsicsResult:
    """K (3, 3) pixels, dist (n,) OpenCV coefficients, rms_px overall reprojection RMS,
    view_rms_px (V,) per used view, used (V_in,) bool: which input views were used."""

    K: np.ndarray
    dist: np.ndarray
    rms_px: float
    view_rms_px: np.ndarray
    used: np.ndarray


_DIST_FLAGS = {4: cv2.CALIB_FIX_K3, 5: 0, 8: cv2.CALIB_RATIONAL_MODEL}


def calibrate_intrinsics(detections: Sequence[BoardDetection | None], spec: BoardSpec, size: tuple[int, int],
                         n_dist: int = 5) -> IntrinsicsResult:
    """K and distortion from several views of a board (``cv2.calibrateCamera``).

    detections : one per image, None (or < MIN_CORNERS corners) = board not found.
    size : (width, height) pixels; n_dist : 4 (k1 k2 p1 p2), 5 (+k3) or 8 (rational).
    Raises :class:`CalibrationError` with fewer than MIN_INTRINSIC_VIEWS usable views.
    """
    if n_dist not in _DIST_FLAGS:
        raise ValueError(f"n_dist must be 4, 5 or 8, got {n_dist}")
    used = np.array([d is not None and len(d) >= MIN_CORNERS for d in detections], dtype=bool)
    views = [d for d, u in zip(detections, used) if u]
    if len(views) < MIN_INTRINSIC_VIEWS:
        raise CalibrationError(
            f"intrinsics need the board in >= {MIN_INTRINSIC_VIEWS} images, found it in {len(views)} "
            f"of {len(detections)}")
    obj = [d.object_points(spec).astype(np.float32) for d in views]
    img = [d.uv.astype(np.float32).reshape(-1, 1, 2) for d in views]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, tuple(int(v) for v in size), None, None,
                                                    flags=_DIST_FLAGS[n_dist], criteria=crit)
    dist = np.asarray(dist, dtype=np.float64).ravel()[:n_dist]
    view_rms = []
    for o, i, r, t in zip(obj, img, rvecs, tvecs):
        proj = cv2.projectPoints(o.astype(np.float64), r, t, K, dist)[0].reshape(-1, 2)
        view_rms.append(np.sqrt(np.mean(np.sum((proj - i.reshape(-1, 2)) ** 2, axis=1))))
    logger.info("intrinsics from %d views: RMS %.3f px", len(views), rms)
    return IntrinsicsResult(np.asarray(K, dtype=np.float64), dist, float(rms), np.array(view_rms), used)


# ----------------------------------------------------------------------------- poses
def _pnp(obj: np.ndarray, uv: np.ndarray, K: np.ndarray, dist: np.ndarray, planar: bool):
    if len(obj) < (4 if planar else MIN_CORNERS):
        raise CalibrationError(f"pose needs >= {4 if planar else MIN_CORNERS} points, got {len(obj)}")
    if not (np.all(np.isfinite(obj)) and np.all(np.isfinite(uv))):
        raise CalibrationError("NaN or inf in pose correspondences")
    obj = np.ascontiguousarray(obj, dtype=np.float64)   # cv2 rejects strided views
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    # Candidates: both IPPE solutions for a plane (the two-fold ambiguity of a planar
    # target seen from afar) and SQPnP's global minimum; each refined by LM; the one
    # with the smallest reprojection error wins.
    candidates = []
    methods = (cv2.SOLVEPNP_IPPE, cv2.SOLVEPNP_SQPNP) if planar else (cv2.SOLVEPNP_SQPNP,)
    for method in methods:
        n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, uv, K, dist, flags=method)
        candidates += list(zip(rvecs[:n], tvecs[:n]))
    best = None
    for rvec, tvec in candidates:
        rvec, tvec = cv2.solvePnPRefineLM(obj, uv, K, dist, rvec.copy(), tvec.copy())
        proj = cv2.projectPoints(obj, rvec, tvec, K, dist)[0].reshape(-1, 2)
        res = np.linalg.norm(proj - uv, axis=1)
        if best is None or np.sum(res**2) < np.sum(best[2] ** 2):
            best = (rvec, tvec, res)
    if best is None:
        raise CalibrationError("cv2.solvePnP found no pose")
    rvec, tvec, res = best
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), res


def board_pose(K: np.ndarray, dist: np.ndarray, detection: BoardDetection,
               spec: BoardSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Board pose in the camera frame: ``p_cam = R p_board + t``.

    Returns R (3, 3), t (3,) metres, residuals_px (M,).
    """
    return _pnp(detection.object_points(spec), detection.uv, np.asarray(K, float),
                np.asarray(dist, float), planar=True)


def floor_placement(origin_m: Sequence[float] = (0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> np.ndarray:
    """(4, 4) world_from_board for a board lying face up on a horizontal surface.

    The board's origin corner is at ``origin_m`` (metres, world), its x axis (columns) along
    world +X rotated by ``yaw_deg`` about +Z; its rows run along -Y (rotated likewise) so the
    printed face looks up (+Z) and the board frame's z points down.
    """
    a = np.radians(yaw_deg)
    x = np.array([np.cos(a), np.sin(a), 0.0])
    y = -np.array([-np.sin(a), np.cos(a), 0.0])
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, np.cross(x, y)], axis=1)
    T[:3, 3] = np.asarray(origin_m, dtype=np.float64)
    return T


def _check_placement(world_from_board: np.ndarray) -> np.ndarray:
    T = np.asarray(world_from_board, dtype=np.float64)
    if T.shape != (4, 4) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9) \
            or abs(np.linalg.det(T[:3, :3]) - 1) > 1e-9:
        raise ValueError("world_from_board must be a (4, 4) rigid transform with a proper rotation")
    return T


def extrinsics_from_board(K: np.ndarray, dist: np.ndarray, detection: BoardDetection, spec: BoardSpec,
                          world_from_board: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-to-camera (R, t) from one view of the board at a known placement.

    world_from_board : (4, 4), ``p_world = T[:3, :3] p_board + T[:3, 3]``.
    Returns R (3, 3), t (3,) metres, residuals_px (M,).
    """
    T = _check_placement(world_from_board)
    R_cb, t_cb, res = board_pose(K, dist, detection, spec)
    B, c = T[:3, :3], T[:3, 3]
    R = R_cb @ B.T                                   # p_cam = R_cb B^T (p_world - c) + t_cb
    return R, t_cb - R @ c, res


def extrinsics_from_points(K: np.ndarray, dist: np.ndarray, X_world: np.ndarray,
                           uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-to-camera (R, t) from >= 6 known 3D points (metres, world) and pixels (N, 2).

    Non-planar or planar point sets both work (SQPnP + Levenberg-Marquardt).
    Returns R (3, 3), t (3,) metres, residuals_px (N,).
    """
    X = np.asarray(X_world, dtype=np.float64)
    uv = np.asarray(uv, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3 or uv.shape != (len(X), 2):
        raise CalibrationError(f"need X (N, 3) and uv (N, 2), got {X.shape} and {uv.shape}")
    return _pnp(X, uv, np.asarray(K, float), np.asarray(dist, float), planar=False)


def placement_from_camera(camera: Camera, detection: BoardDetection, spec: BoardSpec) -> np.ndarray:
    """(4, 4) world_from_board of a board seen by an already placed camera.

    Chains calibration around a ring: camera k (placed) and camera k+1 see the board at
    the same moment; this placement then gives camera k+1 by :func:`extrinsics_from_board`.
    """
    R_cb, t_cb, _ = board_pose(camera.K, camera.dist, detection, spec)
    cam_from_board = np.eye(4)
    cam_from_board[:3, :3], cam_from_board[:3, 3] = R_cb, t_cb
    return camera.world_from_cam @ cam_from_board
