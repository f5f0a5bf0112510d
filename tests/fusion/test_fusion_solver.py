"""The published pose's swivels searched again on the silhouettes (``fusion.solver.PoseSolver``)."""

from dataclasses import replace

import numpy as np
import pytest

from mocap_rt.body.analytic import analytic_pose
from mocap_rt.body.fit import FitConfig
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.silhouette import SilhouetteTargets, pose_points
from mocap_rt.body.skeleton import BoneLengths, J, body_model
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.solver import PoseSolver
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.names import C_TORSO, CUE_JOINT_INDEX, N_CUES
from mocap_rt.studio.body_map import POINT_NAMES
from mocap_rt.studio.body_shape import body_primitives
from mocap_rt.studio.render import RenderConfig, StudioRenderer
from studio_silhouettes import silhouette_cues

LENGTHS = BoneLengths()
MIDDLE = [J[n] for n in ("elbow_l", "elbow_r", "knee_l", "knee_r")]
# the swivels the subject holds (arm_l, arm_r, leg_l, leg_r): elbows flared out and knees turned,
# 40-50 deg from the default poles, farther than the state's search reaches in one frame (30)
SWIVEL = np.radians([45.0, -50.0, -40.0, 40.0])


@pytest.fixture(scope="module")
def frames():
    """Six rendered poses with the limbs bent and swivelled: cues (6, 3), axes, silhouettes,
    true joints (J, 3)."""
    rig = ring_rig(6, size=(640, 480))
    model = body_model(LENGTHS, "paper")
    ren = StudioRenderer(rig, config=RenderConfig(noise_sigma_levels=0.0))
    rng = np.random.default_rng(11)
    rest = model.rest_positions()
    out = []
    for k in range(6):
        yaw = np.radians(55.0 * k)
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
        torso = np.array([0.1 * k - 0.2, 0.05 * k, 1.05])
        cues = np.array([torso + R @ (rest[j] - rest[J["torso"]]) for j in CUE_JOINT_INDEX])
        for c, sx in ((1, -1.0), (2, 1.0)):       # hands forward and in: the elbows bent
            cues[c] = torso + R @ np.array([sx * rng.uniform(0.1, 0.25), rng.uniform(0.25, 0.4), rng.uniform(-0.2, 0.1)])
        for c, sx in ((3, -1.0), (4, 1.0)):       # feet raised: the knees bent
            cues[c] = cues[c] + R @ np.array([0.0, rng.uniform(0.05, 0.15), rng.uniform(0.15, 0.3)])
        root, angles = analytic_pose(model, cues, R, swivel=SWIVEL)
        pos, rot = forward_kinematics(model, root, angles)
        pts = np.empty((len(POINT_NAMES), 3))
        pose_points(pos, rot, np.radians(LENGTHS.foot_pitch_deg), pts)
        cams = silhouette_cues(ren, body_primitives(pts), k)
        cues = pos[list(CUE_JOINT_INDEX)].copy()
        cues[C_TORSO] = torso
        out.append((cues, R, SilhouetteTargets.from_cues(rig.cameras, cams), pos))
    return out


def _middle_error_mm(pose, truth):
    return 1000 * float(np.linalg.norm(pose[2][MIDDLE] - truth[MIDDLE], axis=1).mean())


def test_the_published_swivels_reach_what_the_state_holds_back(frames):
    """From the default poles (the state's swivels after a prior that holds them), the published
    pose finds the subject's flared elbows and turned knees on the silhouettes; the trunk refinement
    and the pelvis's turn off so that the swivels alone are measured."""
    config = FusionConfig(fit=FitConfig(refine_trunk=False, published_pelvis_twist_deg=0.0))
    solver = PoseSolver(LENGTHS, config)
    off = PoseSolver(LENGTHS, replace(config, fit=replace(config.fit, published_swivel_search_deg=0.0,
                                                                   published_arm_search_deg=0.0)))
    coarse = PoseSolver(LENGTHS, replace(config, fit=replace(config.fit, published_swivel_refine=0)))
    plain_err, published_err, coarse_err = [], [], []
    for cues, axes, targets, truth in frames:
        zero = np.zeros(4)
        plain = solver.plain(cues, axes, zero, targets)
        np.testing.assert_array_equal(off.solve(cues, axes, zero, targets)[2], plain[2])   # the search off
        plain_err.append(_middle_error_mm(plain, truth))
        published_err.append(_middle_error_mm(solver.solve(cues, axes, zero, targets), truth))
        coarse_err.append(_middle_error_mm(coarse.solve(cues, axes, zero, targets), truth))
        # the search starts from the state's swivels: at the subject's, it stays there
        at_truth = solver.published_swivel(cues, axes, SWIVEL, targets)
        np.testing.assert_allclose(at_truth, SWIVEL, atol=np.radians(3.75) + 1e-9)
        assert solver.published_swivel(cues, axes, zero, None) is None       # nothing to see
    assert np.mean(coarse_err) < 0.5 * np.mean(plain_err), (plain_err, coarse_err)          # 182 -> 68 mm
    assert np.mean(published_err) < 0.6 * np.mean(coarse_err), (coarse_err, published_err)  # the halvings: 26 mm


def test_the_published_elbows_are_searched_all_round(frames):
    """The state holding the elbows turned 120 or 180 deg from the subject's, beyond the reach of
    a search around it (60 deg and the halvings): the published elbows' search all round
    (``FitConfig.published_arm_search_deg``) finds the subject's on the silhouettes; the knees'
    swivels come out as without it."""
    config = FusionConfig(fit=FitConfig(refine_trunk=False, published_pelvis_twist_deg=0.0))
    solver = PoseSolver(LENGTHS, config)
    near = PoseSolver(LENGTHS, replace(config, fit=replace(config.fit, published_arm_search_deg=60.0)))
    elbows = [J["elbow_l"], J["elbow_r"]]
    for turn in (120.0, 180.0):
        err_near, err_round = [], []
        for cues, axes, targets, truth in frames:
            state = SWIVEL + np.radians([turn, -turn, 0.0, 0.0])
            for s, errs in ((near, err_near), (solver, err_round)):
                errs.append(1000 * np.linalg.norm(s.solve(cues, axes, state, targets)[2][elbows] - truth[elbows],
                                                  axis=1).mean())
            np.testing.assert_array_equal(solver.published_swivel(cues, axes, state, targets)[2:],
                                          near.published_swivel(cues, axes, state, targets)[2:])
        assert np.mean(err_near) > 50.0 and np.mean(err_round) < 10.0, (turn, err_near, err_round)   # 65-285 -> 0-5 mm


def test_the_plain_pose_given_is_the_one_returned_when_nothing_refines_it(frames):
    """``solve(..., plain=...)``: without views neither refinement runs and the given plain pose
    comes back as it is (the tracker passes its state's pose, solved once)."""
    solver = PoseSolver(LENGTHS, FusionConfig())
    cues, axes, _, _ = frames[0]
    plain = solver.plain(cues, axes, np.zeros(4), None)
    assert solver.solve(cues, axes, np.zeros(4), None, plain=plain) is plain


def test_the_published_pelvis_turns_to_the_knees_and_the_rest_of_the_body_stays(frames):
    """The published pose's last step (``twisted``, ``body.pelvis``) on rendered frames whose knees
    the swivels turned: it turns the pelvis only where the knees' hinges point away from it, and
    keeps the trunk above, the arms, the head, the ankles and the feet where the pose had them."""
    on = PoseSolver(LENGTHS, FusionConfig())
    off = PoseSolver(LENGTHS, FusionConfig(fit=FitConfig(published_pelvis_twist_deg=0.0)))
    kept = [J[n] for n in ("torso", "neck", "head", "shoulder_l", "elbow_l", "hand_l", "shoulder_r", "elbow_r",
                           "hand_r", "ankle_l", "foot_l", "ankle_r", "foot_r")]
    moved = 0
    for cues, axes, targets, _ in frames:
        a, b = on.solve(cues, axes, SWIVEL, targets), off.solve(cues, axes, SWIVEL, targets)
        np.testing.assert_allclose(a[2][kept], b[2][kept], atol=1e-6)
        np.testing.assert_array_equal(a[0], b[0])
        moved += not np.allclose(a[2][[J["hip_l"], J["hip_r"]]], b[2][[J["hip_l"], J["hip_r"]]], atol=1e-4)
    assert moved >= 3       # the knees turned by the swivels turn the pelvis on most frames
