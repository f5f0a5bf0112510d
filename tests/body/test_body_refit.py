"""B.4 refit and the two-view annotations pipeline (B.2-B.4 + CCD) on a synthetic pose."""

import json

import numpy as np
import pytest

from mocap_rt.body.annotations import pose_from_annotations, read_annotations
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.refit import SEGMENTS, pose_from_refit, refit_skeleton
from mocap_rt.body.skeleton import END_EFFECTORS, J, BoneLengths, body_model, write_bone_lengths
from mocap_rt.cli import main as cli_main
from mocap_rt.geometry.rig import ring_rig, write_rig


def sim_joints(seed=0):
    """A natural-ish pose of the full model: (model, joints (J, 3))."""
    rng = np.random.default_rng(seed)
    L = BoneLengths(thigh_m=0.45, forearm_m=0.25)
    m = body_model(L)
    a = np.zeros((20, 3))
    for s, sx in (("l", -1), ("r", 1)):
        a[J[f"shoulder_{s}"]] = [rng.uniform(0.2, 1.0), sx * rng.uniform(0.2, 0.6), 0.2 * sx]
        a[J[f"elbow_{s}"], 0] = rng.uniform(0.4, 1.2)
        a[J[f"hip_{s}"]] = [rng.uniform(0.0, 0.6), sx * rng.uniform(0.0, 0.2), 0.0]
        a[J[f"knee_{s}"], 0] = -rng.uniform(0.3, 0.9)
    a[0] = [0.05, -0.05, 0.3]
    return m, L, forward_kinematics(m, np.array([0.1, 0.0, 1.0]), a)[0]


def test_refit_with_exact_measurements_reproduces_the_skeleton():
    m, L, P = sim_joints()
    eff = {n: P[J[n]] for n in END_EFFECTORS}
    dirs = {(a, b): (P[J[b]] - P[J[a]]) / np.linalg.norm(P[J[b]] - P[J[a]]) for a, b in SEGMENTS}
    R = refit_skeleton(eff, dirs, L)
    # the model's shoulders are symmetric about the neck and the hips about the pelvis,
    # exactly the constraints of the refit: the refit is exact
    np.testing.assert_allclose(R, P, atol=1e-9)


def test_refit_restores_bone_lengths_from_noisy_measurements():
    m, L, P = sim_joints(1)
    rng = np.random.default_rng(3)
    eff = {n: P[J[n]] + rng.normal(0, 0.02, 3) for n in END_EFFECTORS}
    dirs = {}
    for a, b in SEGMENTS:
        d = P[J[b]] - P[J[a]] + rng.normal(0, 0.02, 3)
        dirs[(a, b)] = d / np.linalg.norm(d)
    R = refit_skeleton(eff, dirs, L)
    for a, b, want in (("knee_l", "hip_l", L.thigh_m), ("hip_l", "hip_r", 2 * L.hip_half_width_m),
                       ("elbow_r", "wrist_r", L.forearm_m), ("neck", "head", L.neck_head_m)):
        assert np.linalg.norm(R[J[a]] - R[J[b]]) == pytest.approx(want, rel=1e-9)
    sl, sr, neck = R[J["shoulder_l"]], R[J["shoulder_r"]], R[J["neck"]]
    assert np.linalg.norm(sl - neck) == pytest.approx(np.linalg.norm(sr - neck))     # symmetric
    spine = R[J["neck"]] - R[J["pelvis"]]
    assert abs(spine @ (sr - sl)) < 1e-9                                              # perpendicular
    assert np.abs(R - P).max() < 0.15


def test_arms_raised_sideways_keep_their_pose():
    """Arms abducted above the shoulder (100-170 deg) have, read back from their frames,
    an X-Y-Z name with X and Z near 180 deg, outside the limits; the refit's start takes
    the other name of the same rotation, so clamping does not fold the arms down and the
    CCD starts at the truth."""
    rng = np.random.default_rng(4)
    L = BoneLengths()
    m = body_model(L)
    for _ in range(5):
        a = np.zeros((20, 3))
        for s, sx in (("l", -1), ("r", 1)):
            a[J[f"shoulder_{s}"]] = np.radians([rng.uniform(-10, 10), sx * rng.uniform(100, 170),
                                                sx * rng.uniform(-20, 20)])
            a[J[f"elbow_{s}"], 0] = rng.uniform(0.1, 0.8)
        a[0] = [0.0, 0.0, rng.uniform(-np.pi, np.pi)]
        P = forward_kinematics(m, np.array([0.0, 0.0, 1.0]), a)[0]
        root, res = pose_from_refit(m, P, {n: P[J[n]] for n in END_EFFECTORS})
        got = forward_kinematics(m, root, res.angles)[0]
        assert np.abs(got - P).max() < 0.01


def write_annotations(tmp_path, P, L, noise_px=0.0, seed=0):
    rig = ring_rig().subset(["cam_1", "cam_2"])
    write_rig(rig, tmp_path / "rig.toml")
    write_bone_lengths(L, tmp_path / "bones.toml")
    rng = np.random.default_rng(seed)

    def px(cam, X):
        return (cam.project(np.atleast_2d(X))[0][0] + rng.normal(0, noise_px, 2)).tolist()

    doc = {"rig": "rig.toml", "cameras": ["cam_1", "cam_2"], "bones": "bones.toml",
           "points": {n: {c.name: px(c, P[J[n]]) for c in rig.cameras} for n in END_EFFECTORS},
           "segments": {}}
    for a, b in SEGMENTS:
        pa, pb = P[J[a]], P[J[b]]
        # two points on the segment, different in each view (only the line matters)
        doc["segments"][f"{a}-{b}"] = {c.name: [px(c, pa + f1 * (pb - pa)), px(c, pa + f2 * (pb - pa))]
                                       for c, (f1, f2) in zip(rig.cameras, ((0.2, 0.8), (0.1, 0.6)))}
    path = tmp_path / "ann.json"
    path.write_text(json.dumps(doc))
    return path


def test_two_view_pipeline_recovers_the_pose(tmp_path):
    m, L, P = sim_joints(2)
    res = pose_from_annotations(read_annotations(write_annotations(tmp_path, P, L)))
    for n in END_EFFECTORS:
        np.testing.assert_allclose(res.effectors[n], P[J[n]], atol=1e-6)
    np.testing.assert_allclose(res.refit_joints, P, atol=1e-6)
    assert res.ik.position_error_m.max() < 1e-3
    assert np.abs(res.joints - P).max() < 0.01


def test_cli_pose_from_annotations_and_errors(tmp_path, capsys):
    m, L, P = sim_joints(3)
    path = write_annotations(tmp_path, P, L, noise_px=0.5)
    rc = cli_main(["pose-from-annotations", str(path), "--out", str(tmp_path / "o")])
    assert rc == 0
    with np.load(tmp_path / "o" / "pose.npz") as z:
        assert np.abs(z["joints"][0] - P).max() < 0.08
    assert (tmp_path / "o" / "pose.bvh").exists()
    assert "end effector" in capsys.readouterr().out
    doc = json.loads(path.read_text())
    del doc["segments"]["knee_l-hip_l"]
    path.write_text(json.dumps(doc))
    rc = cli_main(["pose-from-annotations", str(path), "--out", str(tmp_path / "o2")])
    assert rc == 2 and "knee_l-hip_l" in capsys.readouterr().err
