"""`mocap-rt process` on a short studio recording rendered here (slow: rendering)."""

import bvh
import numpy as np
import pytest

from mocap_rt.cli import main as cli_main
from mocap_rt.fusion.offline import process_recording
from mocap_rt.names import JOINT_NAMES


@pytest.fixture(scope="module")
def recording(data_dir, tmp_path_factory):
    from mocap_rt.studio.synth import synthesize

    out = tmp_path_factory.mktemp("rec") / "walk"
    synthesize(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh", out, seconds=0.5, truth_masks=False)
    return out


@pytest.mark.slow
def test_process_truth_2d_writes_bvh_and_npz_and_is_accurate(recording, tmp_path):
    out = process_recording(recording, tmp_path, truth_2d=True, noise_px=0.5, progress=False)
    from mocap_rt.body.skeleton import read_bone_lengths
    assert read_bone_lengths(tmp_path / "bones.toml").thigh_m > 0.2
    with np.load(tmp_path / "poses.npz") as z:
        assert list(z["joint_names"]) == list(JOINT_NAMES)
        n = len(z["frames"])
        assert z["joints"].shape == (n, 20, 3) and z["cues"].shape == (n, 6, 3)
    text = (tmp_path / "poses.bvh").read_text()
    mocap = bvh.Bvh(text)
    assert mocap.nframes == n and mocap.get_joints_names() == list(JOINT_NAMES)
    # the BVH is the npz's poses (smoothed: fusion.smooth), joint for joint
    from mocap_rt.body.bvh_export import WORLD_TO_BVH
    from mocap_rt.io.bvh import forward_kinematics, read_bvh
    clip = read_bvh(tmp_path / "poses.bvh")
    with np.load(tmp_path / "poses.npz") as z:
        posed = np.isfinite(z["joints"]).all(axis=(1, 2))
        assert posed.sum() > n // 2
        np.testing.assert_allclose(forward_kinematics(clip.skeleton, clip.motion)[posed],
                                   z["joints"][posed] @ WORLD_TO_BVH.T, atol=1e-4)
    # the joints as markers: C3D (Z up) and TRC (Y up), millimetres in the files, same poses
    from mocap_rt.markers.io import read_c3d, read_trc
    c3d, trc = read_c3d(tmp_path / "poses.c3d"), read_trc(tmp_path / "poses.trc")
    assert c3d.labels == trc.labels == tuple(JOINT_NAMES) and c3d.rate_hz == trc.rate_hz == 30.0
    with np.load(tmp_path / "poses.npz") as z:
        rows = z["frames"] - z["frames"][0]
        np.testing.assert_allclose(c3d.positions[rows], z["joints"], atol=1e-6)
        np.testing.assert_allclose(trc.positions[rows][..., 1], z["joints"][..., 2], atol=1e-8)
    acc = out.accuracy
    assert acc.cue_median_mm < 10 and acc.cue_p95_mm < 30
    assert acc.mpjpe_mm < 80  # bone lengths estimated from only 0.5 s of cues
    # the 2D cues fusion was given (C, F, 6, 2) and the per-frame fusion times
    from mocap_rt.io.recording import Recording
    with Recording(recording) as rec:
        t2d, vis = np.asarray(rec.truth["cues_2d"]), np.asarray(rec.truth["cue_visibility"]) >= 0.5
    assert out.camera_xy.shape == (6, n, 6, 2) and out.fusion_ms.shape == (n,) and (out.fusion_ms > 0).all()
    err = np.linalg.norm(out.camera_xy - t2d[:, :n], axis=-1)
    assert np.isnan(err[~vis[:, :n]]).all() and np.median(err[vis[:, :n]]) < 1.0


@pytest.mark.slow
def test_process_cli_with_perception(recording, tmp_path, capsys):
    rc = cli_main(["process", str(recording), "--out", str(tmp_path / "o"), "--no-progress", "--max-frames", "8"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "poses.bvh" in printed and "cue 3D error" in printed
    with np.load(tmp_path / "o" / "poses.npz") as z:
        assert len(z["frames"]) == 8
        # perception finds at least the head and the torso in most frames
        assert np.isfinite(z["cues"][:, [0, 5]]).all(axis=-1).mean() > 0.5


def test_process_rejects_a_missing_directory(tmp_path, capsys):
    rc = cli_main(["process", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
    assert rc == 2 and "nope" in capsys.readouterr().err


def test_process_config_file_reaches_fusion_and_perception(tmp_path, monkeypatch, capsys):
    """--config's [fusion] and [perception] tables are what process_recording gets; flags override."""
    from types import SimpleNamespace

    import mocap_rt.fusion.offline as offline

    got = {}

    def fake(rec, out, config, perception_config, **kw):
        got.update(config=config, perception=perception_config)
        return SimpleNamespace(frames=np.zeros(0), timings_ms={}, accuracy=None)

    monkeypatch.setattr(offline, "process_recording", fake)
    (tmp_path / "rec").mkdir()
    cfg = tmp_path / "c.toml"
    cfg.write_text("[fusion]\nviews = 'pair'\nik = 'ccd'\n[fusion.filter]\ngate_m = 0.2\n"
                   "[perception]\nroi_margin_px = 9\n")
    argv = ["process", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--config", str(cfg)]
    assert cli_main([*argv, "--ik", "analytic"]) == 0
    assert (got["config"].views, got["config"].ik, got["config"].filter.gate_m) == ("pair", "analytic", 0.2)
    assert got["perception"].roi_margin_px == 9
    assert got["config"].offline_smooth_hz == 4.0
    assert cli_main([*argv[:4], "--overwrite", "--smooth-hz", "0"]) == 0    # no --config: the defaults
    assert (got["config"].views, got["config"].ik, got["perception"]) == ("all", "analytic", None)
    assert got["config"].offline_smooth_hz == 0.0


@pytest.mark.slow
def test_a_smoothing_cutoff_above_half_the_frame_rate_is_refused_before_any_work(recording, tmp_path):
    from mocap_rt.fusion.config import FusionConfig

    with pytest.raises(ValueError, match=r"offline_smooth_hz.*15 Hz"):
        process_recording(recording, tmp_path, FusionConfig(offline_smooth_hz=15.0), progress=False)
    assert not any(tmp_path.iterdir())


def test_tracked_apart_counts_back_to_the_last_frame_tracking_could_have_exchanged_a_pair():
    """Six frames, the last one switching; counted back from it: both pairs measured and
    >= PAIR_APART_M apart in the 3 frames before, then the hands 0.1 m apart and a foot
    unmeasured (3 for each alternative). With the feet 5 cm apart in the frame just before the
    last: the feet 1, the mirror (both pairs) 1, the hands still 3."""
    from mocap_rt.fusion.identity import ALTERNATIVE_PAIRS, ALTERNATIVES
    from mocap_rt.fusion.offline import PAIR_APART_M, _tracked_apart
    from mocap_rt.fusion.result import FusionResult
    from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HAND_L, C_HAND_R

    def frame(hands_m: float, feet_m: float, foot_seen: bool = True) -> FusionResult:
        X = np.zeros((6, 3))
        X[C_HAND_R, 0], X[C_FOOT_R, 0] = hands_m, feet_m
        valid = np.ones(6, bool)
        valid[C_FOOT_R] = foot_seen
        return FusionResult(0, X, valid, np.zeros((20, 3)), np.zeros(1), (), {})

    apart = PAIR_APART_M + 0.01
    results = [frame(apart, apart), frame(0.1, apart, foot_seen=False), frame(apart, apart), frame(apart, apart),
               frame(apart, apart), frame(apart, apart)]       # the last: the switching frame
    span = {a: _tracked_apart(results, ALTERNATIVE_PAIRS[ALTERNATIVES.index(a)], len(results) - 1)
            for a in ALTERNATIVES}
    assert span == {"hands": 3, "feet": 3, "mirror": 3}
    results[3] = frame(apart, 0.05)
    span = {a: _tracked_apart(results, ALTERNATIVE_PAIRS[ALTERNATIVES.index(a)], len(results) - 1)
            for a in ALTERNATIVES}
    assert span == {"hands": 3, "feet": 1, "mirror": 1}


def test_a_mirror_that_follows_a_mirror_reaches_back_as_far():
    """``_relabel_back`` with a stand-in tracker that records which frames it relabels: a mirror
    after the acquisition reaches back over the frames it won; a second mirror (the labels
    back where they were before the first) over the first one's frames as well, so that those
    return to their labels; a feet switch in between breaks the chain."""
    from mocap_rt.fusion.identity import ALTERNATIVES, IdentityState
    from mocap_rt.fusion.offline import _relabel_back
    from mocap_rt.fusion.result import FusionResult

    mirror, feet = ALTERNATIVES.index("mirror"), ALTERNATIVES.index("feet")

    class Tracker:
        def __init__(self):
            self.identity = IdentityState(frames=100)
            self.relabelled: list[tuple[int, int]] = []

        def with_labels(self, r, k):
            self.relabelled.append((r.frame, k))
            return r

    def run(switch_plan):
        """switch_plan: {frame: (alternative, frames won)}; returns the relabelled (frame, k)."""
        t = Tracker()
        results, last = [], None
        for f in range(40):
            results.append(FusionResult(f, np.zeros((6, 3)), np.zeros(6, bool), np.zeros((20, 3)), np.zeros(1),
                                        (), {}))   # nothing measured: no tracked-apart span
            before = t.identity.switches
            if f in switch_plan:
                t.identity.last_switch = switch_plan[f]
                t.identity.switches += 1
            last = _relabel_back(t, results, before, last)
        return t.relabelled

    assert run({20: (mirror, 2), 30: (mirror, 3)}) == [(19, mirror)] + [(f, mirror) for f in range(19, 30)]
    assert run({20: (mirror, 2), 25: (feet, 1), 30: (mirror, 3)}) == [(19, mirror), (28, mirror), (29, mirror)]


def test_the_torso_written_is_the_fused_bodys_midpoint_projected_where_a_camera_found_one():
    """``with_fused_torso`` (what ``mocap-rt perceive``'s closed loop writes, issue 12 item 4):
    the pelvis-neck midpoint of the fused joints projected by OpenCV (the oracle) into each
    camera that measured a torso; the other cues, a camera that found none, and a frame
    without a pose keep what was measured."""
    import cv2

    from mocap_rt.fusion.offline import with_fused_torso
    from mocap_rt.geometry.camera import Camera, look_at
    from mocap_rt.names import C_TORSO

    rng = np.random.default_rng(4)
    K = np.array([[520.0, 0, 322], [0, 515, 238], [0, 0, 1]])
    dist = np.array([-0.12, 0.05, 0.001, -0.002, 0.0])
    cams = [Camera(f"c{i}", (640, 480), K, dist, *look_at(eye, [0.0, 0.0, 1.0]))
            for i, eye in enumerate(([4.0, 0.5, 1.6], [-0.6, 3.8, 2.1], [-3.5, -2.0, 1.2]))]
    F = 5
    joints = np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.3, (F, len(JOINT_NAMES), 3))
    valid = np.ones((F, len(JOINT_NAMES)), bool)
    valid[3, JOINT_NAMES.index("neck")] = False                  # no pose at frame 3
    xy = rng.uniform(0.0, 640.0, (len(cams), F, 6, 2))
    xy[1, 2, C_TORSO] = np.nan                                   # camera 1 found no torso at frame 2
    out = with_fused_torso(xy, cams, joints, valid)
    mid = 0.5 * (joints[:, JOINT_NAMES.index("pelvis")] + joints[:, JOINT_NAMES.index("neck")])
    for c, cam in enumerate(cams):
        oracle = cv2.projectPoints(mid, cv2.Rodrigues(cam.R)[0], cam.t, K, dist)[0][:, 0]
        for f in range(F):
            if (c, f) == (1, 2):
                assert np.isnan(out[c, f, C_TORSO]).all()
            elif f == 3:
                np.testing.assert_array_equal(out[c, f, C_TORSO], xy[c, f, C_TORSO])
            else:
                np.testing.assert_allclose(out[c, f, C_TORSO], oracle[f], atol=1e-6)
    others = [k for k in range(6) if k != C_TORSO]
    np.testing.assert_array_equal(out[:, :, others], xy[:, :, others])
