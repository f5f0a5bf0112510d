"""Triangulation against synthetic truth, cv2.triangulatePoints and independent solvers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from geometry_strategies import random_camera, random_points, seeds
from hypothesis import given, settings

from mocap_rt.geometry.ray_triangulator import RayTriangulator
from mocap_rt.geometry.triangulate import (
    closest_point_ray1,
    line_direction_two_views,
    midpoint_two_rays,
    refine_points,
    reprojection_residuals,
    triangulate_dlt,
    triangulate_points,
    triangulate_rays,
)

SETTINGS = settings(max_examples=25, deadline=None)


def _rig(rng, n=6, dist_size=0):
    return [random_camera(rng, f"cam_{i}", dist_size) for i in range(n)]


def _observe(cams, X):
    return np.stack([c.project(X)[0] for c in cams])


def _undistorted_pixels(cams, uv):
    out = []
    for c, cam in enumerate(cams):
        xy = cam.undistort_pixels(uv[c])
        out.append((np.hstack([xy, np.ones((len(xy), 1))]) @ cam.K.T)[:, :2])
    return np.stack(out)


# ----------------------------------------------------------------------------- two rays
@SETTINGS
@given(seeds)
def test_closest_point_matches_independent_two_parameter_solve(seed):
    rng = np.random.default_rng(seed)
    o1, o2 = rng.normal(size=(2, 20, 3)) * 2
    d1, d2 = rng.normal(size=(2, 20, 3))
    T = closest_point_ray1(o1, d1, o2, d2)
    for i in range(20):
        # minimise |o1 + s d1 - o2 - u d2|^2 over (s, u) with lstsq: independent of eq. 5
        A = np.stack([d1[i], -d2[i]], axis=1)
        s, _ = np.linalg.lstsq(A, o2[i] - o1[i], rcond=None)[0]
        np.testing.assert_allclose(T[i], o1[i] + s * d1[i], atol=1e-9 * (1 + abs(s)))


@SETTINGS
@given(seeds)
def test_midpoint_symmetric_and_gap_is_line_distance(seed):
    rng = np.random.default_rng(seed)
    o1, o2, d1, d2 = rng.normal(size=(4, 10, 3))
    m12, gap12 = midpoint_two_rays(o1, d1, o2, d2)
    m21, gap21 = midpoint_two_rays(o2, d2, o1, d1)
    np.testing.assert_allclose(m12, m21, atol=1e-9)
    n = np.cross(d1, d2)
    expected_gap = np.abs(np.einsum("ij,ij->i", o2 - o1, n)) / np.linalg.norm(n, axis=1)
    np.testing.assert_allclose(gap12, expected_gap, atol=1e-9)
    np.testing.assert_allclose(gap21, expected_gap, atol=1e-9)


def test_intersecting_rays_meet_at_the_point_and_parallel_rays_give_nan():
    X = np.array([[0.3, -0.2, 1.1], [1.0, 2.0, 3.0]])
    o1 = np.array([[3.0, 0, 1.5], [0, 0, 0]])
    o2 = np.array([[0, -3.0, 1.0], [5, 0, 0]])
    p, gap = midpoint_two_rays(o1, X - o1, o2, 7.0 * (X - o2))
    np.testing.assert_allclose(p, X, atol=1e-12)
    np.testing.assert_allclose(gap, 0.0, atol=1e-12)
    par = closest_point_ray1(o1[:1], [[0, 0, 1.0]], o2[:1], [[0, 0, -2.0]])
    assert np.all(np.isnan(par))
    assert np.all(np.isnan(closest_point_ray1(o1[:1], [[np.nan, 0, 1]], o2[:1], [[1.0, 0, 0]])))


# ----------------------------------------------------------------------------- N views
def _rays_lsq(cams, uv, w=None):
    """The NumPy reference: OpenCV-undistorted rays (``Camera.rays``), least squares in NumPy."""
    return triangulate_rays(*map(np.stack, zip(*[c.rays(uv[i]) for i, c in enumerate(cams)])), w)


@SETTINGS
@given(seeds)
def test_noise_free_recovery_random_rigs(seed):
    rng = np.random.default_rng(seed)
    cams = _rig(rng, n=int(rng.integers(2, 7)), dist_size=int(rng.choice([0, 4, 5, 8])))
    X = random_points(rng, 15)
    uv = _observe(cams, X)
    for Y in (triangulate_points(cams, uv), _rays_lsq(cams, uv),
              triangulate_dlt(np.stack([c.P for c in cams]), _undistorted_pixels(cams, uv))):
        np.testing.assert_allclose(Y, X, atol=1e-9 * np.abs(X).max())


def test_dlt_matches_cv2_triangulate_points_two_views():
    rng = np.random.default_rng(3)
    cams = _rig(rng, 2)
    X = random_points(rng, 50)
    uv = _undistorted_pixels(cams, _observe(cams, X))
    h = cv2.triangulatePoints(cams[0].P, cams[1].P, uv[0].T.copy(), uv[1].T.copy())
    oracle = (h[:3] / h[3]).T
    ours = triangulate_dlt(np.stack([cams[0].P, cams[1].P]), uv)
    np.testing.assert_allclose(ours, oracle, atol=1e-9)
    # with 0.5 px noise both linear methods stay within millimetres of each other and the truth
    noisy = uv + rng.normal(0, 0.5, uv.shape)
    h = cv2.triangulatePoints(cams[0].P, cams[1].P, noisy[0].T.copy(), noisy[1].T.copy())
    oracle = (h[:3] / h[3]).T
    ours = triangulate_dlt(np.stack([cams[0].P * -7.0, cams[1].P * 0.01]), noisy)  # any scale/sign
    assert np.median(np.linalg.norm(ours - oracle, axis=1)) < 2e-3
    assert np.median(np.linalg.norm(ours - X, axis=1)) < 1e-2


def test_rays_lsq_matches_independent_lstsq_with_weights():
    rng = np.random.default_rng(5)
    C, N = 5, 8
    o = rng.normal(size=(C, N, 3)) * 3
    d = rng.normal(size=(C, N, 3))
    w = rng.uniform(0.1, 2.0, (C, N))
    X = triangulate_rays(o, d, w)
    for n in range(N):
        rows, rhs = [], []
        for c in range(C):
            u = d[c, n] / np.linalg.norm(d[c, n])
            Pp = np.eye(3) - np.outer(u, u)
            rows.append(np.sqrt(w[c, n]) * Pp)
            rhs.append(np.sqrt(w[c, n]) * Pp @ o[c, n])
        ref = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
        np.testing.assert_allclose(X[n], ref, atol=1e-9)


def test_missing_views_and_weights():
    rng = np.random.default_rng(7)
    cams = _rig(rng, 4, dist_size=5)
    X = random_points(rng, 6)
    uv = _observe(cams, X)
    uv[0, 0] = np.nan              # point 0 seen in 3 views
    uv[1:, 1] = np.nan             # point 1 seen in 1 view -> NaN
    w = np.ones((4, 6))
    w[:3, 2] = 0.0                 # point 2 has one weighted view -> NaN
    w[0, 3] = np.nan               # NaN weight = missing
    tri = RayTriangulator(cams)
    for Y in (triangulate_points(cams, uv, w), tri(uv, w), _rays_lsq(cams, uv, w)):
        assert np.all(np.isnan(Y[1])) and np.all(np.isnan(Y[2]))
        np.testing.assert_allclose(Y[[0, 3, 4, 5]], X[[0, 3, 4, 5]], atol=1e-9)
    # a bad observation loses its influence as its weight goes to zero
    bad = uv.copy()
    bad[0, 4] += 30.0
    w = np.ones((4, 6))
    err_full = np.linalg.norm(triangulate_points(cams, bad, w)[4] - X[4])
    w[0, 4] = 1e-3
    err_down = np.linalg.norm(triangulate_points(cams, bad, w)[4] - X[4])
    assert err_down < 0.01 * err_full


def test_bad_input_raises_value_error():
    rng = np.random.default_rng(1)
    cams = _rig(rng, 2)
    uv = np.zeros((2, 3, 2))
    with pytest.raises(ValueError, match="cameras"):
        triangulate_points(cams[:1], uv)
    with pytest.raises(ValueError, match=r"\(C, N, 2\)"):
        triangulate_points(cams, np.zeros((2, 3)))
    with pytest.raises(ValueError, match=">= 0"):
        triangulate_points(cams, uv, -np.ones((2, 3)))
    with pytest.raises(ValueError, match="weights"):
        triangulate_rays(np.zeros((2, 3, 3)), np.ones((2, 3, 3)), np.ones((3, 2)))
    with pytest.raises(ValueError, match="same shape"):
        triangulate_rays(np.zeros((2, 3, 3)), np.ones((2, 4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        triangulate_dlt(np.full((2, 3, 4), np.nan), uv)
    with pytest.raises(ValueError, match="views"):
        triangulate_dlt(np.ones((3, 3, 4)), uv)
    with pytest.raises(ValueError, match="shape"):
        RayTriangulator(cams)(np.zeros((3, 3, 2)))


# ----------------------------------------------------------------------------- refinement
def test_refinement_lowers_reprojection_error_and_keeps_missing():
    rng = np.random.default_rng(11)
    cams = _rig(rng, 4, dist_size=5)
    X = random_points(rng, 20)
    uv = _observe(cams, X) + rng.normal(0, 1.0, (4, 20, 2))
    uv[1:, 0] = np.nan
    lin = triangulate_points(cams, uv)
    ref = triangulate_points(cams, uv, refine=True)
    assert np.all(np.isnan(ref[0]))
    r_lin = np.nansum(reprojection_residuals(cams, lin, uv)[:, 1:] ** 2)
    r_ref = np.nansum(reprojection_residuals(cams, ref, uv)[:, 1:] ** 2)
    assert r_ref <= r_lin
    # at the optimum the gradient of the reprojection cost vanishes (central differences)
    for n in (1, 5):
        def cost(p):
            return np.nansum(reprojection_residuals(cams, p[None], uv[:, n:n + 1]) ** 2)
        g = [(cost(ref[n] + e) - cost(ref[n] - e)) / 2e-7 for e in np.eye(3) * 1e-7]
        assert np.linalg.norm(g) < 1e-2 * max(1.0, cost(ref[n]))
    # noise-free start stays put
    exact = _observe(cams, X)
    np.testing.assert_allclose(refine_points(cams, exact, X), X, atol=1e-9)


def test_reprojection_residuals_match_cv2_project_points():
    rng = np.random.default_rng(2)
    cams = _rig(rng, 3, dist_size=5)
    X = random_points(rng, 10)
    uv = _observe(cams, X) + rng.normal(0, 2.0, (3, 10, 2))
    uv[2, 3] = np.nan
    res = reprojection_residuals(cams, X, uv)
    for c, cam in enumerate(cams):
        proj = cv2.projectPoints(X, cam.rvec, cam.t, cam.K, cam.dist)[0].reshape(-1, 2)
        np.testing.assert_allclose(res[c], np.linalg.norm(proj - uv[c], axis=1), atol=1e-9)
    assert np.isnan(res[2, 3]) and np.isfinite(res[2, :3]).all()
    behind = 2 * cams[0].center - X[:1]  # mirrored through the centre: behind cam 0
    assert np.isnan(reprojection_residuals(cams[:1], behind, uv[:1, :1])[0, 0])


# ----------------------------------------------------------------------------- lines
@SETTINGS
@given(seeds)
def test_line_direction_two_views(seed):
    rng = np.random.default_rng(seed)
    c1, c2 = _rig(rng, 2)
    A, B = random_points(rng, 2)
    a1, b1 = c1.project(np.stack([A, B]))[0]
    a2, b2 = c2.project(np.stack([A, B]))[0]
    truth = (B - A) / np.linalg.norm(B - A)
    d = line_direction_two_views(c1.P, a1, b1, c2.P, a2, b2)
    np.testing.assert_allclose(d, truth, atol=1e-7)
    # other points on the same image lines, any P scale/sign, swapped order in view 2
    mid = A + 0.3 * (B - A)
    m2 = c2.project(mid[None])[0][0]
    d2 = line_direction_two_views(-3.0 * c1.P, a1, b1, 0.5 * c2.P, b2, m2)
    np.testing.assert_allclose(d2, truth, atol=1e-7)
    d3 = line_direction_two_views(c1.P, b1, a1, c2.P, a2, b2)
    np.testing.assert_allclose(d3, -truth, atol=1e-7)


def test_line_in_epipolar_plane_or_nan_input_gives_nan():
    rng = np.random.default_rng(4)
    c1, c2 = _rig(rng, 2)
    A = random_points(rng, 1)[0]
    B = A + 0.5 * (c2.center - c1.center)  # line parallel to the baseline: epipolar plane
    a1, b1 = c1.project(np.stack([A, B]))[0]
    a2, b2 = c2.project(np.stack([A, B]))[0]
    assert np.all(np.isnan(line_direction_two_views(c1.P, a1, b1, c2.P, a2, b2)))
    assert np.all(np.isnan(line_direction_two_views(c1.P, [np.nan, 1], b1, c2.P, a2, b2)))
    with pytest.raises(ValueError, match="P1"):
        line_direction_two_views(np.zeros((3, 4)), a1, b1, c2.P, a2, b2)


# ----------------------------------------------------------------------------- kernel
@SETTINGS
@given(seeds)
def test_ray_triangulator_equals_numpy_reference_with_noise_weights_and_gaps(seed):
    rng = np.random.default_rng(seed)
    cams = _rig(rng, n=int(rng.integers(2, 7)), dist_size=int(rng.choice([0, 4, 5, 8])))
    X = random_points(rng, 12)
    uv = _observe(cams, X) + rng.normal(0, 1.0, (len(cams), 12, 2))
    uv[rng.random((len(cams), 12)) < 0.2] = np.nan
    w = rng.uniform(0.0, 2.0, (len(cams), 12))
    w[rng.random(w.shape) < 0.1] = 0.0
    ref = _rays_lsq(cams, uv, w)
    out = np.empty((12, 3))
    got = RayTriangulator(cams)(uv, w, out=out)
    assert got is out
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got, ref, atol=1e-9)


# ----------------------------------------------------------------------------- real data
def test_real_charuco_corners_triangulate_to_published_3d(data_dir):
    """Caliscope session: 4 calibrated webcams, ChArUco corners detected in each view;
    triangulating the detections must land on the published 3D corners (metres)."""
    import csv
    import tomllib

    from mocap_rt.geometry.camera import Camera

    root = data_dir / "multiview" / "caliscope_post_optimization"
    table = tomllib.loads((root / "camera_array.toml").read_text())["cameras"]
    ids = sorted(int(k) for k in table)
    cams = [Camera(f"cam_{k}", tuple(table[str(k)]["size"]), table[str(k)]["matrix"],
                   table[str(k)]["distortions"], table[str(k)]["rotation"], table[str(k)]["translation"])
            for k in ids]
    truth = {}
    with open(root / "CHARUCO" / "xyz_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            truth[int(row["sync_index"]), int(row["keypoint_id"])] = [
                float(row[k]) for k in ("x_coord", "y_coord", "z_coord")]
    keys = sorted(truth)
    index = {k: i for i, k in enumerate(keys)}
    uv = np.full((len(cams), len(keys), 2), np.nan)
    with open(root / "CHARUCO" / "xy_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            key = int(row["sync_index"]), int(row["keypoint_id"])
            if key in index:
                uv[ids.index(int(row["cam_id"])), index[key]] = [float(row["img_loc_x"]), float(row["img_loc_y"])]
    X_true = np.array([truth[k] for k in keys])
    seen = np.isfinite(uv).all(-1).sum(0) >= 2
    assert seen.sum() > 300
    for X in (triangulate_points(cams, uv), _rays_lsq(cams, uv), triangulate_points(cams, uv, refine=True)):
        err = np.linalg.norm(X[seen] - X_true[seen], axis=1)
        assert np.median(err) < 0.005 and np.percentile(err, 95) < 0.02
        assert np.all(np.isnan(X[~seen]))
    # adjacent ChArUco corners are one 5.4 cm square apart
    X = triangulate_points(cams, uv, refine=True)
    gaps = [np.linalg.norm(X[index[k]] - X[index[(k[0], k[1] + 1)]]) for k in keys
            if (k[0], k[1] + 1) in index and k[1] % 3 != 2 and seen[index[k]] and seen[index[(k[0], k[1] + 1)]]]
    assert abs(np.median(gaps) - 0.054) < 0.002


def test_ray_triangulator_rejects_bad_weights_and_out():
    rng = np.random.default_rng(0)
    cams = _rig(rng, 3)
    tri = RayTriangulator(cams)
    uv = _observe(cams, random_points(rng, 4))
    for bad in (-1.0, np.inf):
        w = np.ones((3, 4))
        w[2, 3] = bad
        with pytest.raises(ValueError, match="finite and >= 0"):
            tri(uv, w)
    with pytest.raises(ValueError, match="weights must have shape"):
        tri(uv, np.ones((3, 5)))
    with pytest.raises(ValueError, match="out must be"):
        tri(uv, out=np.empty((4, 3), np.float32))


def test_real_board_rows_line_direction(data_dir):
    """B.2 on real data: a row of ChArUco corners seen by two calibrated webcams gives the
    3D direction of that row (published 3D corners), to a few degrees."""
    import csv
    import tomllib

    from mocap_rt.geometry.camera import Camera

    root = data_dir / "multiview" / "caliscope_post_optimization"
    table = tomllib.loads((root / "camera_array.toml").read_text())["cameras"]
    cams = {int(k): Camera(f"cam_{k}", tuple(v["size"]), v["matrix"], v["distortions"], v["rotation"],
                           v["translation"]) for k, v in table.items()}
    xyz, xy = {}, {}
    with open(root / "CHARUCO" / "xyz_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            xyz[int(row["sync_index"]), int(row["keypoint_id"])] = np.array(
                [float(row[k]) for k in ("x_coord", "y_coord", "z_coord")])
    with open(root / "CHARUCO" / "xy_CHARUCO.csv") as fh:
        for row in csv.DictReader(fh):
            xy[int(row["cam_id"]), int(row["sync_index"]), int(row["keypoint_id"])] = np.array(
                [float(row["img_loc_x"]), float(row["img_loc_y"])])

    def ideal(cam_id, uv):  # undistorted pixel
        cam = cams[cam_id]
        return (cam.K @ np.append(cam.undistort_pixels(uv[None])[0], 1.0))[:2]

    angles = []
    for (cam_id, sync, kp) in list(xy):
        if cam_id != 1 or kp % 3 != 0:
            continue
        a_id, b_id = kp, kp + 2  # first and last corner of a row of 3
        keys = [(c, sync, k) for c in (1, 2) for k in (a_id, b_id)]
        if not all(k in xy for k in keys) or (sync, a_id) not in xyz or (sync, b_id) not in xyz:
            continue
        d = line_direction_two_views(cams[1].P, ideal(1, xy[keys[0]]), ideal(1, xy[keys[1]]),
                                     cams[2].P, ideal(2, xy[keys[2]]), ideal(2, xy[keys[3]]))
        truth = xyz[sync, b_id] - xyz[sync, a_id]
        if np.isfinite(d).all():
            angles.append(np.degrees(np.arccos(np.clip(d @ truth / np.linalg.norm(truth), -1, 1))))
    assert len(angles) > 30
    assert np.median(angles) < 1.5, np.median(angles)  # oriented a -> b too (a wrong sign gives ~180)
