"""Motion-suite metrics (fusion/evaluate.py) on hand-computed cases."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap_rt.fusion.evaluate import (anatomical_angles, angle_rmse_deg, heading_deg, mirrored_frames,
                                      procrustes_errors, suite_metrics, wrap_deg)
from mocap_rt.names import CUE_JOINT_INDEX, JOINT_NAMES

J = {n: i for i, n in enumerate(JOINT_NAMES)}


def standing() -> np.ndarray:
    """(1, 20, 3) a body facing +X (left = +Y), arms and legs straight down, metres."""
    P = np.zeros((20, 3))
    P[J["pelvis"]] = (0, 0, 1.0)
    P[J["torso"]] = (0, 0, 1.25)
    P[J["neck"]] = (0, 0, 1.5)
    P[J["head"]] = (0, 0, 1.7)
    for s, y in (("l", 1.0), ("r", -1.0)):
        P[J[f"shoulder_{s}"]] = (0, 0.2 * y, 1.5)
        P[J[f"elbow_{s}"]] = (0, 0.2 * y, 1.2)
        P[J[f"wrist_{s}"]] = (0, 0.2 * y, 0.95)
        P[J[f"hand_{s}"]] = (0, 0.2 * y, 0.87)
        P[J[f"hip_{s}"]] = (0, 0.1 * y, 1.0)
        P[J[f"knee_{s}"]] = (0, 0.1 * y, 0.55)
        P[J[f"ankle_{s}"]] = (0, 0.1 * y, 0.1)
        P[J[f"foot_{s}"]] = (0.08, 0.1 * y, 0.05)
    return P[None]


def test_anatomical_angles_of_a_hand_made_pose():
    P = standing()
    a = anatomical_angles(P)
    for n in a:
        assert a[n][0] == pytest.approx(0.0, abs=1e-9), n
    # left thigh forward horizontal (hip flexion 90), shank straight down (knee flexion 90);
    # right upper arm out sideways (abduction 90), forearm forward (elbow flexion 90)
    P[0, J["knee_l"]] = (0.45, 0.1, 1.0)
    P[0, J["ankle_l"]] = (0.45, 0.1, 0.55)
    P[0, J["elbow_r"]] = (0, -0.5, 1.5)
    P[0, J["wrist_r"]] = (0.25, -0.5, 1.5)
    a = anatomical_angles(P)
    assert a["hip_flex_l"][0] == pytest.approx(90) and a["knee_flex_l"][0] == pytest.approx(90)
    assert a["hip_abd_l"][0] == pytest.approx(0, abs=1e-9)
    assert a["shoulder_abd_r"][0] == pytest.approx(90) and a["elbow_flex_r"][0] == pytest.approx(90)
    # the left hip abducted 30 deg: knee out to +Y
    P = standing()
    P[0, J["knee_l"]] = P[0, J["hip_l"]] + 0.45 * np.array([0, np.sin(np.radians(30)), -np.cos(np.radians(30))])
    assert anatomical_angles(P)["hip_abd_l"][0] == pytest.approx(30)


def test_procrustes_removes_similarity_but_not_reflection():
    rng = np.random.default_rng(0)
    T = rng.normal(size=(4, 20, 3))
    R = Rotation.from_rotvec([0.3, -1.0, 0.5]).as_matrix()
    E = 1.7 * T @ R.T + [0.5, -2, 3]
    np.testing.assert_allclose(procrustes_errors(E, T), 0.0, atol=1e-12)
    M = T * [-1.0, 1.0, 1.0]                          # a mirror image is not a rotation
    assert (procrustes_errors(M, T) > 0.1).all()
    # one joint off by 20 cm in a frame with 4 joints only (others NaN): hand-computed
    X = np.full((1, 20, 3), np.nan)
    X[0, :4] = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    Y = X.copy()
    Y[0, :4] += [0.5, 0.5, 0.5]                       # a translation: removed
    assert procrustes_errors(X, Y)[0] == pytest.approx(0.0, abs=1e-12)
    X[0, 1, 2] = np.nan                               # 3 joints left: still defined
    assert np.isfinite(procrustes_errors(X, Y)[0])
    X[0, 2] = np.nan
    assert np.isnan(procrustes_errors(X, Y)[0])


def test_mirrored_frames_counts_swapped_pairs_beyond_the_margin():
    T = np.repeat(standing(), 4, axis=0)
    E = T.copy()
    E[1, [J["hand_l"], J["hand_r"]]] = E[1, [J["hand_r"], J["hand_l"]]]        # hands swapped: 40 cm apart
    E[2, [J["foot_l"], J["foot_r"]]] = E[2, [J["foot_r"], J["foot_l"]]]        # feet swapped
    E[3, J["hand_l"], 0] = np.nan                                              # judged on the feet
    np.testing.assert_array_equal(mirrored_frames(E, T), [0.0, 1.0, 1.0, 0.0])
    E[3, J["foot_r"], 2] = np.nan
    assert np.isnan(mirrored_frames(E, T)[3])
    # hands together (clap): swapping labels 2 cm apart is not a mirror
    T2 = standing()
    T2[0, J["hand_l"]] = (0.3, 0.01, 1.2)
    T2[0, J["hand_r"]] = (0.3, -0.01, 1.2)
    E2 = T2.copy()
    E2[0, [J["hand_l"], J["hand_r"]]] = E2[0, [J["hand_r"], J["hand_l"]]]
    assert mirrored_frames(E2, T2)[0] == 0.0


def test_heading_of_a_turned_and_of_a_mirrored_body():
    T = standing()
    assert heading_deg(T)[0] == pytest.approx(0.0)
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    assert heading_deg(T @ R.T)[0] == pytest.approx(30.0)
    Mi = T.copy()                                      # hips labelled the wrong way round: faces back
    Mi[0, [J["hip_l"], J["hip_r"]]] = Mi[0, [J["hip_r"], J["hip_l"]]]
    assert abs(wrap_deg(heading_deg(Mi) - heading_deg(T))[0]) == pytest.approx(180.0)
    np.testing.assert_allclose(wrap_deg(np.array([190.0, -190.0, 45.0])), [-170.0, 170.0, 45.0])


def test_angle_rmse_and_suite_metrics_hand_computed():
    T = np.repeat(standing(), 2, axis=0)
    E = T.copy()
    # knees: left 10 deg bent in frame 0, right 20 deg in frame 1 -> RMSE sqrt((100+400)/4)
    for f, s, deg in ((0, "l", 10.0), (1, "r", 20.0)):
        k, a = E[f, J[f"knee_{s}"]], E[f, J[f"ankle_{s}"]]
        E[f, J[f"ankle_{s}"]] = k + 0.45 * np.array([-np.sin(np.radians(deg)), 0, -np.cos(np.radians(deg))])
        assert np.linalg.norm(a - k) == pytest.approx(0.45)
    r = angle_rmse_deg(E, T)
    assert r["knees"] == pytest.approx(np.sqrt((100 + 400) / 4)) and r["elbows"] == pytest.approx(0.0, abs=1e-6)
    # whole-clip figures: a 1 cm offset of every estimated joint and cue
    truth = {"frames": np.array([5, 6]), "joints": T, "cues": T[:, list(CUE_JOINT_INDEX)],
             "joint_names": np.array(JOINT_NAMES)}
    Es = T + [0.01, 0, 0]
    m = suite_metrics(truth, np.array([5, 6]), Es[:, list(CUE_JOINT_INDEX)], Es, np.array([1.0, 3.0]))
    assert m["mpjpe_mm"] == pytest.approx(10.0) and m["pa_mpjpe_mm"] == pytest.approx(0.0, abs=1e-9)
    assert m["mirrored_pct"] == 0.0 and m["heading_p95_deg"] == pytest.approx(0.0, abs=1e-9)
    assert m["cue_hand_l_p95_mm"] == pytest.approx(10.0) and m["knee_mm"] == pytest.approx(10.0)
    assert m["fusion_ms_med"] == 2.0 and m["fusion_ms_p99"] == pytest.approx(2.98)
    # the figure as shown: a hand not estimated (NaN in the scored joints) but drawn 0.31 m off
    # counts there, once, among the 2 x 20 joints: (39 * 10 + 310) / 40 mm
    Ej = Es.copy()
    Ej[0, J["hand_r"]] = np.nan
    shown = Es.copy()
    shown[0, J["hand_r"]] = T[0, J["hand_r"]] + [0, 0.31, 0]
    m = suite_metrics(truth, np.array([5, 6]), Es[:, list(CUE_JOINT_INDEX)], Ej, None, shown)
    assert m["mpjpe_mm"] == pytest.approx(10.0)
    assert m["mpjpe_shown_mm"] == pytest.approx((39 * 10 + 310) / 40)
    assert "mpjpe_shown_mm" not in suite_metrics(truth, np.array([5, 6]), Es[:, list(CUE_JOINT_INDEX)], Ej)
