"""The elbow's pole of a raised arm (``limb_geometry._arm_pole``, issue 10): against forward
kinematics of known angles within the joint limits, and a brute-force search."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap_rt.body.analytic import AnalyticConfig, analytic_pose
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.limb_geometry import joint_violation
from mocap_rt.body.skeleton import J, body_model
from mocap_rt.names import CUE_JOINT_INDEX

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
