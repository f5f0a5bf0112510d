"""Fusion building blocks: Kalman cue filter, view selection, triangulation, Z-buffer prediction."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.fusion.filter import CueFilter, FilterConfig
from mocap_rt.cues import CameraCues
from mocap_rt.fusion.views import (CUE_RADII_M, RigProjector, cue_pixels, frontal_pair, hands_on_head, head_on_trunk,
                                    predict_views, triangulate_cues)
from mocap_rt.geometry.ray_triangulator import RayTriangulator, ill_conditioned
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.geometry.triangulate import triangulate_with_prior


def test_kalman_tracks_constant_velocity_and_predicts():
    f = CueFilter(2, FilterConfig(measurement_noise_m=0.005, accel_psd_m2ps3=0.5))
    rng = np.random.default_rng(0)
    v = np.array([[1.0, -0.5, 0.2], [0.0, 0.3, 0.0]])
    p0 = np.array([[0.0, 0, 1], [1, 1, 0.1]])
    for k in range(90):
        t = k / 30
        f.update(t, p0 + v * t + rng.normal(0, 0.005, (2, 3)))
    np.testing.assert_allclose(f.vel, v, atol=0.15)
    t = 90 / 30
    np.testing.assert_allclose(f.predict_at(t), p0 + v * t, atol=0.02)


def test_kalman_gates_outliers_and_drops_stale_tracks():
    cfg = FilterConfig(gate_m=0.3, max_coast_s=0.2)
    f = CueFilter(1, cfg)
    for k in range(10):
        f.update(k / 30, np.array([[0.0, 0, 1]]))
    acc = f.update(10 / 30, np.array([[2.0, 0, 1]]))          # a 2 m jump: rejected
    assert not acc[0] and np.allclose(f.pos[0], [0, 0, 1], atol=1e-3)
    f.update(20 / 30, np.full((1, 3), np.nan))                # nothing for 0.33 s: track dropped
    assert not f.alive[0] and np.isnan(f.predict_at(21 / 30)).all()
    acc = f.update(21 / 30, np.array([[2.0, 0, 1]]))          # restarts on the new position
    assert acc[0] and np.allclose(f.pos[0], [2, 0, 1])


def test_a_track_started_on_an_outlier_moves_to_the_steady_point_it_rejects():
    """Jumping jacks' first frames: the head track starts on the hands clasped above the head
    (0.35 m up) and flies off with their velocity; the head, measured steadily from then on,
    is rejected by the gate. After ``confirm_frames`` mutually consistent rejections the track
    restarts there (not after ``max_coast_s``); measurements that jump about (each farther
    than the gate from the one before) never take a live track over."""
    cfg = FilterConfig(gate_m=0.35, max_coast_s=0.5, confirm_frames=3)
    f = CueFilter(1, cfg)
    hands = np.array([[0.0, 0.0, 1.9]])
    head = np.array([[0.05, -0.2, 1.56]])
    for k in range(3):
        f.update(k / 30, hands + [[0.12 * k, 0.05 * k, 0.0]])   # the track learns a wild velocity
    for k in range(3, 3 + cfg.confirm_frames):
        acc = f.update(k / 30, head + np.random.default_rng(k).normal(0, 0.003, (1, 3)))
        assert acc[0] == (k == 2 + cfg.confirm_frames)
    np.testing.assert_allclose(f.pos[0], head[0], atol=0.01)
    assert f.predict_at((3 + cfg.confirm_frames) / 30)[0, 2] == pytest.approx(1.56, abs=0.01)
    # a live track on the head: outliers in every frame for 0.33 s, each more than the gate from
    # the one before, never take it over; the head is taken up again when it is seen
    for k in range(10, 20):
        outlier = head + [[0.5 * (-1) ** k, 0.1 * (k % 3), 0.45]]
        assert not f.update(k / 30, outlier)[0]
        np.testing.assert_allclose(f.pos[0], head[0], atol=0.01)
    assert f.update(20 / 30, head)[0]
    # the same track on the hands, accepted every frame, while the head is measured every third
    # frame (perception's head check puts it back, the next prediction pulls it away): the
    # third consistent rejection, 0.2 s after the first, restarts the track on the head
    f = CueFilter(1, cfg)
    for k in range(30):
        z = head if k % 3 == 2 else hands + [[0.01 * k, 0.0, 0.0]]
        acc = f.update(k / 30, z)
        if k == 8:
            break
        assert acc[0] == (k % 3 != 2)
    assert acc[0] and np.allclose(f.pos[0], head[0])


def test_rig_projector_matches_camera_project():
    rig = ring_rig()
    X = np.random.default_rng(1).normal([0, 0, 1], 0.6, (8, 3))
    uv, z, dist = RigProjector(rig.cameras).project(X)
    for c, cam in enumerate(rig.cameras):
        ref, front = cam.project(X)
        np.testing.assert_allclose(uv[c][front], ref[front], atol=1e-9)
        np.testing.assert_allclose(dist[c], np.linalg.norm(X - cam.center, axis=1))


def test_triangulation_rejects_an_outlier_view():
    rig = ring_rig()
    X = np.array([[0.1, -0.2, 1.2], [0.0, 0.3, 0.5]])
    proj = RigProjector(rig.cameras)
    uv, _, _ = proj.project(X)
    uv[2, 0] += [40.0, -25.0]                                  # a wrong blob in one camera
    Xh, used, res = triangulate_cues(RayTriangulator(rig.cameras), proj, uv, np.ones((6, 2)), 4.0)
    np.testing.assert_allclose(Xh, X, atol=1e-6)
    assert not used[2, 0] and used[:, 1].all() and used[:, 0].sum() == 5
    assert np.nanmax(res[used]) < 1e-3


def test_two_cameras_facing_each_other_do_not_measure_depth_between_them():
    """A hand beside the face seen by two opposite ring cameras only (the others dropped it as the
    face's blob): their rays meet 6-9 deg from antiparallel, so 2 px of lateral error put the
    plain triangulation 0.1-0.3 m off along the line between them (the hands crossing at the face
    s0: 0.45 m). ``ill_conditioned`` finds it; with the filter's point as a prior the rays keep
    what they measure and the prior decides the depth."""
    rig = ring_rig()
    proj, tri = RigProjector(rig.cameras), RayTriangulator(rig.cameras)
    X = np.array([[0.08, 0.15, 1.6], [0.3, -0.2, 1.0]])
    uv, _, _ = proj.project(X)
    w = np.zeros((6, 2))
    w[[1, 4], 0] = 1.0                        # cameras 1 and 4 face each other across the subject
    w[[0, 1], 1] = 1.0                        # adjacent cameras, 60 deg apart
    noisy = uv.copy()
    noisy[1, 0] += [2.0, 0.0]                 # image x runs the other way in the opposite view:
    noisy[4, 0] += [2.0, 0.0]                 # the rays move apart along the line between them
    Xh = tri(noisy, w)
    assert np.linalg.norm(Xh[0] - X[0]) > 0.1
    used = w > 0
    np.testing.assert_array_equal(ill_conditioned(proj.centers, Xh, used, 20.0), [True, False])
    three = used.copy()
    three[2, 0] = True                        # a third view 60 deg from one of them: conditioned
    assert not ill_conditioned(proj.centers, Xh, three, 20.0)[0]
    one = np.zeros_like(used)
    one[1, 0] = True
    assert not ill_conditioned(proj.centers, Xh, one, 20.0).any()
    prior = X[0] + [0.03, -0.02, 0.02]
    Xp = triangulate_with_prior(rig.cameras, noisy[:, :1], w[:, :1], prior[None], 0.05)[0]
    assert np.linalg.norm(Xp - X[0]) < 1.2 * np.linalg.norm(prior - X[0]) < np.linalg.norm(Xh[0] - X[0]) / 3
    # exact rays and the prior on them: the point itself
    np.testing.assert_allclose(triangulate_with_prior(rig.cameras, uv[:, :1], w[:, :1], X[:1], 0.05)[0], X[0], atol=1e-9)
    # well-conditioned views: the prior moves the point by about prior_weight of its distance
    Xw = triangulate_with_prior(rig.cameras, uv[:, 1:], w[:, 1:], X[1:] + [0.1, 0.0, 0.0], 0.05)[0]
    assert 0.0 < np.linalg.norm(Xw - X[1]) < 0.1 * 0.05 * 2


def test_a_head_that_views_put_on_a_hand_comes_back_on_the_trunk():
    """Four views see the head, two (more confident) took the hands clasped 0.35 m above it.
    Where least squares followed the two and dropped the right views (the closed loop of
    jumping jacks s5051: the head 0.8 m from the torso), the largest consensus set of views
    puts it back on the trunk (0.42 m from the torso). A head on the trunk is left alone."""
    rig = ring_rig()
    proj, tri = RigProjector(rig.cameras), RayTriangulator(rig.cameras)
    X = np.array([[0.0, 0.0, 1.58], [0.3, -0.1, 1.9], [-0.3, 0.1, 1.1], [0.1, 0, 0.05], [-0.1, 0, 0.05],
                  [0.0, 0.0, 1.16]])                                  # head, hands, feet, torso
    uv, _, _ = proj.project(X)
    w = np.full((6, 6), 0.5)
    uv[[1, 4], 0] = uv[[1, 4], 1]                                     # two views: the head on hand_l
    w[[1, 4], 0] = 1.0
    thr = np.full(6, 6.0)
    Xls, used, _ = triangulate_cues(tri, proj, uv, w, thr, np.zeros(6, bool))
    Xls[0], used[:, 0] = X[1], [False, True, False, False, True, False]   # what least squares kept there
    Xh, used_h = head_on_trunk(tri, proj, uv, w, thr, Xls, used, 0.42)
    np.testing.assert_allclose(Xh[0], X[0], atol=1e-6)
    assert not used_h[[1, 4], 0].any() and used_h[[0, 2, 3, 5], 0].all()
    np.testing.assert_array_equal(Xh[1:], Xls[1:])
    X_ok, used_ok, _ = triangulate_cues(tri, proj, proj.project(X)[0], w, thr, np.zeros(6, bool))
    assert head_on_trunk(tri, proj, uv, w, thr, X_ok, used_ok, 0.42)[0] is X_ok


@pytest.mark.parametrize("pan_deg", [0, 60, 150, -100])
def test_frontal_pair_faces_the_subject(pan_deg):
    rig = ring_rig()
    centers = np.array([c.center for c in rig.cameras])
    a = np.radians(pan_deg)
    right = np.array([np.cos(a), np.sin(a), 0])
    forward = np.cross([0, 0, 1], right)
    torso = np.array([0.2, -0.1, 1.0])
    pair = frontal_pair(centers, torso - 0.1 * right, torso + 0.1 * right, torso, forward)
    # independent check: the two cameras most in front of the subject (largest forward component)
    front = (centers - torso)[:, :2] @ forward[:2] / np.linalg.norm((centers - torso)[:, :2], axis=1)
    assert set(pair) == set(np.argsort(front)[-2:])


def test_zbuffer_hides_a_cue_behind_a_nearer_one():
    rig = ring_rig()
    cam = rig.cameras[0]
    head = np.array([0.0, 0.0, 1.6])
    behind = head + 0.3 * (head - cam.center) / np.linalg.norm(head - cam.center)  # straight behind the head
    X = np.array([head, behind, [0.5, 0, 1.0], [-0.1, 0, 0.05], [0.1, 0, 0.05], [0, 0, 1.1]])
    xy, vis, rad = predict_views(RigProjector(rig.cameras), X, np.array([0.1, 0.05, 0.05, 0.06, 0.06, 0.15]))
    assert vis[0, 0] and not vis[0, 1]            # hidden in cam_1 by the nearer head
    opposite = int(np.argmax(np.linalg.norm([c.center - rig.cameras[0].center for c in rig.cameras], axis=1)))
    assert vis[opposite, 1]                       # seen from the other side
    np.testing.assert_allclose(xy[0, 1], xy[0, 0], atol=1e-6)
    assert rad[0, 0] > rad[0, 1] * 1.5            # the head's disc is larger and nearer
    # unknown cues are not visible and have no position
    X[2] = np.nan
    xy, vis, _ = predict_views(RigProjector(rig.cameras), X)
    assert np.isnan(xy[:, 2]).all() and not vis[:, 2].any()



def _cues_at(rig, xy, rad):
    """Each camera's cues at the pixels ``xy`` (C, 6, 2), the head's blob of radius ``rad`` (C,)."""
    return {c.name: CameraCues(c.name, 0, xy[i], np.zeros((6, 2, 2)), np.full(6, np.pi * rad[i] ** 2), np.ones(6))
            for i, c in enumerate(rig.cameras)}


def test_a_hand_resting_on_the_head_is_kept_where_the_prediction_shows_it():
    """``cue_pixels`` drops a hand found on the head's blob (the face reported twice), unless
    ``hands_on_head`` says the prediction rests that hand on the head, visible and sticking out of
    the head's disc in the view: a hand on top of the head stays measured; one the head hides, one
    passing in front of the face, one inside the head, one swinging past or one predicted elsewhere
    does not."""
    rig = ring_rig()
    proj = RigProjector(rig.cameras)
    index = {c.name: i for i, c in enumerate(rig.cameras)}
    head = np.array([0.0, 0.0, 1.6])
    to_cam0 = (rig.cameras[0].center - head) / np.linalg.norm(rig.cameras[0].center - head)
    X = np.array([head, head + [0.0, 0.0, 0.14], head - 0.13 * to_cam0,       # on top; behind, as cam 0 sees it
                  [-0.1, 0, 0.05], [0.1, 0, 0.05], [0, 0, 1.1]])
    xy, vis, rad = predict_views(proj, X, CUE_RADII_M)
    measured = xy.copy()
    measured[0, 2] = xy[0, 0] + [0.0, 0.5 * rad[0, 0]]         # cam 0 reports the face as the hidden hand
    cues = _cues_at(rig, measured, rad[:, 0])
    on_blob = np.linalg.norm(measured[:, 1:3] - measured[:, :1], axis=-1) < 1.5 * rad[:, :1]
    assert on_blob[:, 0].all() and on_blob[0, 1]                # the cases the drop is for

    uv, w, kept = cue_pixels(cues, index, len(rig.cameras), 0.1)
    assert np.isnan(uv[:, 1]).all() and (w[:, 1] == 0).all() and not kept.any()   # no prediction: dropped
    np.testing.assert_allclose(uv[:, 0], xy[:, 0])                                  # the head stays

    still = np.zeros(6)
    resting = hands_on_head(proj, X, still, 0.12, 0.20, 0.5)
    assert not hands_on_head(proj, X, np.full(6, 1.0), 0.12, 0.20, 0.5)[1].any()   # swinging past: not resting
    assert resting[1][:, 1].all() and not resting[1][0, 2]     # on top: everywhere; behind: not in cam 0
    uv, w, kept = cue_pixels(cues, index, len(rig.cameras), 0.1, resting)
    np.testing.assert_allclose(uv[:, 1], xy[:, 1])              # resting on the head: kept in every view
    assert kept[:, 1].all() and np.isnan(uv[0, 2]).all() and not kept[0, 2]
    assert not kept[:, [0, 3, 4, 5]].any()

    for hand in (head + 0.25 * to_cam0, head + [0.0, 0.0, 0.08]):   # in front of the face; inside the head
        X2 = X.copy()
        X2[1] = hand
        assert not hands_on_head(proj, X2, still, 0.12, 0.20, 0.5)[1][:, 1].any()
    X2 = X.copy()
    X2[1] = head + 0.15 * to_cam0           # on the face: cam 0 sees it inside the head's disc, others beside it
    shown = hands_on_head(proj, X2, still, 0.12, 0.20, 0.5)[1][:, 1]
    assert predict_views(proj, X2, CUE_RADII_M)[1][0, 1] and not shown[0] and shown.any()
    far = (resting[0].copy(), resting[1])
    far[0][:, 1] = proj.project(np.array([[-0.3, 0.0, 1.0]]))[0][:, 0]     # predicted at the hip
    assert np.isnan(cue_pixels(cues, index, len(rig.cameras), 0.1, far)[0][:, 1]).all()

def _two_hands_uv(rig):
    X = np.array([[0, 0, 1.6], [-0.35, 0.1, 1.0], [0.35, -0.1, 1.1], [-0.1, 0, 0.05], [0.12, 0.05, 0.05],
                  [0, 0, 1.1]])
    uv, _, _ = RigProjector(rig.cameras).project(X)
    return X, uv


@pytest.mark.parametrize("with_reference", [True, False])
def test_fix_left_right_makes_the_views_agree(with_reference):
    from mocap_rt.fusion.labels import fix_left_right

    rig = ring_rig()
    X, uv = _two_hands_uv(rig)
    bad = uv.copy()
    for c in (1, 4):                       # two views labelled the hands the other way round
        bad[c, [1, 2]] = bad[c, [2, 1]]
    bad[3, [3, 4]] = bad[3, [4, 3]]        # and one view the feet
    tri, proj = RayTriangulator(rig.cameras), RigProjector(rig.cameras)
    ref = X + 0.03 if with_reference else None
    fixed, w, n = fix_left_right(tri, proj, bad, np.ones((6, 6)), ref)
    np.testing.assert_allclose(fixed, uv)
    assert n == 3


def _label_search_by_loop(tri, proj, uv, w, a, b, cams):
    """The cold label search one combination at a time (the batched ``labels._label_search``'s
    oracle): (C,) bool views to swap, or None."""
    from mocap_rt.fusion.labels import LR_COST_CAP_PX

    best = None
    for mask in range(1 << (cams.size - 1)):
        flips = [False] + [bool(mask >> k & 1) for k in range(cams.size - 1)]
        t_uv, t_w = uv[:, [a, b]].copy(), w[:, [a, b]].copy()
        for c, f in zip(cams, flips):
            if f:
                t_uv[c], t_w[c] = t_uv[c, ::-1], t_w[c, ::-1]
        X = tri(t_uv, np.where(np.isfinite(t_uv).all(-1), t_w, 0.0))
        if not np.isfinite(X).all():
            continue
        err = np.linalg.norm(proj.project(X)[0] - t_uv, axis=-1)[cams]
        cost = float(np.nansum(np.minimum(err, LR_COST_CAP_PX)))
        n_flip = sum(flips)
        key = (round(cost, 6), -max(n_flip, cams.size - n_flip))
        if best is None or key < best[0]:
            best = (key, flips, n_flip > cams.size - n_flip)
    if best is None:
        return None
    swap = np.zeros(len(uv), dtype=bool)
    swap[cams] = [f != best[2] for f in best[1]]
    return swap


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_wrong=st.integers(0, 6), n_missing=st.integers(0, 4),
       noise_px=st.floats(0.0, 30.0))
def test_the_batched_cold_label_search_chooses_what_one_combination_at_a_time_does(seed, n_wrong, n_missing,
                                                                                     noise_px):
    """Random views of the two hands (some labelled the other way round, some cues missing or
    weighed 0, pixel noise up to the error cap): the batched search swaps the same views as
    trying each combination in turn, and those views make the labels agree."""
    from mocap_rt.fusion.labels import _label_search

    rng = np.random.default_rng(seed)
    rig = ring_rig()
    X, uv = _two_hands_uv(rig)
    uv = uv + rng.normal(0.0, noise_px, uv.shape)
    w = rng.uniform(0.2, 1.0, (6, 6))
    wrong = rng.choice(6, n_wrong, replace=False)
    uv[wrong, 1], uv[wrong, 2] = uv[wrong, 2].copy(), uv[wrong, 1].copy()
    for c, k in zip(rng.integers(0, 6, n_missing), rng.integers(1, 3, n_missing)):
        if rng.random() < 0.5:
            uv[c, k] = np.nan
        else:
            w[c, k] = 0.0
    tri, proj = RayTriangulator(rig.cameras), RigProjector(rig.cameras)
    seen = np.isfinite(uv[:, [1, 2]]).all(-1) & (w[:, [1, 2]] > 0)
    cams = np.flatnonzero(seen.any(axis=1))
    if cams.size < 2:
        return
    want = _label_search_by_loop(tri, proj, uv, w, 1, 2, cams)
    got = _label_search(tri, proj, uv, w, 1, 2, cams)
    assert (got is None) == (want is None)
    if want is not None:
        np.testing.assert_array_equal(got, want)
    if want is not None and noise_px < 2.0 and n_missing == 0:
        # the views labelled the other way round, or, of the two mirror images, the one that
        # keeps more views' labels (either when half are wrong)
        swapped, right = set(np.flatnonzero(got)), set(range(6)) - set(wrong)
        assert swapped in (set(wrong), right)
        if n_wrong != 3:
            assert swapped == (set(wrong) if n_wrong < 3 else right)


def test_kalman_recovers_after_one_bad_measurement():
    f = CueFilter(1, FilterConfig(gate_m=0.3))
    for k in range(10):
        f.update(k / 30, np.array([[0.0, 0, 1]]))
    f.update(10 / 30, np.array([[0.0, 0, 0.85]]))          # a bad one inside the gate: wild velocity
    accepted = [f.update(k / 30, np.array([[0.0, 0, 1]]))[0] for k in range(11, 16)]
    assert all(accepted) and np.allclose(f.pos[0], [0, 0, 1], atol=0.02)


def test_a_limb_beyond_its_reach_from_the_torso_is_no_measurement(jumping_jacks):
    """``torso_reach_m`` by hand for the default adult: a hand reaches hypot(0.25, 0.19) + 0.29 +
    0.26 + 0.08 m from the torso cue; ``beyond_reach`` drops one farther than 1.3 times that and
    keeps the head however far. Every frame of the jumping jacks' truth (arms overhead, feet
    apart) is kept with the subject's lengths."""
    from mocap_rt.body.estimate import bone_lengths_from_joints
    from mocap_rt.body.skeleton import BoneLengths
    from mocap_rt.fusion.cue_checks import REACH_MARGIN, beyond_reach, torso_reach_m
    from mocap_rt.io.recording import Recording
    from mocap_rt.names import C_FOOT_L, C_HAND_L, C_HAND_R, C_HEAD, C_TORSO

    reach = torso_reach_m(BoneLengths())
    arm = np.hypot(0.25, 0.19) + 0.29 + 0.26 + 0.08
    assert reach[C_HAND_L] == pytest.approx(arm) and np.isinf(reach[[C_HEAD, C_TORSO]]).all()
    assert reach[C_FOOT_L] == pytest.approx(np.hypot(0.25, 0.09) + BoneLengths().leg_reach_m())
    X = np.ones((6, 3))                                 # the feet at the torso cue
    X[C_HEAD] = X[C_TORSO] + [0.0, 0.0, 3.0]
    X[C_HAND_L] = X[C_TORSO] + [0.0, REACH_MARGIN * arm - 0.01, 0.0]
    X[C_HAND_R] = X[C_TORSO] + [REACH_MARGIN * arm + 0.01, 0.0, 0.0]
    out = beyond_reach(X, reach)
    assert np.isnan(out[C_HAND_R]).all()
    np.testing.assert_array_equal(np.delete(out, C_HAND_R, axis=0), np.delete(X, C_HAND_R, axis=0))
    X[C_TORSO] = np.nan                                 # no torso: nothing to measure the reach from
    np.testing.assert_array_equal(beyond_reach(X, reach), X)
    with Recording(jumping_jacks) as rec:
        cues, joints = np.asarray(rec.truth["cues"]), np.asarray(rec.truth["joints"])
    subject = torso_reach_m(bone_lengths_from_joints(joints))
    assert all(np.isfinite(beyond_reach(c, subject)).all() for c in cues)


def test_one_hand_split_between_both_labels_is_seen_twice_two_hands_together_are_not():
    """Every view of a 6-camera ring sees a hand (5 cm radius) as a disc of pi (5 cm f / z)^2
    pixels. With the hands apart, ``pair_area_reference`` learns one hand's area per view. Two
    hands held 6 cm apart each cover a disc; one hand whose pixels perception split between both
    labels (centres 6 cm apart, each half the disc) covers one: ``seen_twice`` drops the label
    coming back there (its track not alive or just restarted), and neither of the two hands
    together, nor of two tracked hands (a clap hides one hand behind the other)."""
    from mocap_rt.fusion.cue_checks import SEEN_TWICE_RATIO, pair_area_reference, pair_areas, seen_twice
    from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HAND_L, C_HAND_R

    rig = ring_rig()
    proj = RigProjector(rig.cameras)
    f2 = proj.K[:, 0, 0] * proj.K[:, 1, 1]

    def frame(X, share):
        """pixels (C, 6, 2), areas (C, 6) of the hands: each ``share`` of its own disc."""
        uv, z, _ = proj.project(X)
        area = np.full(z.shape, np.nan)
        for h in (C_HAND_L, C_HAND_R):
            area[:, h] = share * np.pi * 0.05 ** 2 * f2 / z[:, h] ** 2
        return uv, area

    X = np.tile([0.0, 0.0, 1.0], (6, 1))
    X[[C_FOOT_L, C_FOOT_R]] = np.nan                    # the feet: no pair to measure
    X[C_HAND_L], X[C_HAND_R] = [-0.4, 0.2, 1.3], [0.4, 0.2, 1.3]
    ref = np.full((len(rig.cameras), 2), np.nan)
    for _ in range(3):
        ref = pair_area_reference(ref, pair_areas(proj, frame(X, 1.0)[1], frame(X, 1.0)[0], X), X, 0.12)
    np.testing.assert_allclose(ref[:, 0], np.pi * 0.05 ** 2, rtol=0.05)   # one hand's area, m^2
    assert np.isnan(ref[:, 1]).all()
    X[C_HAND_L] = X[C_HAND_R] + [0.06, 0.0, 0.0]
    used = np.ones((len(rig.cameras), 6), bool)
    returning = np.zeros(6, bool)
    returning[C_HAND_L] = True                          # the left hand's track is not alive
    uv, together = frame(X, 1.0)
    np.testing.assert_array_equal(seen_twice(X, used, returning, pair_areas(proj, together, uv, X), ref, 0.12), X)
    uv, split = frame(X, 0.5)
    areas = pair_areas(proj, split, uv, X)
    assert np.median(areas[:, 0] / ref[:, 0]) < SEEN_TWICE_RATIO
    out = seen_twice(X, used, returning, areas, ref, 0.12)
    assert np.isnan(out[C_HAND_L]).all() and np.isfinite(np.delete(out, [C_HAND_L, C_FOOT_L, C_FOOT_R], 0)).all()
    returning = returning[[0, 2, 1, 3, 4, 5]]           # now the right hand came back
    assert np.isnan(seen_twice(X, used, returning, areas, ref, 0.12)[C_HAND_R]).all()
    np.testing.assert_array_equal(seen_twice(X, used, np.zeros(6, bool), areas, ref, 0.12), X)   # both tracked
    X[C_HAND_L] = X[C_HAND_R] + [0.15, 0.0, 0.0]        # farther apart than duplicate_m: two hands
    np.testing.assert_array_equal(seen_twice(X, used, returning, pair_areas(proj, split, frame(X, 0.5)[0], X), ref,
                                             0.12), X)
