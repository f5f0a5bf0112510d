"""``mocap-rt calibrate``: calibrate cameras into a rig TOML (docs/calibration.md).

* ``calibrate dlt``: one camera from >= 6 non-coplanar known 3D points and their pixels
  (CSV with header ``X,Y,Z,u,v``; metres, pixels), by the normalised DLT.
* ``calibrate board``: intrinsics from images or a video of a checkerboard / ChArUco
  board, and extrinsics from one image of the board lying at a known placement (or from a
  CSV of known 3D points).

Both write the camera into ``--out`` (replacing a camera of the same name, otherwise
appending; the file is created if missing) and print the reprojection RMS.
World frame: right-handed, +Z up, metres.
"""

from __future__ import annotations

import argparse
import csv
import logging
from pathlib import Path

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
POINT_COLUMNS = ("X", "Y", "Z", "u", "v")


def register(subparsers) -> None:
    parser = subparsers.add_parser("calibrate", help="calibrate cameras into a rig TOML (DLT or board)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="calibrate_command", required=True, metavar="METHOD")

    dlt = sub.add_parser("dlt", help="one camera from known 3D points (CSV X,Y,Z,u,v) by the DLT",
                         description="Calibrate one camera (K, R, t; no distortion) from >= 6 non-coplanar "
                                     "3D points in metres and their pixels, by the Hartley-normalised DLT.")
    dlt.add_argument("--points", required=True, type=Path, help="CSV with header X,Y,Z,u,v (metres, pixels)")
    dlt.add_argument("--size", required=True, help="image size WxH in pixels, e.g. 640x480")
    _add_camera_out_args(dlt)
    dlt.set_defaults(func=run_dlt)

    board = sub.add_parser("board", help="intrinsics from board images/video, extrinsics from a placed board",
                           description="Intrinsics (K, distortion) from several images or a video of a "
                                       "checkerboard/ChArUco board; extrinsics from one image of the board at a "
                                       "known placement (--extrinsic-image) or from known 3D points "
                                       "(--extrinsic-points CSV X,Y,Z,u,v).")
    src = board.add_argument_group("intrinsics")
    src.add_argument("--images", nargs="+", type=Path, default=[],
                     help="image files, folders of images and/or video files of the board")
    src.add_argument("--every", type=int, default=10, help="use every Nth video frame (default 10)")
    src.add_argument("--n-dist", type=int, choices=(4, 5, 8), default=5,
                     help="distortion coefficients: 4 (k1 k2 p1 p2), 5 (+k3), 8 (rational)")
    src.add_argument("--intrinsics-from", type=Path,
                     help="take K and distortion of --name from this rig TOML instead of --images")
    _add_board_args(board)
    ext = board.add_argument_group("extrinsics")
    ext.add_argument("--extrinsic-image", type=Path, help="image of the board lying at the known placement")
    ext.add_argument("--board-origin", default="0,0,0",
                     help="world position X,Y,Z (m) of the board's origin corner (default 0,0,0); "
                          "write --board-origin=-1,0,0 when X is negative")
    ext.add_argument("--board-yaw-deg", type=float, default=0.0,
                     help="rotation of the board's x axis from world +X about +Z (degrees)")
    ext.add_argument("--extrinsic-points", type=Path, help="CSV X,Y,Z,u,v of known 3D points (instead)")
    _add_camera_out_args(board)
    board.set_defaults(func=run_board)

    make = sub.add_parser("make-board", help="write a printable board image (PNG)",
                          description="Write a printable image of a ChArUco or checkerboard board; print it at "
                                      "the size that makes one square --square-m metres, then measure it.")
    _add_board_args(make)
    make.add_argument("--px-per-square", type=int, default=200, help="pixels per square (default 200)")
    make.add_argument("--out", required=True, type=Path, help="PNG file to write")
    make.set_defaults(func=run_make_board)


def _add_camera_out_args(parser) -> None:
    parser.add_argument("--name", required=True, help="camera name in the rig, e.g. cam_1")
    parser.add_argument("--out", required=True, type=Path, help="rig TOML to write or add the camera to")


def _add_board_args(parser) -> None:
    spec = parser.add_argument_group("board")
    spec.add_argument("--board", choices=("charuco", "chessboard"), default="charuco", help="board kind")
    spec.add_argument("--squares", default="8x6", help="squares along x and y, e.g. 8x6")
    spec.add_argument("--square-m", type=float, required=True, help="square side in metres (measure the print)")
    spec.add_argument("--marker-m", type=float, help="ChArUco marker side in metres (default 0.75 square)")
    spec.add_argument("--dict", default="DICT_5X5_100", help="ChArUco dictionary (default DICT_5X5_100)")
    spec.add_argument("--inverted", action="store_true", help="board printed white-on-black")


# ----------------------------------------------------------------------------- inputs
def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must look like 640x480, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"--size must be positive, got {text!r}")
    return w, h


def _floats(text: str, n: int, flag: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != n:
        raise ValueError(f"{flag} needs {n} comma-separated numbers, got {text!r}")
    return values


def read_points_csv(path: Path):
    """(X (N, 3), uv (N, 2)) float64 from a CSV with header X,Y,Z,u,v (extra columns ignored)."""
    import numpy as np

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such points file")
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in POINT_COLUMNS if c not in header]
        if missing:
            raise ValueError(f"{path}: header must contain {','.join(POINT_COLUMNS)}; missing {','.join(missing)}")
        reader.fieldnames = header
        rows = []
        for line_no, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[c]) for c in POINT_COLUMNS])
            except (TypeError, ValueError):
                raise ValueError(f"{path}:{line_no}: expected 5 numbers X,Y,Z,u,v, got {row}") from None
    if not rows:
        raise ValueError(f"{path}: no data rows")
    arr = np.array(rows)
    return arr[:, :3], arr[:, 3:]


def _load_rig(path: Path):
    from mocap_rt.geometry.rig import Rig, read_rig

    return read_rig(path) if path.exists() else Rig((), {})


def _save_camera(camera, out: Path, rms_px: float) -> None:
    from mocap_rt.geometry.rig import write_rig

    rig = _load_rig(out).with_camera(camera)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_rig(rig, out)
    c = camera.center
    print(f"{camera.name}: fx={camera.K[0, 0]:.2f} fy={camera.K[1, 1]:.2f} cx={camera.K[0, 2]:.2f} "
          f"cy={camera.K[1, 2]:.2f} px; centre=({c[0]:.4f}, {c[1]:.4f}, {c[2]:.4f}) m")
    print(f"reprojection RMS {rms_px:.4f} px; wrote {out} ({len(rig)} camera(s): {', '.join(rig.names)})")


# ----------------------------------------------------------------------------- dlt
def run_dlt(args: argparse.Namespace) -> int:
    import numpy as np

    from mocap_rt.geometry.dlt import calibrate_dlt

    size = parse_size(args.size)
    X, uv = read_points_csv(args.points)
    camera, residuals = calibrate_dlt(X, uv, size, args.name)
    rms = float(np.sqrt(np.mean(residuals**2)))
    print(f"DLT from {len(X)} points of {args.points}: max error {residuals.max():.4f} px")
    _save_camera(camera, args.out, rms)
    return 0


# ----------------------------------------------------------------------------- board
def _iter_images(paths: list[Path], every: int):
    """Yield (label, image) from image files, folders of images and videos."""
    import cv2

    for path in paths:
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not files:
                raise FileNotFoundError(f"{path}: folder holds no images ({', '.join(IMAGE_SUFFIXES)})")
            yield from _iter_images(files, every)
        elif not path.exists():
            raise FileNotFoundError(f"{path}: no such image, folder or video")
        elif path.suffix.lower() in IMAGE_SUFFIXES:
            img = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{path}: OpenCV cannot read this image")
            yield str(path), img
        else:
            cap = cv2.VideoCapture(str(path))
            if not cap.isOpened():
                raise ValueError(f"{path}: OpenCV cannot open this video")
            try:
                index = 0
                while True:
                    ok, frame = cap.read()
                    if not ok:
                        break
                    if index % max(1, every) == 0:
                        yield f"{path}#{index}", frame
                    index += 1
            finally:
                cap.release()


def _board_spec(args: argparse.Namespace):
    from mocap_rt.geometry.board import BoardSpec

    try:
        sx, sy = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        raise ValueError(f"--squares must look like 8x6, got {args.squares!r}") from None
    marker = args.marker_m if args.marker_m is not None else 0.75 * args.square_m
    return BoardSpec(args.board, sx, sy, args.square_m, marker, args.dict, args.inverted)


def run_board(args: argparse.Namespace) -> int:
    import numpy as np

    from mocap_rt.geometry.board import (
        calibrate_intrinsics,
        detect_board,
        extrinsics_from_board,
        extrinsics_from_points,
        floor_placement,
    )
    from mocap_rt.geometry.camera import Camera

    spec = _board_spec(args)
    if args.extrinsic_image and args.extrinsic_points:
        raise ValueError("give --extrinsic-image or --extrinsic-points, not both")
    if args.intrinsics_from:
        from mocap_rt.geometry.rig import read_rig

        try:
            known = read_rig(args.intrinsics_from)[args.name]
        except KeyError as exc:
            raise ValueError(f"{args.intrinsics_from}: {exc.args[0]}") from None
        K, dist, size, rms = known.K, known.dist, known.size, float("nan")
        print(f"intrinsics of {args.name} from {args.intrinsics_from}")
    elif args.images:
        detections, size = [], None
        for label, img in _iter_images(args.images, args.every):
            shape = (img.shape[1], img.shape[0])
            if size is None:
                size = shape
            elif shape != size:
                raise ValueError(f"{label}: image size {shape[0]}x{shape[1]} differs from {size[0]}x{size[1]}")
            det = detect_board(img, spec)
            logger.info("%s: %s", label, "no board" if det is None else f"{len(det)} corners")
            detections.append(det)
        if size is None:
            raise ValueError("--images gave no images")
        result = calibrate_intrinsics(detections, spec, size, n_dist=args.n_dist)
        K, dist, rms = result.K, result.dist, result.rms_px
        print(f"intrinsics from {int(result.used.sum())} of {len(detections)} images: RMS {rms:.4f} px, "
              f"distortion {np.array2string(dist, precision=5)}")
    else:
        raise ValueError("give --images (board pictures/video) or --intrinsics-from RIG.toml")

    R, t = np.eye(3), np.zeros(3)
    if args.extrinsic_image:
        import cv2

        img = cv2.imread(str(args.extrinsic_image), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(f"{args.extrinsic_image}: cannot read the extrinsic image")
        det = detect_board(img, spec)
        if det is None:
            raise ValueError(f"{args.extrinsic_image}: board not found")
        placement = floor_placement(_floats(args.board_origin, 3, "--board-origin"), args.board_yaw_deg)
        R, t, res = extrinsics_from_board(K, dist, det, spec, placement)
        rms = float(np.sqrt(np.mean(res**2)))
        print(f"extrinsics from {len(det)} board corners in {args.extrinsic_image}")
    elif args.extrinsic_points:
        X, uv = read_points_csv(args.extrinsic_points)
        R, t, res = extrinsics_from_points(K, dist, X, uv)
        rms = float(np.sqrt(np.mean(res**2)))
        print(f"extrinsics from {len(X)} known points in {args.extrinsic_points}")
    else:
        print("no --extrinsic-image/--extrinsic-points: pose left at identity (intrinsics only)")
    _save_camera(Camera(args.name, size, K, dist, R, t), args.out, rms)
    return 0


def run_make_board(args: argparse.Namespace) -> int:
    import cv2

    spec = _board_spec(args)
    img = spec.image(args.px_per_square, args.px_per_square // 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), img):
        raise ValueError(f"{args.out}: OpenCV cannot write this image (use .png)")
    print(f"wrote {args.out}: {img.shape[1]}x{img.shape[0]} px, {spec.squares_x}x{spec.squares_y} squares; "
          f"print so that one square is {spec.square_m * 100:.1f} cm")
    return 0


def run(args: argparse.Namespace) -> int:
    return args.func(args)
