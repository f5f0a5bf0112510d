"""BodyTracker driven by exact 2D projections (+ noise) of real CMU motion."""

from dataclasses import replace

import numpy as np
import pytest

from mocap_rt.body.estimate import bone_lengths_from_joints
from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.cues import CameraCues, CuePrediction
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.tracker import BodyTracker
from mocap_rt.geometry.rig import desktop_rig, ring_rig
from mocap_rt.io.bvh import read_bvh
from mocap_rt.names import CUE_JOINT_INDEX, JOINT_NAMES
from mocap_rt.studio.body_map import body_motion


@pytest.fixture(scope="module")
def walk(data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    return body_motion(clip, fps=30, n_frames=80, placement="centre").joints


def camera_cues(rig, points, frame, rng, noise_px=1.0, drop=()):
    out = {}
    for cam in rig.cameras:
        uv, front = cam.project(points)
        uv = uv + rng.normal(0, noise_px, uv.shape)
        ok = front & cam.in_image(uv)
        ok[list(drop)] = False
        xy = np.where(ok[:, None], uv, np.nan)
        out[cam.name] = CameraCues(cam.name, frame, xy, np.zeros((6, 2, 2)), ok * 100.0, ok * 1.0)
    return out


def run(tracker, rig, joints, seed=0, **kw):
    rng = np.random.default_rng(seed)
    res = []
    for f, J in enumerate(joints):
        res.append(tracker.step(f, camera_cues(rig, J[list(CUE_JOINT_INDEX)], f, rng, **kw)))
    return res


def test_tracker_on_truth_cues_meets_a_loose_accuracy_bound(walk):
    rig = ring_rig()
    tracker = BodyTracker(rig, FusionConfig(bone_lengths=bone_lengths_from_joints(walk)))
    res = run(tracker, rig, walk)
    cues = np.array([r.cues_3d for r in res])
    joints = np.array([r.joints for r in res])
    cue_err = np.linalg.norm(cues - walk[:, list(CUE_JOINT_INDEX)], axis=-1)
    assert np.all(np.array([r.cue_valid for r in res]))
    assert np.median(cue_err) < 0.010 and np.percentile(cue_err, 95) < 0.030
    mpjpe = np.linalg.norm(joints - walk, axis=-1)[10:].mean()
    assert mpjpe < 0.040
    assert len(res[-1].bvh_frame) == tracker.bvh_skeleton.n_channels
    assert set(res[-1].cameras_used) <= set(rig.names) and len(res[-1].cameras_used) >= 4
    assert res[-1].timings_ms["total"] > 0


def test_predict_gives_every_camera_the_projected_cues(walk):
    rig = ring_rig()
    tracker = BodyTracker(rig)
    run(tracker, rig, walk[:20], noise_px=0.0)
    pred = tracker.predict(20)
    assert tracker.identity.frames >= tracker.config.identity.acquire_frames
    assert list(pred) == list(rig.names)
    truth = walk[20][list(CUE_JOINT_INDEX)]
    for cam in rig.cameras:
        p = pred[cam.name]
        assert isinstance(p, CuePrediction) and p.frame == 20
        uv, _ = cam.project(truth)
        err = np.linalg.norm(p.xy - uv, axis=1)
        assert np.nanmax(err) < 15.0           # one frame ahead of a walk, in pixels
        assert np.all(p.radius_px[np.isfinite(p.radius_px)] > 1)
        # where the body shows each part's centre: the head and hands (body.visible), not the
        # shoes (the leg's split is the subject's convention) nor the torso
        assert np.isnan(p.offset_px[3:]).all()
        assert np.isfinite(p.offset_px[:3]).any(axis=1).sum() >= 2 and np.nanmax(np.abs(p.offset_px)) < 10.0
        assert p.shape_px is None                # a foot of the walk swings
    # the visible shoes' shapes, once the facing is acquired and while the feet move slower
    # than ``shoe_shapes_max_speed_mps``: positive definite, a shoe's length (0.22 m, ~30 px
    # here) at most
    assert np.linalg.norm(tracker.filter.vel[[3, 4]], axis=1).max() > tracker.config.shoe_shapes_max_speed_mps
    anyspeed = BodyTracker(rig, replace(tracker.config, shoe_shapes_max_speed_mps=np.inf))
    run(anyspeed, rig, walk[:20], noise_px=0.0)
    preds = anyspeed.predict(20)
    for p in preds.values():
        shoes = p.shape_px[3:5][np.isfinite(p.shape_px[3:5, 0, 0])]
        assert np.isnan(p.shape_px[[0, 1, 2, 5]]).all() and len(shoes) >= 1
        assert (np.linalg.eigvalsh(shoes) > 0).all() and np.sqrt(np.linalg.eigvalsh(shoes).max()) < 20.0
        # ... with the shoes' visible centres (cast on the published feet) where a shoe has a
        # shape (none where another part hides it), within the shoe
        assert (np.isfinite(p.offset_px[3:5, 0]) <= np.isfinite(p.shape_px[3:5, 0, 0])).all()
    shoe_off = np.array([p.offset_px[3:5] for p in preds.values()])
    assert np.isfinite(shoe_off[..., 0]).sum() >= 3 and np.nanmax(np.abs(shoe_off)) < 10.0
    no_shoes = BodyTracker(rig, replace(anyspeed.config, shoe_offsets=False))
    run(no_shoes, rig, walk[:20], noise_px=0.0)
    assert all(np.isnan(p.offset_px[3:]).all() for p in no_shoes.predict(20).values())
    early = BodyTracker(rig, anyspeed.config)
    run(early, rig, walk[:3], noise_px=0.0)
    assert all(p.shape_px is None and p.offset_px is not None for p in early.predict(3).values())
    off = BodyTracker(rig, replace(tracker.config, visible_offsets=False))
    run(off, rig, walk[:3], noise_px=0.0)
    assert all(p.offset_px is None and p.shape_px is None for p in off.predict(3).values())


def test_missing_cameras_and_the_pair_mode(walk):
    rig = ring_rig()
    tracker = BodyTracker(rig, FusionConfig(views="pair", bone_lengths=bone_lengths_from_joints(walk)))
    rng = np.random.default_rng(3)
    res = []
    for f, J in enumerate(walk[:40]):
        cues = camera_cues(rig, J[list(CUE_JOINT_INDEX)], f, rng)
        if f % 3 == 0:
            cues.pop("cam_2")                     # an absent camera is simply missing
        res.append(tracker.step(f, cues))
    assert len(res[-1].pair) == 2
    err = np.linalg.norm(np.array([r.cues_3d for r in res]) - walk[:40, list(CUE_JOINT_INDEX)], axis=-1)
    assert np.nanmedian(err) < 0.015


def test_desktop_rig_upper_body(walk):
    rig = desktop_rig()
    # the desktop user moves in place 1.8 m in front of the cameras (walk minus its travel)
    J = walk.copy()
    J[..., :2] -= walk[:, JOINT_NAMES.index("pelvis"), None, :2]
    tracker = BodyTracker(rig, FusionConfig(bone_lengths=bone_lengths_from_joints(walk)))
    res = run(tracker, rig, J[:30], drop=(3, 4))  # feet never seen
    r = res[-1]
    assert r.cue_valid[[0, 1, 2, 5]].all() and not r.cue_valid[[3, 4]].any()
    upper = [JOINT_NAMES.index(n) for n in ("head", "hand_l", "hand_r", "torso")]
    assert np.linalg.norm(r.joints[upper] - J[29, upper], axis=1).max() < 0.03
    assert not r.joint_valid[JOINT_NAMES.index("knee_l")] and r.joint_valid[JOINT_NAMES.index("elbow_l")]
    assert np.isfinite(r.joints).all()


def test_config_errors():
    with pytest.raises(ValueError, match="views"):
        FusionConfig(views="three")
    with pytest.raises(ValueError, match="ik"):
        FusionConfig(ik="magic")
    with pytest.raises(ValueError, match="subject_foot_pitch_deg"):
        FusionConfig(subject_foot_pitch_deg=90.0)
    with pytest.raises(ValueError, match="tracking_foot_pitch_deg"):
        FusionConfig(tracking_foot_pitch_deg=float("nan"))
    for bad in (-1.0, 90.0, float("nan")):
        with pytest.raises(ValueError, match="min_ray_angle_deg"):
            FusionConfig(min_ray_angle_deg=bad)


def test_the_silhouette_fit_of_the_lengths_runs_in_the_background_and_agrees(backwards_walk_3s):
    """The service's tracker fits the proportions in another process: the frame that calibrates takes the
    cues' estimate at once, a later frame the fitted lengths, the same the offline tracker fits
    in that frame; with them the arms' joints lie nearer the truth than with the estimate."""
    from mocap_rt.fusion.evaluate import truth_camera_cues
    from mocap_rt.io.recording import Recording

    rec = Recording(backwards_walk_3s)
    truth, names = rec.truth, list(rec.rig.names)
    widths = {c.name: int(c.size[0]) for c in rec.rig.cameras}
    offline = BodyTracker(rec.rig, FusionConfig(fps=rec.fps))
    live = BodyTracker(rec.rig, FusionConfig(fps=rec.fps), background_calibration=True)
    unfitted = BodyTracker(rec.rig, FusionConfig(fps=rec.fps, fit_bone_lengths=False))
    rng = np.random.default_rng(0)
    at = None
    idx = [list(truth["joint_names"]).index(n) for n in JOINT_NAMES]
    arms = [JOINT_NAMES.index(f"{j}_{s}") for j in ("shoulder", "elbow") for s in "lr"]
    err = {id(offline): [], id(unfitted): []}
    for f in range(rec.n_frames):
        cues = truth_camera_cues(truth, names, f, f, 1.0, rng, widths)
        for t in (offline, live, unfitted):
            r = t.step(f, cues)
            if at is not None and t is not live:
                err[id(t)].append(np.linalg.norm(r.joints[arms] - truth["joints"][f][idx][arms], axis=1))
        if at is None and offline.calibrated:
            at = f
            assert live.calibrated and live.lengths == unfitted.lengths != offline.lengths
            live.calibration.fitting.result(timeout=120)     # the other process's fit, done
    assert at is not None and at < rec.n_frames - 1
    assert live.lengths == offline.lengths            # taken by the frame after it was done
    # the subject's lengths have the subject's foot and their own trunk and arms (fitted without the
    # prior); the state's body has the tracking foot and the fit with the prior
    state, subject = offline.solver.lengths, offline.lengths
    assert subject.foot_pitch_deg == FusionConfig().subject_foot_pitch_deg != state.foot_pitch_deg
    assert state.foot_pitch_deg == FusionConfig().tracking_foot_pitch_deg == BoneLengths().foot_pitch_deg
    assert subject != state.with_foot_pitch(subject.foot_pitch_deg)
    assert offline.bvh_skeleton is offline.published.bvh
    fitted, estimated = (1000 * np.mean(err[id(t)]) for t in (offline, unfitted))
    assert fitted < estimated, (fitted, estimated)      # 69 vs 72 mm on these 30 frames at 320x240
    rec.close()


def test_the_background_fits_process_starts_before_the_frames():
    """The service's tracker starts the fit's process when it is made (a start at the
    calibration delayed the next pose); the job comes later, once; a process that never got
    one is stopped with its object. No process where no fit will run."""
    import gc

    from mocap_rt.body.calibrate import BackgroundFit
    from mocap_rt.body.skeleton import BoneLengths

    tracker = BodyTracker(ring_rig(6), FusionConfig(), background_calibration=True)
    spare = tracker.calibration._process
    assert isinstance(spare, BackgroundFit) and spare._proc.is_alive() and not spare.done()
    for given in (BodyTracker(ring_rig(6), FusionConfig(bone_lengths=BoneLengths()), background_calibration=True),
                  BodyTracker(ring_rig(6), FusionConfig(fit_bone_lengths=False), background_calibration=True),
                  BodyTracker(ring_rig(6), FusionConfig())):
        assert given.calibration._process is None
    proc = spare._proc
    tracker.calibration._process = spare = None
    gc.collect()
    proc.join(10)
    assert not proc.is_alive()

    fit = BackgroundFit()
    fit.submit(BoneLengths(), [("not a frame",)] * 6)      # raises in the child
    with pytest.raises(RuntimeError, match="one job"):
        fit.submit(BoneLengths(), [])
    with pytest.raises(RuntimeError, match="fit failed: TypeError"):
        fit.result(timeout=120)


def test_a_failed_background_fit_keeps_the_estimate(caplog):
    from mocap_rt.body.calibrate import BackgroundFit

    tracker = BodyTracker(ring_rig(6), FusionConfig(), background_calibration=True)
    before = tracker.lengths
    fit = BackgroundFit(before, [("not a frame",)] * 6)       # raises in the child
    with pytest.raises(RuntimeError, match="fit failed: TypeError"):
        fit.result(timeout=120)
    tracker.calibration.fitting = fit
    tracker._poll_fitted()
    assert tracker.calibration.fitting is None and tracker.lengths == before
    assert "the estimate stays" in caplog.text


def test_the_published_pose_has_its_trunk_refined_and_the_state_keeps_the_plain_one(kick_reversed):
    """With silhouettes the published joints and BVH row are the refined pose
    (``BodyFitter.refine_trunk``), the head joint on the fused head cue where the trunk was
    hung; the tracker's state (predictions, identity) is what ``FitConfig(refine_trunk=False)``
    gives, so the two trackers' cues and labels stay equal frame by frame. The same holds for the
    published swivels' search (``PoseSolver.published_swivel``, on in ``full``)."""
    from mocap_rt.body.fit import FitConfig
    from mocap_rt.fusion.evaluate import truth_camera_cues
    from mocap_rt.io.recording import Recording
    from mocap_rt.names import C_HEAD

    rec = Recording(kick_reversed)
    truth, names = rec.truth, list(rec.rig.names)
    widths = {c.name: int(c.size[0]) for c in rec.rig.cameras}
    trunk_only = FitConfig(published_swivel_search_deg=0.0, published_arm_search_deg=0.0)
    on = BodyTracker(rec.rig, FusionConfig(fps=rec.fps, fit=trunk_only))
    off = BodyTracker(rec.rig, FusionConfig(fps=rec.fps, fit=replace(trunk_only, refine_trunk=False)))
    full = BodyTracker(rec.rig, FusionConfig(fps=rec.fps))
    rngs = [np.random.default_rng(0) for _ in range(3)]
    hung = swivelled = 0
    for f in range(rec.n_frames):
        a, b, c = (t.step(f, truth_camera_cues(truth, names, f, f, 1.0, rng, widths))
                   for t, rng in zip((on, off, full), rngs))
        np.testing.assert_array_equal(a.cues_ik, b.cues_ik)
        np.testing.assert_array_equal(c.cues_ik, b.cues_ik)
        for t, r in ((on, a), (full, c)):
            np.testing.assert_array_equal(r.bvh_frame, t.published.bvh_row(r.root_pos, r.angles))
        if not np.allclose(a.joints, b.joints):
            hung += 1
            np.testing.assert_allclose(a.joints[JOINT_NAMES.index("head")], a.cues_ik[C_HEAD], atol=1e-9)
        swivelled += not np.allclose(c.joints, a.joints)
    assert 0 < hung and 0 < swivelled, (hung, swivelled)
    rec.close()


def test_a_hand_no_view_measures_is_held_where_it_was_not_dropped_to_rest(hand_held_behind_head):
    """The right hand rests behind the head; from frame 25 no view reports it. Once its track has
    coasted out (``FilterConfig.max_coast_s``) the published hand stays where it was last
    estimated, turned with the body (``hold_limbs``), not at the rest pose (the arm dropped)."""
    from mocap_rt.fusion.evaluate import truth_camera_cues
    from mocap_rt.io.recording import Recording
    from mocap_rt.names import C_HAND_R, C_TORSO, J

    with Recording(hand_held_behind_head) as rec:
        truth, rig, n = rec.truth, rec.rig, rec.n_frames
        names, widths = list(rec.rig.names), {c.name: int(c.size[0]) for c in rec.rig.cameras}
        tracker = BodyTracker(rig, FusionConfig(fps=rec.fps))
        rng = np.random.default_rng(0)
        dead_from = 25 + int(np.ceil(tracker.config.filter.max_coast_s * rec.fps)) + 1
        assert n - dead_from >= 10
        held, rest = [], []
        for f in range(n):
            cues = truth_camera_cues(truth, names, f, f, 1.0, rng, widths)
            if f >= 25:
                for cc in cues.values():
                    cc.xy[C_HAND_R], cc.confidence[C_HAND_R] = np.nan, 0.0
            r = tracker.step(f, cues)
            if f >= dead_from:
                assert not r.cue_valid[C_HAND_R] and not np.isfinite(r.cues_ik[C_HAND_R]).all()
                true_hand = truth["joints"][f][J["hand_r"]]
                held.append(np.linalg.norm(r.joints[J["hand_r"]] - true_hand))
                at_rest = tracker.solver.fill_missing(r.cues_ik, r.axes)[C_HAND_R]
                rest.append(np.linalg.norm(at_rest - true_hand))
    assert np.max(held) < 0.15
    assert np.min(rest) > 0.5          # where the rest pose puts it: the arm hanging


def test_a_held_limb_keeps_its_place_on_the_turning_body():
    """``hold_limbs`` keeps a measured hand's offset from the torso in the body frame;
    ``PoseSolver.fill_missing`` puts it back with the frame's axes: the body turned 90 deg more
    about Z, the hand's offset (0.3, 0.1, 0.4) turns to (-0.1, 0.3, 0.4) (by hand). A limb never
    held stays at rest."""
    from scipy.spatial.transform import Rotation

    from mocap_rt.fusion.solver import PoseSolver
    from mocap_rt.fusion.identity import hold_limbs
    from mocap_rt.names import C_HAND_L, C_HAND_R, C_HEAD, C_TORSO

    rz = lambda deg: Rotation.from_euler("z", deg, degrees=True).as_matrix()      # noqa: E731
    cues = np.full((6, 3), np.nan)
    cues[C_TORSO], cues[C_HEAD] = [1.0, 2.0, 1.0], [1.0, 2.0, 1.5]
    cues[C_HAND_L] = cues[C_TORSO] + [0.3, 0.1, 0.4]
    held = hold_limbs(np.full((6, 3), np.nan), cues, rz(90))
    np.testing.assert_allclose(held[C_HAND_L], [0.1, -0.3, 0.4], atol=1e-12)
    assert np.isnan(held[[C_HAND_R, C_HEAD]]).all()
    solver = PoseSolver(BoneLengths(), FusionConfig())
    later = np.full((6, 3), np.nan)
    later[C_TORSO], later[C_HEAD] = [0.0, 0.0, 1.0], [0.0, 0.0, 1.5]
    filled = solver.fill_missing(later, rz(180), held)
    np.testing.assert_allclose(filled[C_HAND_L], [-0.1, 0.3, 1.4], atol=1e-12)
    np.testing.assert_allclose(filled[C_HAND_R], solver.fill_missing(later, rz(180))[C_HAND_R])


def test_a_cold_start_with_the_hand_behind_the_head_puts_it_nowhere_off_the_body(hand_held_behind_head):
    """A tracker started while the right hand rests behind the head (frame 25): most views
    drop the hand as the face reported twice, and the left/right labelling pairs the one view
    that keeps it with another view's left hand, 2.8 m off the body. ``beyond_reach`` drops that;
    the hand is measured from the 5th frame on, never more than 0.1 m off."""
    from mocap_rt.fusion.evaluate import truth_camera_cues
    from mocap_rt.io.recording import Recording
    from mocap_rt.names import C_HAND_R

    with Recording(hand_held_behind_head) as rec:
        truth, n = rec.truth, rec.n_frames
        names, widths = list(rec.rig.names), {c.name: int(c.size[0]) for c in rec.rig.cameras}
        tracker = BodyTracker(rec.rig, FusionConfig(fps=rec.fps))
        rng = np.random.default_rng(0)
        err = np.array([np.linalg.norm(tracker.step(f, truth_camera_cues(truth, names, f, f, 1.0, rng, widths))
                                       .cues_ik[C_HAND_R] - truth["cues"][f][C_HAND_R]) for f in range(25, n)])
    assert np.isfinite(err[4:]).all()
    assert np.nanmax(err) < 0.1


@pytest.mark.parametrize("share", [0.5, 1.0])
def test_a_hand_coming_back_on_the_other_is_that_hand_seen_twice_unless_both_are_there(backwards_walk_3s, share):
    """Walking backwards, each view's hand blobs cover pi (5 cm f / z)^2 pixels; the left hand goes
    unreported from frame 20, and from frame 45 (its track ended) every view reports it 6 px
    beside the right hand. Perception splitting the right hand's pixels between both labels
    (``share`` 0.5 of the blob each): one hand seen twice, the left never measured there
    (``cue_checks.seen_twice``) while the right still is, within 3 cm. A blob of its own each (``share``
    1.0: two hands held together): the left is measured beside the right."""
    from mocap_rt.fusion.evaluate import truth_camera_cues
    from mocap_rt.fusion.views import RigProjector
    from mocap_rt.io.recording import Recording
    from mocap_rt.names import C_HAND_L, C_HAND_R

    with Recording(backwards_walk_3s) as rec:
        truth, rig, n = rec.truth, rec.rig, rec.n_frames
        names, widths = list(rec.rig.names), {c.name: int(c.size[0]) for c in rec.rig.cameras}
    proj = RigProjector(rig.cameras)
    tracker = BodyTracker(rig, FusionConfig(fps=30.0, bone_lengths=bone_lengths_from_joints(truth["joints"])))
    rng = np.random.default_rng(0)
    left_measured, right_err = [], []
    for f in range(n):
        cues = truth_camera_cues(truth, names, f, f, 0.5, rng, widths)
        _, z, _ = proj.project(truth["cues"][f])
        for c, cc in enumerate(cues.values()):
            cc.area[:] = np.where(cc.confidence > 0, np.pi * 0.05 ** 2 * proj.K[c, 0, 0] * proj.K[c, 1, 1] / z[c] ** 2,
                                  0.0)
            if f >= 20:
                cc.xy[C_HAND_L], cc.confidence[C_HAND_L], cc.area[C_HAND_L] = np.nan, 0.0, 0.0
                if f >= 45 and cc.confidence[C_HAND_R] > 0:
                    cc.xy[C_HAND_L], cc.confidence[C_HAND_L] = cc.xy[C_HAND_R] + [6.0, 0.0], cc.confidence[C_HAND_R]
                    cc.area[C_HAND_L] = cc.area[C_HAND_R] = share * cc.area[C_HAND_R]
        r = tracker.step(f, cues)
        if f >= 45:
            left_measured.append(r.cue_valid[C_HAND_L])
            right_err.append(np.linalg.norm(r.cues_3d[C_HAND_R] - truth["cues"][f][C_HAND_R]))
    assert n - 45 >= 30
    if share < 1.0:
        assert not any(left_measured) and np.max(right_err) < 0.03
    else:
        assert np.mean(left_measured) > 0.9
