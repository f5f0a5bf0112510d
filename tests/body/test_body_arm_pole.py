"""The elbow's pole of a raised arm (``limb_geometry._arm_pole``, issue 10): against forward
kinematics of known angles within the joint limits, and a brute-force search."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap_rt.body import silhouette as S
from mocap_rt.body.analytic import AnalyticConfig, analytic_pose
from mocap_rt.body.estimate import bone_lengths_from_joints
from mocap_rt.body.fit import BodyFitter, FitConfig
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.limb_geometry import _arm_pole, _elbow_cost, _pole_circle, _pole_costs, _rot_about, \
    joint_violation
from mocap_rt.body.skeleton import J, body_model
from mocap_rt.names import C_HEAD, C_TORSO, CUE_JOINT_INDEX
from mocap_rt.studio.body_map import POINT_NAMES

FIXED = AnalyticConfig(elbow_pole_candidates=0)
SEARCH = AnalyticConfig()


def shoulder_names_deg(model, angles, side):
    """The shoulder's limits (lo, hi) and its rotation's two X-Y-Z names, scipy's (|Y| <= 90
    deg) and (X + 180, 180 - Y, Z + 180), degrees."""
    j = J[f"shoulder_{side}"]
    lo, hi = np.degrees(model.limits[j, :, 0]), np.degrees(model.limits[j, :, 1])
    a = Rotation.from_euler("XYZ", angles[j]).as_euler("XYZ", degrees=True)
    wrap = lambda v: (v + 180.0) % 360.0 - 180.0  # noqa: E731
    return lo, hi, a, np.array([wrap(a[0] + 180), wrap(180 - a[1]), wrap(a[2] + 180)])


def shoulder_violation_deg(model, angles, side):
    """Degrees the shoulder's rotation lies outside its limits, judged on both X-Y-Z names of
    the rotation (scipy's, |Y| <= 90 deg, and (X + 180, 180 - Y, Z + 180))."""
    lo, hi, a, b = shoulder_names_deg(model, angles, side)
    return min(float(np.sum(np.maximum(0, lo - x) + np.maximum(0, x - hi))) for x in (a, b))


def shoulder_swing_twist_deg(model, angles, side):
    """Degrees the shoulder's rotation lies outside its limits judged as swing and twist (the
    fit's measure, ``limb_geometry._swing_twist_violation``), with scipy: where the bone
    points, on the X and Y limits (of scipy's |Y| <= 90 deg name below the horizontal, the
    better of it and (X + 180, 180 - Y, Z + 180) above); the rotation about the bone left
    after the minimal swing of the rest frame (Z down) onto it, on the Z limits, with a
    weight falling from 1 at 135 deg of elevation to 0 straight up."""
    lo, hi, a, b = shoulder_names_deg(model, angles, side)
    R = Rotation.from_euler("XYZ", angles[J[f"shoulder_{side}"]])
    excess = lambda v, k: max(0.0, lo[k] - v) + max(0.0, v - hi[k])  # noqa: E731
    d = R.apply([0.0, 0.0, 1.0])
    swing = excess(a[0], 0) + excess(a[1], 1)
    if d[2] < 0:
        swing = min(swing, excess(b[0], 0) + excess(b[1], 1))
    w = min(1.0, (180.0 - np.degrees(np.arccos(np.clip(d[2], -1, 1)))) / 45.0)
    if w <= 0:
        return swing
    axis = np.cross([0.0, 0.0, 1.0], d)
    n = np.linalg.norm(axis)
    S = Rotation.from_rotvec(axis / n * np.arccos(np.clip(d[2], -1, 1))) if n > 1e-12 else Rotation.identity()
    twist = np.degrees((R * S.inv()).as_rotvec() @ d)
    return swing + w * excess(twist, 2)


def arm_poses(rng, kind, n):
    """(n, J, 3) poses of the paper model, both arms alike (mirrored), shoulder twist within
    +-15 deg of neutral: ``face`` = hands in front of the face, ``overhead``, ``hanging``."""
    out = np.zeros((n, 20, 3))
    for i in range(n):
        if kind == "face":
            flex, abd, elbow = rng.uniform(50, 100), rng.uniform(0, 40), rng.uniform(100, 145)
        elif kind == "overhead":
            flex, abd, elbow = rng.uniform(150, 178), rng.uniform(0, 30), rng.uniform(10, 70)
        else:
            flex, abd, elbow = rng.uniform(-20, 30), rng.uniform(0, 20), rng.uniform(0, 60)
        twist = rng.uniform(-15, 15)
        out[i, 0] = [0.0, 0.0, rng.uniform(-np.pi, np.pi)]
        for s, sx in (("l", -1.0), ("r", 1.0)):
            out[i, J[f"shoulder_{s}"]] = np.radians([flex, sx * abd, sx * twist])
            out[i, J[f"elbow_{s}"], 0] = np.radians(elbow)
    return out


def solve(model, a, config):
    P = forward_kinematics(model, np.array([0.0, 0.0, 1.0]), a)[0]
    axes = forward_kinematics(model, np.array([0.0, 0.0, 1.0]), a)[1][0]
    r, got = analytic_pose(model, P[list(CUE_JOINT_INDEX)], axes, config)
    P2 = forward_kinematics(model, r, got)[0]
    return P, P2, got


@pytest.mark.parametrize("kind", ["face", "overhead"])
def test_raised_arm_elbow_within_limits_and_near_the_truth(kind):
    model = body_model(preset="paper")
    rng = np.random.default_rng(21 if kind == "face" else 22)
    err_fixed, err_search, viol_fixed, viol_search = [], [], [], []
    for a in arm_poses(rng, kind, 40):
        for s in ("l", "r"):
            assert shoulder_violation_deg(model, a, s) == 0.0          # the truth is within the limits
        P, P_fixed, a_fixed = solve(model, a, FIXED)
        _, P_search, a_search = solve(model, a, SEARCH)
        np.testing.assert_allclose(P_search[list(CUE_JOINT_INDEX)], P[list(CUE_JOINT_INDEX)], atol=1e-9)
        for s in ("l", "r"):
            e = J[f"elbow_{s}"]
            err_fixed.append(np.linalg.norm(P_fixed[e] - P[e]))
            err_search.append(np.linalg.norm(P_search[e] - P[e]))
            viol_fixed.append(shoulder_violation_deg(model, a_fixed, s))
            viol_search.append(shoulder_violation_deg(model, a_search, s))
    err_fixed, err_search = np.array(err_fixed) * 1000, np.array(err_search) * 1000
    viol_fixed, viol_search = np.array(viol_fixed), np.array(viol_search)
    out = viol_fixed > 5.0                      # the arms the fixed pole puts out of range
    assert out.sum() >= (10 if kind == "face" else 4)   # overhead: mostly within range on its second name
    assert np.all(viol_search[out] < 1.0)       # ... are within range with the searched pole
    assert np.median(err_search[out]) < 60.0    # elbow within 6 cm (median) of the truth, mm
    assert np.median(err_search[out]) < 0.5 * np.median(err_fixed[out])
    inside = viol_fixed == 0.0
    assert np.all(err_search[inside] == err_fixed[inside])   # an arm within range keeps its elbow
    print(f"{kind}: {out.sum()} of {out.size} arms out of range with the fixed pole (median {np.median(viol_fixed[out]):.0f} "
          f"deg); elbow error median {np.median(err_fixed[out]):.0f} -> {np.median(err_search[out]):.0f} mm")


def test_hanging_arm_keeps_the_fixed_pole():
    model = body_model(preset="paper")
    for a in arm_poses(np.random.default_rng(23), "hanging", 30):
        _, _, a_fixed = solve(model, a, FIXED)
        _, _, a_search = solve(model, a, SEARCH)
        if all(shoulder_violation_deg(model, a_fixed, s) == 0.0 for s in ("l", "r")):
            np.testing.assert_array_equal(a_search, a_fixed)


def test_searched_pole_is_the_best_of_the_candidates():
    """The allocation-free search equals a brute force over the same candidate poles (each
    solved by ``analytic_pose`` with the swivel, scored with scipy's decompositions)."""
    model = body_model(preset="paper")
    rng = np.random.default_rng(24)
    n, twist_cost = SEARCH.elbow_pole_candidates, SEARCH.elbow_twist_cost
    checked = 0
    for kind in ("face", "overhead", "hanging"):
        for a in arm_poses(rng, kind, 10):
            P, R = forward_kinematics(model, np.array([0.0, 0.0, 1.0]), a)
            cues = P[list(CUE_JOINT_INDEX)]
            _, got = analytic_pose(model, cues, R[0], SEARCH)
            for slot, s in ((0, "l"), (1, "r")):
                costs, poses = [], []
                for k in range(n):
                    sw = np.zeros(4)
                    sw[slot] = 2 * np.pi * k / n
                    _, cand = analytic_pose(model, cues, R[0], FIXED, sw)
                    v = shoulder_violation_deg(model, cand, s)
                    z = Rotation.from_euler("XYZ", cand[J[f"shoulder_{s}"]]).as_euler("XYZ", degrees=True)[2]
                    costs.append(v + twist_cost * abs(z))
                    poses.append(cand)
                    if k == 0 and v < 1e-9:
                        break
                best = poses[int(np.argmin(costs))]
                np.testing.assert_allclose(got[J[f"shoulder_{s}"]], best[J[f"shoulder_{s}"]], atol=1e-6)
                checked += 1
    assert checked == 60


def test_the_fit_judges_a_shoulder_by_swing_and_twist():
    """``joint_violation``, the limit term of the fit's and the identity's cost, equals the
    scipy oracle on the shoulders: arms raised past the shoulder in any plane cost nothing
    (their |Y| <= 90 deg name has X and Z near 180 deg, which cost such an arm 200-230
    degrees when judged on that name alone), a hanging arm turned about itself by 180 deg
    (the elbow bending backwards, which the other name's box admits: ``shoulder_violation_deg``)
    costs its twist past the limit, and random rotations cost what the oracle says."""
    model = body_model(preset="paper")
    lo, hi = np.ascontiguousarray(model.limits[..., 0]), np.ascontiguousarray(model.limits[..., 1])
    rng = np.random.default_rng(25)
    for s, sx in (("l", -1.0), ("r", 1.0)):
        j = J[f"shoulder_{s}"]
        for i in range(300):
            if i < 40:     # raised sideways, forwards or in between, past the horizontal, little twist
                turn = Rotation.from_euler("Z", sx * rng.uniform(0, 90), degrees=True)  # about the rest bone
                R = turn.inv() * Rotation.from_euler("XYZ", [0, sx * rng.uniform(95, 178), 0], degrees=True) * turn
                R = R * Rotation.from_euler("Z", sx * rng.uniform(-15, 15), degrees=True)
            elif i < 60:   # hanging, turned about itself by 180 deg
                R = Rotation.from_euler("XYZ", [rng.uniform(-10, 0), sx * rng.uniform(0, 10), 180], degrees=True)
            else:
                R = Rotation.random(random_state=rng)
            a = np.zeros((20, 3))
            a[j] = R.as_euler("XYZ")              # the |Y| <= 90 deg name, as the fit reads it
            got = np.degrees(joint_violation(a, lo, hi, model.dof, j))
            assert got == pytest.approx(shoulder_swing_twist_deg(model, a, s), abs=1e-6)
            if i < 40:
                assert got == 0.0
            elif i < 60:
                assert got > 80.0 and shoulder_violation_deg(model, a, s) == 0.0


@pytest.fixture(scope="module")
def hands_on_head(tmp_path_factory):
    """Frames of the procedural hands on the head (seed 0) while the hands rest there (from
    2.6 s, 0.2 s), 6-camera ring at 320x240: (rig, truth dict, {frame: SilhouetteTargets})."""
    from mocap_rt.body.silhouette import SilhouetteTargets
    from mocap_rt.fusion.evaluate import truth_camera_cues
    from mocap_rt.io.recording import Recording
    from mocap_rt.studio.synth import make_rig, synthesize
    from mocap_rt.studio.variants import load_motion

    clip, name = load_motion("procedural:hands_on_head:0", None)
    out = tmp_path_factory.mktemp("hands_on_head") / "rec"
    synthesize(clip, out, rig=make_rig("ring", size=(320, 240)), fps=30.0, seconds=0.2, start_s=2.6, seed=3,
               motion_name=name)
    rec = Recording(out)
    truth, rig = rec.truth, rec.rig
    widths = {c.name: int(c.size[0]) for c in rig.cameras}
    rng = np.random.default_rng(0)
    targets = {f: SilhouetteTargets.from_cues(rig.cameras, truth_camera_cues(truth, list(rig.names), f, f, 0.0, rng,
                                                                              widths))
               for f in range(rec.n_frames)}
    rec.close()
    return rig, truth, targets



def _truth_axes(joints):
    """Body axes (3, 3) of truth joints (J, 3): up from the torso cue to the head, right from
    the hips and shoulders."""
    X = joints[list(CUE_JOINT_INDEX)]
    up = X[C_HEAD] - X[C_TORSO]
    up /= np.linalg.norm(up)
    right = joints[J["hip_r"]] - joints[J["hip_l"]] + joints[J["shoulder_r"]] - joints[J["shoulder_l"]]
    right -= up * (right @ up)
    right /= np.linalg.norm(right)
    return np.column_stack([right, np.cross(up, right), up])


def test_the_pose_is_the_one_the_fit_scored(hands_on_head):
    """Hands resting on the head, the truth's cues: the pose solved with the fit's axes,
    swivels and silhouettes (what the tracker publishes) has the silhouette cost the fit
    reported for it (its elbows chosen on the silhouettes alike), and its elbows differ from
    the fixed pole's."""
    rig, truth, targets = hands_on_head
    joints = truth["joints"]
    model = body_model(bone_lengths_from_joints(joints), "paper")
    cfg = AnalyticConfig()
    fitter = BodyFitter(model, cfg)
    A, B = np.empty((S.N_CAPSULES, 3)), np.empty((S.N_CAPSULES, 3))
    pts = np.empty((len(POINT_NAMES), 3))
    for f, T in targets.items():
        X = joints[f][list(CUE_JOINT_INDEX)]
        res = fitter.fit(X, _truth_axes(joints[f]), None, T)
        elbows = {}
        for name, views in (("measured", (T.args()[:5], 1e4)), ("fixed pole", ())):
            root, angles = analytic_pose(model, X, res.axes, cfg, res.swivel, *views)
            pos, rot = forward_kinematics(model, root, angles)
            elbows[name] = pos[[J["elbow_l"], J["elbow_r"]]]
            if name == "measured":
                S.pose_points(pos, rot, np.radians(model.lengths.foot_pitch_deg), pts)
                S.body_capsules(pts, A, B)
                sil = S.capsules_cost(A, B, S.CAPSULE_RADII_M, *T.args()) * 1e4
                np.testing.assert_allclose(sil, res.silhouette_cm2, rtol=1e-9)
        assert np.linalg.norm(elbows["measured"] - elbows["fixed pole"], axis=1).max() > 0.05


def test_the_elbow_on_the_silhouettes_chooses_what_scoring_every_candidate_does(hands_on_head):
    """``_arm_pole`` with the elbow measured passes over candidates that cannot win; against
    a brute force scoring all of them (random arms about the rendered body, random poles)."""
    rig, truth, targets = hands_on_head
    joints = truth["joints"][0]
    model = body_model(bone_lengths_from_joints(truth["joints"]), "paper")
    L1 = model.lengths.upper_arm_m
    L2 = model.lengths.forearm_m + model.lengths.hand_m
    cfg = AnalyticConfig()
    n, views, w = cfg.elbow_pole_candidates, targets[0].args()[:5], 1e4
    axes = _truth_axes(joints)
    rng = np.random.default_rng(7)
    pts = np.empty((3, 3))
    evaluated = 0
    for i in range(200):
        s = "lr"[i % 2]
        shoulder = joints[J[f"shoulder_{s}"]] + rng.normal(0.0, 0.02, 3)
        hand = shoulder + rng.normal(0.0, 1.0, 3) * [0.25, 0.25, 0.3]
        pole = rng.normal(size=3)
        pole /= np.linalg.norm(pole)
        lim = np.ascontiguousarray(model.limits[J[f"shoulder_{s}"]])
        got = _arm_pole(shoulder, hand, L1, L2, pole, axes, lim, n, cfg.elbow_twist_cost, views, w,
                        cfg.elbow_turn_cost)
        d, u, w0, v0, ca, sa = _pole_circle(shoulder, hand, L1, L2, pole)
        base = np.empty(n)
        _pole_costs(u, w0, v0, ca, sa, axes, lim, n, cfg.elbow_twist_cost, base, False)
        costs = [_elbow_cost(shoulder, hand, L1, u, w0, v0, ca, sa, k, n, views, w, cfg.elbow_turn_cost, base[k], pts)
                 for k in range(n)]
        np.testing.assert_array_equal(got, _rot_about(d, 2.0 * np.pi * int(np.argmin(costs)) / n, pole))
        evaluated += int(np.argmin(costs)) != 0
    assert evaluated > 20          # the choice is not always the given pole
