"""Where the legs meet the shoes (perception.leg_attach): a numpy reference, drawn cases and the
studio's renders against the truth's ankles."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.perception.leg_attach import MIN_BLOB_AREA_PX, MIN_RING_PX, OTHER_SD, RING_SD, leg_attachment


def reference(sil, x0, y0, xy, cov, area, min_area):
    """The kernel's definition, in numpy: the mean of the person's pixels in the ring around each
    blob, on or above its centre row, away from the other blob's centre."""
    out = np.full((2, 2), np.nan)
    ys, xs = np.nonzero(sil)
    px = np.stack([xs + x0, ys + y0], 1).astype(float)
    for k in range(2):
        if not (area[k] >= min_area and np.isfinite(xy[k]).all()):
            continue
        lam, vec = np.linalg.eigh(cov[k])
        sd2, sd1 = np.sqrt(np.maximum(lam, 1e-6))
        a = vec[:, 1]
        d = px - xy[k]
        ta = d @ a / sd1
        tb = d @ np.array([-a[1], a[0]]) / sd2
        r2 = ta ** 2 + tb ** 2
        keep = (r2 >= RING_SD[0] ** 2) & (r2 <= RING_SD[1] ** 2) & (px[:, 1] <= np.floor(xy[k, 1] - y0) + y0)
        if np.isfinite(xy[1 - k]).all():
            keep &= ((px - xy[1 - k]) ** 2).sum(1) > (OTHER_SD * sd2) ** 2
        if keep.sum() >= MIN_RING_PX:
            out[k] = px[keep].mean(0)
    return out


def draw_foot(shape, centre, heading_deg, heel_left: bool):
    """A side-view shoe (ellipse 40 x 12 px) with a shank (14 px wide) standing on its heel end."""
    sil = np.zeros(shape, np.uint8)
    cx, cy = centre
    cv2.ellipse(sil, (cx, cy), (20, 6), heading_deg, 0, 360, 255, -1)
    a = np.array([np.cos(np.radians(heading_deg)), np.sin(np.radians(heading_deg))])
    heel = np.array(centre) + (-12 if heel_left else 12) * a
    cv2.rectangle(sil, (int(heel[0]) - 7, 0), (int(heel[0]) + 7, int(heel[1])), 255, -1)
    ys, xs = np.nonzero(_ellipse_only(shape, centre, heading_deg))
    cov = np.cov(np.stack([xs, ys]), bias=True) + np.eye(2) / 12.0
    return sil, np.array([xs.mean(), ys.mean()]), cov, float(xs.size)


def _ellipse_only(shape, centre, heading_deg):
    m = np.zeros(shape, np.uint8)
    cv2.ellipse(m, centre, (20, 6), heading_deg, 0, 360, 255, -1)
    return m


@pytest.mark.parametrize("heel_left", [True, False])
@pytest.mark.parametrize("heading", [0.0, 15.0, -20.0])
def test_the_attachment_is_at_the_heel_end_of_a_drawn_foot(heel_left, heading):
    sil, c, cov, area = draw_foot((120, 160), (80, 90), heading, heel_left)
    out = np.empty((2, 2))
    xy = np.array([c, [np.nan, np.nan]])
    leg_attachment(sil, 0, 0, xy, np.array([cov, np.eye(2)]), np.array([area, 0.0]), MIN_BLOB_AREA_PX, out)
    a = np.array([np.cos(np.radians(heading)), np.sin(np.radians(heading))])
    t = (out[0] - c) @ a
    assert (t < -5.0) if heel_left else (t > 5.0)
    assert np.isnan(out[1]).all()                      # the missing second blob


def test_small_or_missing_blobs_and_bare_rings_measure_nothing():
    sil, c, cov, area = draw_foot((120, 160), (80, 90), 0.0, True)
    out = np.empty((2, 2))
    covs = np.array([cov, cov])
    leg_attachment(sil, 0, 0, np.array([c, c]), covs, np.array([MIN_BLOB_AREA_PX - 1, np.nan]),
                   MIN_BLOB_AREA_PX, out)
    assert np.isnan(out).all()
    shoe_only = _ellipse_only((120, 160), (80, 90), 0.0)     # no leg: nothing in the ring
    leg_attachment(shoe_only, 0, 0, np.array([c, [np.nan, np.nan]]), covs, np.array([area, 0.0]),
                   MIN_BLOB_AREA_PX, out)
    assert np.isnan(out).all()


def test_the_other_shoes_leg_is_left_out():
    """Person pixels in this shoe's ring but near the other shoe's centre (its leg, where the two
    feet stand close) do not move this shoe's attachment; without the other shoe they would."""
    sil, c, cov, area = draw_foot((120, 160), (80, 90), 0.0, True)
    other = np.array([108.0, 84.0])                    # toe side, inside the ring
    crowded = sil.copy()
    crowded[81:88, 105:112] = 255
    out = {}
    for name, img, xy2 in (("alone", sil, [np.nan, np.nan]), ("crowded", crowded, other),
                           ("unknown other", crowded, [np.nan, np.nan])):
        o = np.empty((2, 2))
        leg_attachment(img, 0, 0, np.array([c, xy2]), np.array([cov, cov]), np.array([area, 0.0]),
                       MIN_BLOB_AREA_PX, o)
        out[name] = o[0]
    np.testing.assert_allclose(out["crowded"], out["alone"])
    assert out["unknown other"][0] > out["alone"][0] + 1.0


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_kernel_matches_the_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    h, w = 90, 130
    sil = (rng.random((h, w)) < rng.uniform(0.2, 0.8)).astype(np.uint8) * 255
    x0, y0 = int(rng.integers(0, 300)), int(rng.integers(0, 200))
    xy = np.stack([rng.uniform(10, w - 10, 2) + x0, rng.uniform(10, h - 10, 2) + y0], 1)
    if rng.random() < 0.3:
        xy[1] = np.nan
    cov = np.empty((2, 2, 2))
    for k in range(2):
        ang = rng.uniform(0, np.pi)
        R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        cov[k] = R @ np.diag(rng.uniform(2, 60, 2)) @ R.T
    area = rng.uniform(0, 80, 2)
    out = np.empty((2, 2))
    leg_attachment(sil, x0, y0, xy, cov, area, MIN_BLOB_AREA_PX, out)
    np.testing.assert_allclose(out, reference(sil, x0, y0, xy, cov, area, MIN_BLOB_AREA_PX), atol=1e-9)


def test_rendered_legs_meet_the_shoes_at_the_truths_ankles(data_dir):
    """The studio renders a CMU walk and a Bandai kick (6-camera ring, 320x240): the person's
    silhouette, and each shoe alone for its blob moments. Along each blob's axis, the measured
    attachment lies on the side of the blob's centre where the truth's ankle projects in most
    views; and per frame, summed over the views and feet, the measurements lie nearer the truth's
    ankles than the places of the ankles of the feet turned round by 180 deg (the body facing the
    other way) in every frame but a few (measured: 0-1 %, offline on six suite clips)."""
    from mocap_rt.geometry.rig import ring_rig
    from mocap_rt.io.bvh import read_bvh
    from mocap_rt.studio.body_map import POINT_NAMES, body_motion
    from mocap_rt.studio.body_shape import body_primitives
    from mocap_rt.studio.render import RenderConfig, StudioRenderer
    from studio_shoes import shoe_covariance

    rig = ring_rig(6, size=(320, 240))
    ren = StudioRenderer(rig, config=RenderConfig(noise_sigma_levels=0.0))
    P = {n: i for i, n in enumerate(POINT_NAMES)}
    agree, views, frames_right, frames = 0, 0, 0, 0
    for path in ("cmu/cmu_02_01_walk.bvh", "bandai_namco/dataset-1_kick_normal_001.bvh"):
        motion = body_motion(read_bvh(data_dir / "bvh" / path), fps=30, n_frames=40, start_s=1.0, placement="centre")
        for fr in range(0, 40, 4):
            pts = motion.points[fr]
            up = np.array([0.0, 0.0, 1.0])
            cost_true, cost_turned = 0.0, 0.0
            for c, cam in enumerate(rig.cameras):
                sil = ren.render(c, body_primitives(pts), fr).mask.astype(np.uint8)
                xy, cov, area = np.full((2, 2), np.nan), np.full((2, 2, 2), np.nan), np.zeros(2)
                for k, s in enumerate("lr"):
                    shoe = shoe_covariance(ren, c, pts[P[f"heel_{s}"]], pts[P[f"toe_{s}"]], fr)
                    if shoe is not None and shoe[2] >= MIN_BLOB_AREA_PX:
                        cov[k], xy[k], area[k] = shoe
                out = np.empty((2, 2))
                leg_attachment(sil, 0, 0, xy, cov, area, MIN_BLOB_AREA_PX, out)
                for k, s in enumerate("lr"):
                    if not np.isfinite(out[k]).all():
                        continue
                    a = np.linalg.eigh(cov[k])[1][:, 1]
                    foot = 0.5 * (pts[P[f"heel_{s}"]] + pts[P[f"toe_{s}"]])
                    v = pts[P[f"ankle_{s}"]] - foot
                    uv = cam.project(np.stack([foot, foot + v, foot + 2 * (v @ up) * up - v]))[0]
                    t_meas, t_true, t_turned = (out[k] - xy[k]) @ a, (uv[1] - uv[0]) @ a, (uv[2] - uv[0]) @ a
                    if abs(t_true) > 2.0:
                        agree += np.sign(t_meas) == np.sign(t_true)
                        views += 1
                    d = t_turned - t_true
                    if abs(d) > 1e-9:
                        lam = np.clip((t_meas - t_true) / d, 0.0, 1.0)
                        cost_true += lam * d * d
                        cost_turned += (1.0 - lam) * d * d
            frames += 1
            frames_right += cost_true < cost_turned
    assert views > 100 and agree / views >= 0.85, (agree, views)
    assert frames_right >= frames - 1, (frames_right, frames)
