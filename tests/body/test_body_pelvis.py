"""The pelvis turned about the spine to the knees' hinges (``body.pelvis``), on hand-built poses."""

import numpy as np
import pytest

from mocap_rt.body.fit import FitConfig
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.pelvis import twist_pelvis
from mocap_rt.body.skeleton import BoneLengths, J, body_model

MODEL = body_model(BoneLengths(), "paper")
ROOT = np.array([0.3, -0.2, 0.95])
UPPER = [J[n] for n in ("torso", "neck", "head", "shoulder_l", "elbow_l", "wrist_l", "hand_l",
                        "shoulder_r", "elbow_r", "wrist_r", "hand_r")]
ENDS = [J[n] for n in ("ankle_l", "foot_l", "ankle_r", "foot_r")]
BONES = [(J[p], J[c]) for p, c in (("hip_l", "knee_l"), ("knee_l", "ankle_l"), ("hip_r", "knee_r"),
                                   ("knee_r", "ankle_r"), ("pelvis", "hip_l"), ("pelvis", "hip_r"))]


def pose(turn_deg: float, knee_deg: float = 60.0, yaw_deg: float = 30.0) -> np.ndarray:
    """A body facing ``yaw_deg``, arms raised a little, both thighs turned ``turn_deg`` about
    themselves (the knees' hinges turned so against the pelvis's right), knees bent ``knee_deg``."""
    a = np.zeros((len(MODEL.names), 3))
    a[J["pelvis"]] = [0.0, 0.0, np.radians(yaw_deg)]
    a[J["shoulder_l"]] = [0.4, -0.2, 0.1]
    a[J["elbow_l"], 0] = 0.7
    a[J["shoulder_r"]] = [-0.3, 0.1, 0.0]
    for s in ("l", "r"):
        a[J[f"hip_{s}"]] = [np.radians(20.0), 0.0, np.radians(turn_deg)]
        a[J[f"knee_{s}"], 0] = -np.radians(knee_deg)
    return a


def hinge_deg(P: np.ndarray, R: np.ndarray, s: str) -> float:
    """The angle of the knee's hinge, (hip -> knee) x (knee -> ankle), from the pelvis's right in
    its transverse plane, folded into [-90, 90)."""
    h, k, a = P[J[f"hip_{s}"]], P[J[f"knee_{s}"]], P[J[f"ankle_{s}"]]
    n = R[J["pelvis"]].T @ np.cross(k - h, a - k)
    return float((np.degrees(np.arctan2(n[1], n[0])) + 90.0) % 180.0 - 90.0)


@pytest.mark.parametrize("turn", [-30.0, -10.0, 15.0, 35.0])
def test_the_pelvis_turns_to_the_knees_hinges_and_nothing_else_moves(turn):
    a = pose(turn)
    P0, R0 = forward_kinematics(MODEL, ROOT, a)
    before = hinge_deg(P0, R0, "l")
    assert abs(before) == pytest.approx(abs(turn), rel=0.1)     # the hinges turned with the thighs (flexed 20 deg)
    out, applied = twist_pelvis(MODEL, ROOT, a, prior=0.0, max_deg=45.0)
    P1, R1 = forward_kinematics(MODEL, ROOT, out)
    assert applied == pytest.approx(before, abs=0.5)
    for s in ("l", "r"):   # the pelvis now faces where the knees bend (to what the moved hips change: one pass)
        assert abs(hinge_deg(P1, R1, s)) < 0.1 * abs(turn)
    np.testing.assert_allclose(P1[UPPER], P0[UPPER], atol=1e-9)        # the trunk above, arms and head stay
    np.testing.assert_allclose(R1[UPPER], R0[UPPER], atol=1e-9)
    np.testing.assert_allclose(P1[ENDS], P0[ENDS], atol=1e-6)          # the ankles and feet stay
    np.testing.assert_allclose(R1[ENDS], R0[ENDS], atol=1e-6)
    for p, c in BONES:                                                  # a rigid body
        assert np.linalg.norm(P1[c] - P1[p]) == pytest.approx(np.linalg.norm(P0[c] - P0[p]), abs=1e-9)
    # the pelvis turned about its own long axis: its up is unchanged
    np.testing.assert_allclose(R1[J["pelvis"]][:, 2], R0[J["pelvis"]][:, 2], atol=1e-9)


def test_straight_legs_say_nothing():
    a = pose(30.0, knee_deg=0.0)
    out, applied = twist_pelvis(MODEL, ROOT, a, prior=0.3, max_deg=45.0)
    assert applied == 0.0
    np.testing.assert_array_equal(out, a)


def test_the_prior_and_the_limit_hold_the_turn_back():
    a = pose(40.0, knee_deg=30.0)                  # each hinge weighs sin(30 deg) = 0.5
    _, free = twist_pelvis(MODEL, ROOT, a, prior=0.0, max_deg=90.0)
    _, held = twist_pelvis(MODEL, ROOT, a, prior=1.0, max_deg=90.0)
    assert held == pytest.approx(free * 1.0 / (1.0 + 1.0), abs=1.0)     # two legs of 0.5 against 1
    _, capped = twist_pelvis(MODEL, ROOT, a, prior=0.0, max_deg=20.0)
    assert abs(capped) == pytest.approx(20.0)


def test_one_bent_knee_turns_the_pelvis_less_than_two():
    a = pose(30.0)
    a[J["knee_r"], 0] = 0.0                        # the right leg straight: its hinge undefined
    _, one = twist_pelvis(MODEL, ROOT, a, prior=0.3, max_deg=45.0)
    _, two = twist_pelvis(MODEL, ROOT, pose(30.0), prior=0.3, max_deg=45.0)
    assert 0.0 < abs(one) < abs(two)


@pytest.mark.parametrize("field, value", [("published_pelvis_twist_deg", -1.0), ("published_pelvis_twist_deg", 120.0),
                                          ("pelvis_twist_prior", -0.1), ("pelvis_twist_prior", float("nan"))])
def test_a_turn_or_prior_out_of_range_is_refused_by_name(field, value):
    with pytest.raises(ValueError, match=f"FitConfig.{field}"):
        FitConfig(**{field: value})
