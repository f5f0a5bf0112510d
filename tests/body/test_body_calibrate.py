"""The subject's proportions fitted to rendered silhouettes (``body.calibrate``)."""

from dataclasses import replace

import numpy as np
import pytest

from mocap_rt.body.analytic import analytic_pose
from mocap_rt.body.calibrate import fit_bone_lengths, fit_state_and_published, moved_percent
from mocap_rt.body.fit import BodyFitter
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.silhouette import SilhouetteTargets, pose_points
from mocap_rt.body.skeleton import BoneLengths, J, body_model
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.names import C_HEAD, C_TORSO, CUE_JOINT_INDEX, N_CUES
from mocap_rt.studio.body_map import POINT_NAMES
from mocap_rt.studio.body_shape import body_primitives
from mocap_rt.studio.render import RenderConfig, StudioRenderer
from studio_silhouettes import silhouette_cues

# a subject far from the default adult's proportions (short forearms, narrow shoulders, as
# the CMU and Bandai skeletons are), and where its trunk shows its centre
TRUE = BoneLengths(trunk_m=0.42, neck_head_m=0.24, shoulder_half_width_m=0.13, upper_arm_m=0.29, forearm_m=0.20,
                   hand_m=0.08, hip_half_width_m=0.08, thigh_m=0.43, shank_m=0.42, foot_m=0.09,
                   torso_cue_up_m=0.025)
ELBOWS = [J["elbow_l"], J["elbow_r"]]
SHOULDERS = [J["shoulder_l"], J["shoulder_r"]]


def _frames(rig, lengths):
    """Eight poses of the true body (arms bent, raised, forward; the body turning), each with its
    cues (6, 3), axes (3, 3), rendered silhouettes and true joints (J, 3)."""
    model = body_model(lengths, "paper")
    ren = StudioRenderer(rig, config=RenderConfig(noise_sigma_levels=0.0))
    rng = np.random.default_rng(3)
    frames = []
    for k in range(8):
        yaw = np.radians(40.0 * k)
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
        torso = np.array([0.1 * k - 0.3, 0.05 * k, 1.15])   # the shoes above the floor, which hides what is below it
        up = R[:, 2]
        head = torso + up * (lengths.trunk_m / 2 + lengths.neck_head_m - lengths.torso_cue_up_m)
        rest = model.rest_positions()
        cues = np.empty((N_CUES, 3))
        for c, j in enumerate(CUE_JOINT_INDEX):
            cues[c] = torso + R @ (rest[j] - rest[J["torso"]])
        cues[C_HEAD] = head
        cues[C_TORSO] = torso
        for s, sx in ((1, -1.0), (2, 1.0)):       # hands: forward, out, up, bent at the elbow
            cues[s] = torso + R @ np.array([sx * rng.uniform(0.15, 0.45), rng.uniform(0.1, 0.4),
                                            rng.uniform(-0.25, 0.35)])
        root, angles = analytic_pose(model, cues, R)
        pos, rot = forward_kinematics(model, root, angles)
        pts = np.empty((len(POINT_NAMES), 3))
        pose_points(pos, rot, np.radians(lengths.foot_pitch_deg), pts)
        cams = silhouette_cues(ren, body_primitives(pts), k)
        cues = pos[list(CUE_JOINT_INDEX)].copy()       # the hands where the arms reach
        cues[C_TORSO] = torso
        frames.append((cues, R, SilhouetteTargets.from_cues(rig.cameras, cams), pos))
    return frames


def _joint_error_mm(lengths, frames, joints):
    model = body_model(lengths, "paper")
    err = []
    for cues, axes, _, truth in frames:
        root, angles = analytic_pose(model, cues, axes)
        pos = forward_kinematics(model, root, angles)[0]
        err.append(np.linalg.norm(pos[joints] - truth[joints], axis=1))
    return 1000 * float(np.mean(err))


@pytest.fixture(scope="module")
def frames():
    return _frames(ring_rig(6, size=(640, 480)), TRUE)


def _start():
    """What the cues alone give: the default proportions, the head at its measured distance."""
    start = replace(BoneLengths().scaled(0.95), torso_cue_up_m=0.0)
    return replace(start, neck_head_m=TRUE.trunk_m / 2 + TRUE.neck_head_m - TRUE.torso_cue_up_m - start.trunk_m / 2)


def test_the_silhouettes_cost_nothing_at_the_truth(frames):
    true_fit, start_fit = BodyFitter(body_model(TRUE, "paper")), BodyFitter(body_model(_start(), "paper"))
    true_cost = [true_fit.fit(cues, axes, None, targets).silhouette_cm2 for cues, axes, targets, _ in frames]
    start_cost = [start_fit.fit(cues, axes, None, targets).silhouette_cm2 for cues, axes, targets, _ in frames]
    assert max(true_cost) < 0.05, true_cost          # cm^2 a frame: 0.01
    assert np.mean(start_cost) > 20 * np.mean(true_cost), start_cost


def test_the_fit_finds_the_subjects_proportions_from_the_default_adults(frames):
    start = _start()
    fitted = fit_bone_lengths(start, [f[:3] for f in frames], prior_cost=0.0)
    for name in ("shoulder_half_width_m", "forearm_m", "torso_cue_up_m"):     # what the cues cannot measure
        assert abs(getattr(fitted, name) - getattr(TRUE, name)) < abs(getattr(start, name) - getattr(TRUE, name))
    e0, e1 = (_joint_error_mm(L, frames, ELBOWS + SHOULDERS) for L in (start, fitted))
    assert e1 < 0.25 * e0, (e0, e1)          # 92 -> 16 mm
    # the head stays where the cues put it
    for L in (start, fitted):
        assert L.trunk_m / 2 + L.neck_head_m - L.torso_cue_up_m == pytest.approx(
            TRUE.trunk_m / 2 + TRUE.neck_head_m - TRUE.torso_cue_up_m)
    # the service's prior keeps the lengths nearer the estimate, part of the way to the truth
    near = fit_bone_lengths(start, [f[:3] for f in frames])
    assert moved_percent(near, start) < moved_percent(fitted, start)
    assert e1 < _joint_error_mm(near, frames, ELBOWS + SHOULDERS) < 0.6 * e0      # 49 mm


def test_the_published_body_fits_its_trunk_and_arms_without_the_prior(frames):
    """``fit_state_and_published``: the state's lengths are ``fit_bone_lengths``'s (with the prior);
    the published body's trunk, torso cue and arms are searched again without it, its legs stay
    the estimate's, and its shoulders and elbows come nearer the truth than the state's."""
    start = _start()
    views = [f[:3] for f in frames]
    state, published = fit_state_and_published(start, views)
    assert state == fit_bone_lengths(start, views)
    for name in ("hip_half_width_m", "thigh_m", "shank_m", "foot_m", "hand_m"):
        assert getattr(published, name) == getattr(start, name)
    e_start, e_state, e_pub = (_joint_error_mm(L, frames, ELBOWS + SHOULDERS) for L in (start, state, published))
    assert e_pub < 0.5 * e_state < 0.5 * e_start, (e_start, e_state, e_pub)


def test_the_true_arms_stay(frames):
    fitted = fit_bone_lengths(TRUE, [f[:3] for f in frames])
    assert _joint_error_mm(fitted, frames, ELBOWS + SHOULDERS) < 5.0


def test_without_silhouettes_the_lengths_stay():
    assert fit_bone_lengths(TRUE, []) == TRUE
    no_views = SilhouetteTargets(ring_rig(2).cameras)
    assert fit_bone_lengths(TRUE, [(np.zeros((N_CUES, 3)), np.eye(3), no_views)] * 6) == TRUE


# ---------------------------------------------------------------- the published trunk (body.fit.refine_trunk)
TRUNK_AND_LEGS = [J[n] for n in ("pelvis", "torso", "neck", "hip_l", "hip_r", "knee_l", "knee_r")]


def _axes_on(cues, right):
    """Body axes (right, forward, up) with up on the torso cue -> head cue line (as ``body_axes``)."""
    up = cues[C_HEAD] - cues[C_TORSO]
    up /= np.linalg.norm(up)
    r = right - up * (right @ up)
    r /= np.linalg.norm(r)
    return np.column_stack([r, np.cross(up, r), up])


def _pose(model, cues, axes, config=None):
    args = (model, cues, axes) if config is None else (model, cues, axes, config)
    return forward_kinematics(model, *analytic_pose(*args))[0]


def test_the_trunk_hung_from_the_head_puts_the_head_joint_on_its_cue():
    """``AnalyticConfig.trunk_from_head``: wherever the torso cue lies on the trunk's line, the
    head joint is on the head cue and the pelvis trunk + neck below it."""
    from mocap_rt.body.analytic import AnalyticConfig

    model = body_model(TRUE, "paper")
    hung = AnalyticConfig(trunk_from_head=True)
    rng = np.random.default_rng(5)
    rest = model.rest_positions()
    for _ in range(20):
        cues = rest[list(CUE_JOINT_INDEX)] + rng.normal(0, 0.02, (N_CUES, 3))
        cues[C_TORSO] = cues[C_HEAD] - np.array([0, 0, rng.uniform(0.3, 0.5)])     # anywhere below the head
        axes = _axes_on(cues, np.array([1.0, 0, 0]))
        got = _pose(model, cues, axes, hung)
        np.testing.assert_allclose(got[J["head"]], cues[C_HEAD], atol=1e-9)
        np.testing.assert_allclose(got[J["pelvis"]], cues[C_HEAD] - axes[:, 2] * (TRUE.neck_head_m + TRUE.trunk_m),
                                   atol=1e-9)
        plain = _pose(model, cues, axes)           # the default: the trunk on the torso cue
        np.testing.assert_allclose(plain[J["torso"]], cues[C_TORSO] - axes[:, 2] * TRUE.torso_cue_up_m, atol=1e-9)


def test_refine_trunk_recovers_the_trunk_from_a_torso_cue_off_its_joint(frames):
    """The torso cue 3 cm behind the joint and its height unknown (``torso_cue_up_m`` 0, the
    truth's 2.5 cm), as perception's visible centre is: the trunk hung from the head cue and
    tilted to the rendered silhouettes puts the trunk and legs nearer the truth's than the
    plain pose does, the head joint stays on its cue. A plain pose that is right stays."""
    lengths = replace(TRUE, torso_cue_up_m=0.0)
    model = body_model(lengths, "paper")
    fitter = BodyFitter(model)
    plain_err, hung_err = [], []
    for cues, axes, targets, truth in frames:
        c = cues.copy()
        c[C_TORSO] -= 0.03 * axes[:, 1]
        ax = _axes_on(c, axes[:, 0])
        hung = fitter.refine_trunk(c, ax, np.zeros(4), targets)
        assert hung is not None
        got = _pose(model, *hung, fitter.hung)
        np.testing.assert_allclose(got[J["head"]], c[C_HEAD], atol=1e-9)
        plain_err.append(np.linalg.norm(_pose(model, c, ax)[TRUNK_AND_LEGS] - truth[TRUNK_AND_LEGS], axis=1).mean())
        hung_err.append(np.linalg.norm(got[TRUNK_AND_LEGS] - truth[TRUNK_AND_LEGS], axis=1).mean())
    assert np.mean(hung_err) < 0.5 * np.mean(plain_err), (plain_err, hung_err)      # 70 -> 11 mm
    # the true lengths and cue: the plain pose is exact, and what refine_trunk returns is no worse
    true_fit = BodyFitter(body_model(TRUE, "paper"))
    for cues, axes, targets, truth in frames:
        hung = true_fit.refine_trunk(cues, axes, np.zeros(4), targets)
        if hung is not None:
            got = _pose(body_model(TRUE, "paper"), *hung, true_fit.hung)
            assert np.linalg.norm(got[TRUNK_AND_LEGS] - truth[TRUNK_AND_LEGS], axis=1).mean() < 0.01
    assert fitter.refine_trunk(frames[0][0], frames[0][1], np.zeros(4), SilhouetteTargets(ring_rig(6).cameras)) is None
