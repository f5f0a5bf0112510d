"""Time to triangulate the six cues of one frame from six views (issue 2, item 7).

Target: <= 50 us per frame, median, warmed, *including* the undistortion of the
6 x 6 observed pixels. Prints one row per method (median over repeated blocks,
methods interleaved so machine noise hits them alike) and the speed-up against the
NumPy/OpenCV reference.

    .venv/bin/python -m bench triangulate
"""

from __future__ import annotations

import argparse
import time

import numpy as np

TARGET_US = 50.0


def _scene(seed: int = 0):
    from mocap_rt.geometry.camera import Camera
    from mocap_rt.geometry.rig import ring_rig

    rig = ring_rig(n_cameras=6)
    rng = np.random.default_rng(seed)
    # realistic lens distortion so the undistortion is really exercised
    cams = [Camera(c.name, c.size, c.K, [-0.12, 0.05, 1e-3, -5e-4, -0.01], c.R, c.t) for c in rig.cameras]
    cues = rng.uniform([-0.6, -0.6, 0.1], [0.6, 0.6, 1.8], (6, 3))
    uv = np.stack([c.project(cues)[0] for c in cams]) + rng.normal(0.0, 0.5, (6, 6, 2))
    uv[1, 0] = np.nan  # one cue occluded in one view, as in a real frame
    weights = rng.uniform(0.5, 1.0, (6, 6))
    return cams, cues, uv, weights


def _median_us(fn, n_inner: int, n_blocks: int) -> float:
    per_call = []
    for _ in range(n_blocks):
        t0 = time.perf_counter()
        for _ in range(n_inner):
            fn()
        per_call.append((time.perf_counter() - t0) / n_inner)
    return float(np.median(per_call) * 1e6)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="bench_triangulate", description=__doc__.splitlines()[0])
    parser.add_argument("--blocks", type=int, default=15, help="timed blocks per method")
    parser.add_argument("--inner", type=int, default=200, help="calls per block")
    args = parser.parse_args(argv if argv is not None else [])

    from mocap_rt.geometry.ray_triangulator import RayTriangulator
    from mocap_rt.geometry.triangulate import midpoint_two_rays, triangulate_dlt, triangulate_points, triangulate_rays

    cams, cues, uv, weights = _scene()
    fast6 = RayTriangulator(cams)
    P = np.stack([c.P for c in cams])
    out6 = np.empty((6, 3))
    uv2 = np.ascontiguousarray(uv[[0, 2]])
    fast2 = RayTriangulator([cams[0], cams[2]])

    def undistort_only():
        for c, cam in enumerate(cams):
            cam.undistort_pixels(uv[c])

    def numpy_two_ray():
        o1, d1 = cams[0].rays(uv[0])
        o2, d2 = cams[2].rays(uv[2])
        return midpoint_two_rays(o1, d1, o2, d2)[0]

    def numpy_nview():
        rays = [cam.rays(uv[c]) for c, cam in enumerate(cams)]
        return triangulate_rays(np.stack([o for o, _ in rays]), np.stack([d for _, d in rays]), weights)

    def entry_nview():
        return triangulate_points(cams, uv, weights)

    def numpy_dlt():
        und = np.stack([np.hstack([cam.undistort_pixels(uv[c]), np.ones((6, 1))]) @ cam.K.T
                        for c, cam in enumerate(cams)])[..., :2]
        return triangulate_dlt(P, und, weights)

    def numba_two_ray():
        return fast2(uv2)

    def numba_nview():
        return fast6(uv, weights, out=out6)

    methods = [
        ("undistort 36 px only (cv2, 6 calls)", undistort_only),
        ("two-ray midpoint, numpy+cv2", numpy_two_ray),
        ("N-view rays LSQ, numpy+cv2 (triangulate_rays)", numpy_nview),
        ("N-view, one call (triangulate_points)", entry_nview),
        ("N-view DLT, numpy+cv2 (triangulate_dlt)", numpy_dlt),
        ("two-ray LSQ, numba RayTriangulator", numba_two_ray),
        ("N-view rays LSQ, numba RayTriangulator", numba_nview),
    ]
    for _, fn in methods:  # warm-up: numba compile/cache load, allocator, cv2
        for _ in range(50):
            fn()
    err6 = np.nanmax(np.abs(numba_nview() - numpy_nview()))
    samples: dict[str, list[float]] = {name: [] for name, _ in methods}
    for _ in range(args.blocks):  # interleave methods block by block
        for name, fn in methods:
            samples[name].append(_median_us(fn, args.inner, 1))
    ref = float(np.median(samples[methods[2][0]]))
    print(f"six cues x six views per frame, pixel noise 0.5 px, 1 occluded view; "
          f"median of {args.blocks} blocks x {args.inner} calls")
    print(f"{'method':52s} {'median us':>10s} {'best us':>8s} {'vs numpy N-view':>16s} {'target':>8s}")
    for name, _ in methods:
        med = float(np.median(samples[name]))
        verdict = "" if name.startswith("undistort") else ("ok" if med <= TARGET_US else "MISS")
        print(f"{name:52s} {med:10.1f} {min(samples[name]):8.1f} {ref / med:15.1f}x {verdict:>8s}")
    print(f"target: <= {TARGET_US:.0f} us per frame (median, warmed, undistortion included); "
          "'best' = fastest block, a hint of the quiet-machine figure")
    print(f"numba vs numpy N-view max |dX| = {err6:.2e} m; cue error vs truth "
          f"{np.nanmax(np.linalg.norm(numba_nview() - cues, axis=1)) * 1e3:.2f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
